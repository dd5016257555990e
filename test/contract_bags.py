"""Contract bags written the way a ground segment would: rosbags message classes from the .msg text.

Used by the bag and calibration tests; nothing of this project is involved in writing them.
"""

from __future__ import annotations

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from support import REPO

ST, GRS, CMD = "taiji2_msgs/msg/StarTracker", "taiji2_msgs/msg/GrsVoltages", "geometry_msgs/msg/WrenchStamped"
TOPICS = {"/taiji2/star_tracker": ST, "/taiji2/grs1/voltages": GRS, "/taiji2/grs2/voltages": GRS,
          "/taiji2/maneuver/command": CMD}


def ground_segment_store():
    """A type store built the way an outside tool would: Humble + the contract's .msg files."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    for path in sorted((REPO / "src" / "taiji2_msgs" / "msg").glob("*.msg")):
        store.register(get_types_from_msg(path.read_text(), f"taiji2_msgs/msg/{path.stem}"))
    return store


def ground_segment_data(n=300, seed=5):
    rng = np.random.default_rng(seed)
    stamps = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 100_000_000
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return {"stamps": stamps, "quat": quat, "cov": rng.uniform(1e-12, 1e-10, size=(n, 9)),
            "volts": rng.normal(scale=1e-3, size=(2, n, 6)), "torque": rng.normal(scale=1e-3, size=(n // 10, 3))}


def write_ground_segment_bag(path, storage="mcap", data=None, *, skip=(), overrides=None):
    """Write a contract bag with rosbags message classes and serialize_cdr, as a ground segment would."""
    store = ground_segment_store()
    data = data or ground_segment_data()
    overrides = overrides or {}
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    Quaternion, Vector3 = types["geometry_msgs/msg/Quaternion"], types["geometry_msgs/msg/Vector3"]
    Wrench, WrenchStamped = types["geometry_msgs/msg/Wrench"], types["geometry_msgs/msg/WrenchStamped"]
    StarTracker, GrsVoltages = types[ST], types[GRS]

    def header(ns, frame):
        return Header(stamp=Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9)), frame_id=frame)

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        conns = {t: writer.add_connection(t, overrides.get(t, mt), typestore=store)
                 for t, mt in TOPICS.items() if t not in skip}
        for k, ns in enumerate(data["stamps"]):
            if "/taiji2/star_tracker" in conns and overrides.get("/taiji2/star_tracker", ST) == ST:
                q = data["quat"][k]
                msg = StarTracker(header=header(ns, "crf"), attitude=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
                                  attitude_covariance=data["cov"][k])
                writer.write(conns["/taiji2/star_tracker"], int(ns) + 1000, store.serialize_cdr(msg, ST))
            for i, topic in enumerate(("/taiji2/grs1/voltages", "/taiji2/grs2/voltages")):
                if topic in conns and overrides.get(topic, GRS) == GRS:
                    v = data["volts"][i, k]
                    msg = GrsVoltages(header=header(ns, f"tmrf{i + 1}"), grs_id=i + 1, vx1=v[0], vx2=v[1], vy1=v[2],
                                      vy2=v[3], vz1=v[4], vz2=v[5])
                    writer.write(conns[topic], int(ns) + 2000, store.serialize_cdr(msg, GRS))
            if k % 10 == 0 and "/taiji2/maneuver/command" in conns:
                t = data["torque"][k // 10]
                msg = WrenchStamped(header=header(ns, "crf"), wrench=Wrench(
                    force=Vector3(x=0.0, y=0.0, z=0.0), torque=Vector3(x=t[0], y=t[1], z=t[2])))
                writer.write(conns["/taiji2/maneuver/command"], int(ns) + 3000, store.serialize_cdr(msg, CMD))
    return data


def simulated_data(out, stamp0_ns=1_700_000_000 * 10**9, commands=None):
    """The data dict of :func:`write_ground_segment_bag` from a simulator SimOutput."""
    stamps = stamp0_ns + np.rint(out.t_s * 1e9).astype(np.int64)
    torque = out.truth.torque_command_n_m[::10] if commands is None else commands
    return {"stamps": stamps, "quat": out.st_quat_xyzw, "cov": out.st_cov_rad2,
            "volts": np.moveaxis(out.voltages_v, 1, 0), "torque": torque}
