"""The struct codec of plain messages (taiji2_runtime.fast_cdr) writes the bytes Cyclone DDS's own machine writes
and reads the values it reads, for every message type of the graph's packages, with random values (strings
of every length mod 8, empty and odd-length sequences, so every alignment residue is crossed)."""

from __future__ import annotations

import numpy as np
import pytest
from cyclonedds.idl import IdlStruct

from taiji2_runtime import fast_cdr
from taiji2_runtime.interfaces import message_class
from taiji2_runtime.typestore import typestore

PACKAGES = ("taiji2_msgs", "std_msgs", "geometry_msgs", "builtin_interfaces", "diagnostic_msgs", "rosgraph_msgs",
            "sensor_msgs")
_INT_RANGE = {"int8": 7, "int16": 15, "int32": 31, "int64": 63}


def _types() -> list[str]:
    store = typestore()
    return sorted(t for t in store.fielddefs if t.split("/")[0] in PACKAGES and "/msg/" in t)


def _value(base: str, rng: np.random.Generator):
    if base in ("string", "wstring"):
        return "".join(chr(97 + int(c)) for c in rng.integers(0, 26, int(rng.integers(0, 11))))
    if base == "bool":
        return bool(rng.integers(0, 2))
    if base.startswith("float"):
        v = float(rng.normal() * 10.0 ** rng.integers(-12, 6))
        return float(np.float32(v)) if base == "float32" else v
    if base in ("byte", "char", "uint8"):
        return int(rng.integers(0, 256))
    if base.startswith("uint"):
        return int(rng.integers(0, 2 ** min(int(base[4:]), 63)))
    bits = _INT_RANGE[base]
    return int(rng.integers(-(2 ** bits), 2 ** bits))


def _fill(msgtype: str, rng: np.random.Generator):
    cls = message_class(msgtype)
    _consts, fields = typestore().fielddefs[msgtype]
    kwargs = {}
    for name, (kind, args) in fields:
        if kind == 1:
            kwargs[name] = _value(args[0], rng)
        elif kind == 2:
            kwargs[name] = _fill("/".join(_split(args)), rng)
        else:
            (sub_kind, sub_args), size = args
            n = size if kind == 3 else int(rng.integers(0, 6))
            if sub_kind == 1:
                kwargs[name] = [_value(sub_args[0], rng) for _ in range(n)]
            else:
                kwargs[name] = [_fill("/".join(_split(sub_args)), rng) for _ in range(n)]
    return cls(**kwargs)


def _split(name: str) -> list[str]:
    parts = name.split("/")
    return parts if len(parts) == 3 else [parts[0], "msg", parts[1]]


@pytest.mark.parametrize("msgtype", _types())
def test_the_struct_codec_equals_cyclone_dds(msgtype):
    cls = message_class(msgtype)
    rng = np.random.default_rng(abs(hash(msgtype)) % 2**32)
    compiled = cls.serialize is not IdlStruct.serialize
    for _ in range(20):
        msg = _fill(msgtype, rng)
        reference = IdlStruct.serialize(msg)
        assert msg.serialize() == reference  # the graph's writers call this
        assert cls.deserialize(reference) == IdlStruct.deserialize.__func__(cls, reference)
        assert cls.deserialize(msg.serialize()) == msg or not compiled or _has_float32(msgtype)


def _has_float32(msgtype: str) -> bool:
    return "float32" in repr(typestore().fielddefs[msgtype])


def test_the_hot_path_messages_are_compiled():
    # the sensor, command, telemetry and estimate messages that every accelerated run carries per sample
    for name in ("taiji2_msgs/msg/GrsVoltages", "taiji2_msgs/msg/StarTracker", "geometry_msgs/msg/WrenchStamped",
                 "taiji2_msgs/msg/SpacePackets", "taiji2_msgs/msg/ScaleFactorEstimate", "rosgraph_msgs/msg/Clock"):
        assert message_class(name).serialize is not IdlStruct.serialize, name


def test_other_encodings_go_through_cyclone_dds():
    cls = message_class("taiji2_msgs/msg/GrsVoltages")
    msg = cls(grs_id=2, vx1=1.5)
    msg.header.frame_id = "tmrf2"
    v2 = msg.serialize(use_version_2=True)
    assert v2 == IdlStruct.serialize(msg, use_version_2=True) and v2[:4] != fast_cdr._HEADER
    assert cls.deserialize(v2) == msg
