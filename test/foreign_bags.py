"""Contract bags as another tool writes them: plain rosbags, other conventions than ours.

Nothing of this project writes them (rosbags message classes from the contract's .msg text and
``serialize_cdr``), and they differ from our recorder and from :mod:`contract_bags` in every way
the contract leaves open:

* stamp origin: a real epoch (~1.7e9 s) with the grid offset from whole seconds (``offset_ns``);
* timing convention (``grs_convention="command_at_stamp"``): the other simulator stamps a GRS
  sample with the start of the step it averages, so the sample stamped t_k already reflects the
  command stamped t_k (ours stamps it t_{k+1}); the star tracker is instantaneous in both;
* message order in the file: per epoch GRS2, GRS1, then the star tracker, commands written ahead
  of time, bag (receive) stamps with a per-topic latency, and ``order="topic_blocks"`` writes each
  topic as one block (a converter dumping topic by topic);
* storage: MCAP or sqlite3.
"""

from __future__ import annotations

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

from contract_bags import CMD, GRS, ST, ground_segment_store

DT_NS = 100_000_000


def foreign_stamps(n: int, start_ns: int = 1_712_345_678 * 10**9, offset_ns: int = 37_000_000) -> np.ndarray:
    """(n,) header stamps of a 10 Hz grid at a real epoch, offset from whole seconds [ns]."""
    return start_ns + offset_ns + np.arange(n, dtype=np.int64) * DT_NS


def write_foreign_bag(path, data: dict, storage: str = "mcap", *, grs_convention: str = "command_at_stamp",
                      order: str = "interleaved", start_ns: int = 1_712_345_678 * 10**9,
                      offset_ns: int = 37_000_000) -> dict:
    """Write ``data`` (the dict of :func:`contract_bags.simulated_data`) the way another tool would.

    Parameters
    ----------
    path : path-like
        Bag directory to create.
    data : dict
        ``quat`` (n, 4), ``cov`` (n, 9), ``volts`` (2, n, 6), ``torque`` (m, 3) one per 10 samples;
        its ``stamps`` are ignored (this writer has its own time origin).
    storage : str
        ``mcap`` or ``sqlite3``.
    grs_convention : str
        ``command_at_stamp`` (GRS stamped one period earlier than ours, see the module doc) or
        ``ours``.
    order : str
        ``interleaved`` (per epoch, GRS2, GRS1, star tracker) or ``topic_blocks``.

    Returns
    -------
    dict
        ``st_ns``, ``grs_ns`` (the header stamps written).
    """
    store = ground_segment_store()
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    Quaternion, Vector3 = types["geometry_msgs/msg/Quaternion"], types["geometry_msgs/msg/Vector3"]
    Wrench, WrenchStamped = types["geometry_msgs/msg/Wrench"], types["geometry_msgs/msg/WrenchStamped"]
    StarTracker, GrsVoltages = types[ST], types[GRS]
    n = data["quat"].shape[0]
    st_ns = foreign_stamps(n, start_ns, offset_ns)
    grs_ns = st_ns - DT_NS if grs_convention == "command_at_stamp" else st_ns.copy()

    def header(ns: int, frame: str):
        return Header(stamp=Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9)), frame_id=frame)

    def st_message(k: int) -> tuple[int, bytes]:
        q = data["quat"][k]
        msg = StarTracker(header=header(st_ns[k], "crf"), attitude=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
                          attitude_covariance=data["cov"][k])
        return int(st_ns[k]) + 4_000_000, store.serialize_cdr(msg, ST)

    def grs_message(i: int, k: int) -> tuple[int, bytes]:
        v = data["volts"][i, k]
        msg = GrsVoltages(header=header(grs_ns[k], f"tmrf{i + 1}"), grs_id=i + 1, vx1=v[0], vx2=v[1], vy1=v[2],
                          vy2=v[3], vz1=v[4], vz2=v[5])
        return int(grs_ns[k]) + 2_500_000 + 300_000 * i, store.serialize_cdr(msg, GRS)

    def cmd_message(j: int) -> tuple[int, bytes]:
        t = data["torque"][j]
        ns = int(st_ns[0]) + 10 * j * DT_NS
        msg = WrenchStamped(header=header(ns, "crf"), wrench=Wrench(
            force=Vector3(x=0.0, y=0.0, z=0.0), torque=Vector3(x=t[0], y=t[1], z=t[2])))
        return ns - 2_000_000_000, store.serialize_cdr(msg, CMD)  # commanded 2 s ahead

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        conn_cmd = writer.add_connection("/taiji2/maneuver/command", CMD, typestore=store)
        conn_g2 = writer.add_connection("/taiji2/grs2/voltages", GRS, typestore=store)
        conn_g1 = writer.add_connection("/taiji2/grs1/voltages", GRS, typestore=store)
        conn_st = writer.add_connection("/taiji2/star_tracker", ST, typestore=store)
        n_cmd = data["torque"].shape[0]
        if order == "topic_blocks":
            for j in range(n_cmd):
                writer.write(conn_cmd, *cmd_message(j))
            for i, conn in ((1, conn_g2), (0, conn_g1)):
                for k in range(n):
                    writer.write(conn, *grs_message(i, k))
            for k in range(n):
                writer.write(conn_st, *st_message(k))
        else:
            for j in range(min(20, n_cmd)):
                writer.write(conn_cmd, *cmd_message(j))
            for k in range(n):
                if k % 10 == 0 and k // 10 + 20 < n_cmd:
                    writer.write(conn_cmd, *cmd_message(k // 10 + 20))
                writer.write(conn_g2, *grs_message(1, k))
                writer.write(conn_g1, *grs_message(0, k))
                writer.write(conn_st, *st_message(k))
    return {"st_ns": st_ns, "grs_ns": grs_ns}
