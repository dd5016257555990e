"""Write a simulated experiment as a raw-data contract bag (docs/interfaces.md), with rosbags.

The three raw topics at every sample and the command at every step (stamped at the step's start,
the instant from which it holds), header stamps in simulated seconds; the run's provenance (seed,
fidelity, layout, effects: the hidden truth of a blind test) goes into the bag's custom metadata,
which no estimator or diagnosis step reads.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from taiji2_model.contract import COMMAND_TOPIC, GRS_TOPICS, STAR_TRACKER_TOPIC

__all__ = ["write_simulated_bag"]

_ST, _GRS, _CMD = "taiji2_msgs/msg/StarTracker", "taiji2_msgs/msg/GrsVoltages", "geometry_msgs/msg/WrenchStamped"


def write_simulated_bag(path: str | Path, t_s: np.ndarray, st_quat_xyzw: np.ndarray, st_cov_rad2: np.ndarray,
                        voltages_v: np.ndarray, command_t_s: np.ndarray, torque_cmd_n_m: np.ndarray, *,
                        storage: str = "mcap", provenance: dict[str, Any] | None = None) -> Path:
    """Write the raw topics of a simulated run.

    Parameters
    ----------
    path : str or Path
        Bag directory to create (must not exist).
    t_s : numpy.ndarray
        (n,) sample stamps [s] (star tracker and both GRS).
    st_quat_xyzw, st_cov_rad2 : numpy.ndarray
        (n, 4) attitude, (n, 9) covariance [rad^2].
    voltages_v : numpy.ndarray
        (n, 2, 6) electrode voltages of GRS1, GRS2 [V].
    command_t_s, torque_cmd_n_m : numpy.ndarray
        (m,) command stamps [s], (m, 3) torques [N m].
    storage : str
        ``mcap`` or ``sqlite3``.
    provenance : dict, optional
        Stored as JSON in the bag's custom metadata under ``taiji2.provenance``.

    Returns
    -------
    Path
        The bag directory.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    from taiji2_runtime.typestore import typestore

    path = Path(path)
    if path.exists():
        raise ValueError(f"{path}: already exists; choose another output")
    if storage not in ("mcap", "sqlite3"):
        raise ValueError(f"storage {storage!r}: expected mcap or sqlite3")
    store = typestore()
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    Quaternion, Vector3 = types["geometry_msgs/msg/Quaternion"], types["geometry_msgs/msg/Vector3"]
    Wrench, WrenchStamped = types["geometry_msgs/msg/Wrench"], types["geometry_msgs/msg/WrenchStamped"]
    StarTracker, GrsVoltages = types[_ST], types[_GRS]

    def stamp(seconds: float) -> tuple[Any, int]:
        ns = round(seconds * 1e9)
        return Time(sec=ns // 10**9, nanosec=ns % 10**9), ns

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        st = writer.add_connection(STAR_TRACKER_TOPIC, _ST, typestore=store)
        grs = [writer.add_connection(GRS_TOPICS[i], _GRS, typestore=store) for i in range(2)]
        cmd = writer.add_connection(COMMAND_TOPIC, _CMD, typestore=store)
        commands = sorted(zip(np.asarray(command_t_s, dtype=float), np.asarray(torque_cmd_n_m, dtype=float),
                              strict=True), key=lambda item: item[0])
        next_command = 0
        for k, t in enumerate(np.asarray(t_s, dtype=float)):
            while next_command < len(commands) and commands[next_command][0] <= t:
                tc, torque = commands[next_command]
                time, ns = stamp(tc)
                msg = WrenchStamped(header=Header(stamp=time, frame_id="crf"),
                                    wrench=Wrench(force=Vector3(x=0.0, y=0.0, z=0.0),
                                                  torque=Vector3(x=torque[0], y=torque[1], z=torque[2])))
                writer.write(cmd, ns, store.serialize_cdr(msg, _CMD))
                next_command += 1
            time, ns = stamp(t)
            q = st_quat_xyzw[k]
            writer.write(st, ns, store.serialize_cdr(StarTracker(
                header=Header(stamp=time, frame_id="crf"), attitude=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
                attitude_covariance=np.asarray(st_cov_rad2[k], dtype=np.float64)), _ST))
            for i in range(2):
                v = voltages_v[k, i]
                writer.write(grs[i], ns, store.serialize_cdr(GrsVoltages(
                    header=Header(stamp=time, frame_id=f"tmrf{i + 1}"), grs_id=i + 1, vx1=v[0], vx2=v[1], vy1=v[2],
                    vy2=v[3], vz1=v[4], vz2=v[5]), _GRS))
        if provenance is not None:
            writer.set_custom_data("taiji2.provenance", json.dumps(provenance))
    return path
