"""CDR bytes of every taiji2 message equal what rosbags (an independent encoder) makes of the same .msg text."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from taiji2_runtime.interfaces import message_class

MSG_DIR = Path(__file__).resolve().parents[2] / "src" / "taiji2_msgs" / "msg"
MSG_FILES = sorted(MSG_DIR.glob("*.msg"))


def _reference_store():
    store = get_typestore(Stores.ROS2_HUMBLE)
    for f in MSG_FILES:
        store.register(get_types_from_msg(f.read_text(), f"taiji2_msgs/msg/{f.stem}"))
    return store


def _fill(store, msgtype: str, rng: np.random.Generator, ours: object):
    """Random values set on our message, and the same values as a rosbags message."""
    _consts, fields = store.fielddefs[msgtype]
    kwargs = {}
    for name, (kind, args) in fields:
        if kind == 2:  # nested message
            kwargs[name] = _fill(store, args, rng, getattr(ours, name))
            continue
        if kind == 1:
            base = args[0]
            if base == "string":
                value = "tmrf" + str(int(rng.integers(0, 10**int(rng.integers(0, 6)))))
            elif base == "bool":
                value = bool(rng.integers(0, 2))
            elif base.startswith("float"):
                value = float(rng.normal() * 10.0 ** rng.integers(-12, 3))
            elif base.startswith("uint"):
                value = int(rng.integers(0, 2**min(8 * (int(base[4:]) // 8), 31)))
            else:
                value = int(rng.integers(-(2**30), 2**30))
            setattr(ours, name, value)
            kwargs[name] = value
        elif kind == 3:
            values = rng.normal(size=args[1]) * 1e-9
            setattr(ours, name, [float(v) for v in values])
            kwargs[name] = values
        elif kind == 4 and args[0][1][0] in ("uint8", "int64"):  # unbounded sequence (SpacePackets)
            dtype = np.uint8 if args[0][1][0] == "uint8" else np.int64
            high = 256 if dtype is np.uint8 else 2**62
            values = rng.integers(0, high, size=int(rng.integers(0, 300)), dtype=dtype)
            setattr(ours, name, [int(v) for v in values])
            kwargs[name] = values
        else:
            raise AssertionError(f"unhandled field kind in {msgtype}.{name}")
    return store.types[msgtype](**kwargs)


@pytest.mark.parametrize("msg_file", MSG_FILES, ids=lambda p: p.stem)
def test_cdr_bytes_match_rosbags(msg_file):
    assert MSG_FILES, "no .msg files found"
    msgtype = f"taiji2_msgs/msg/{msg_file.stem}"
    store = _reference_store()
    rng = np.random.default_rng(7)
    for _ in range(20):
        ours = message_class(msgtype)()
        reference = _fill(store, msgtype, rng, ours)
        expected = bytes(store.serialize_cdr(reference, msgtype))
        assert bytes(ours.serialize()) == expected
        # and both directions decode to the same message
        back = message_class(msgtype).deserialize(expected)
        assert back == ours


def test_contract_messages_have_exactly_the_contract_fields():
    star = message_class("taiji2_msgs/msg/StarTracker").get_fields_and_field_types()
    assert star == {"header": "std_msgs/Header", "attitude": "geometry_msgs/Quaternion",
                    "attitude_covariance": "float64[9]"}
    grs = message_class("taiji2_msgs/msg/GrsVoltages").get_fields_and_field_types()
    assert list(grs) == ["header", "grs_id", "vx1", "vx2", "vy1", "vy2", "vz1", "vz2"]
    assert grs["grs_id"] == "uint8" and all(grs[k] == "float64" for k in list(grs)[2:])
