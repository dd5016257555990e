"""XCDR1 little-endian (de)serialisation of plain ROS 2 messages with ``struct``, for the embedded runtime.

Cyclone DDS's Python binding (de)serialises a sample field by field through its interpreted type machine:
for the graph's 10-Hz sensor messages that cost ~50 us to write and ~100 us to read each (cProfile of the
ground receiver and the estimator nodes), on every publisher and every subscriber of every sample, which is
a large share of an accelerated run's CPU. A message made of numeric fields, strings, nested messages and
arrays or unbounded sequences of numbers has a layout that only its strings and sequences make variable: its
fields compile here into a few ``struct`` operations (consecutive numbers into one, with the padding for
each alignment of the position it starts at), read and written with ``operator.attrgetter`` and positional
construction. The bytes are those Cyclone DDS writes and the values those it reads
(``test/runtime/test_fast_cdr.py`` compares both for every message type of the graph); anything else (a
big-endian or XCDR2 sample, bounded strings or sequences, arrays of strings or messages) goes through
Cyclone DDS unchanged.
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Callable
from typing import Any

__all__ = ["Codec", "compile_codec"]

# rosbags node kinds (rosbags.typesys.base.Nodetype): BASE=1, NAME=2, ARRAY=3, SEQUENCE=4
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4
#: struct format and size of each numeric ROS 2 base type
_NUMERIC = {"bool": "?", "byte": "B", "char": "B", "int8": "b", "uint8": "B", "int16": "h", "uint16": "H",
            "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q", "float32": "f", "float64": "d"}
_HEADER = b"\x00\x01\x00\x00"  # XCDR1 (plain CDR), little endian, no options
_U32 = struct.Struct("<I")


class _Unsupported(Exception):
    """A field this module does not compile (the message goes through Cyclone DDS)."""


def _pad(position: int, size: int) -> int:
    """Padding before an item of ``size`` octets at payload ``position`` (XCDR1: aligned to min(size, 8))."""
    align = min(size, 8)
    return (-position) % align


class _Numbers:
    """Consecutive numeric fields: one struct per alignment residue (position mod 8) of their start."""

    def __init__(self, paths: list[str], formats: list[str]) -> None:
        self.paths = paths
        one = operator.attrgetter(paths[0])
        # attrgetter of several names returns a tuple, of one name the bare value
        self.get = operator.attrgetter(*paths) if len(paths) > 1 else (lambda m: (one(m),))
        self.structs = []
        for residue in range(8):
            fmt, position = "<", residue
            for f in formats:
                size = struct.calcsize(f)
                pad = _pad(position, size)
                fmt += "x" * pad + f
                position += pad + size
            self.structs.append(struct.Struct(fmt))


class _String:
    def __init__(self, path: str) -> None:
        self.get = operator.attrgetter(path)


class _Array:
    """A fixed-length array or an unbounded sequence of one numeric type."""

    def __init__(self, path: str, fmt: str, length: int | None) -> None:
        self.get = operator.attrgetter(path)
        self.fmt = fmt
        self.size = struct.calcsize(fmt)
        self.length = length  # None: a sequence (count first)
        self.fixed = None if length is None else struct.Struct(f"<{length}{fmt}")


class Codec:
    """``serialize(msg) -> bytes`` and ``deserialize(data) -> msg`` of one message class (module docstring)."""

    def __init__(self, cls: type, ops: list[Any], build: Callable[[list[Any], int], tuple[Any, int]]) -> None:
        self.cls = cls
        self.ops = ops
        self._build = build

    def serialize(self, msg: Any) -> bytes:
        out = bytearray(_HEADER)
        for op in self.ops:
            position = len(out) - 4
            if type(op) is _Numbers:
                s = op.structs[position % 8]
                out += s.pack(*op.get(msg))
            elif type(op) is _String:
                text = op.get(msg).encode("utf-8")
                out += b"\x00" * _pad(position, 4)
                out += _U32.pack(len(text) + 1)
                out += text
                out += b"\x00"
            else:
                values = op.get(msg)
                if op.length is None:
                    out += b"\x00" * _pad(position, 4)
                    out += _U32.pack(len(values))
                    position = len(out) - 4
                    if not len(values):
                        continue
                    out += b"\x00" * _pad(position, op.size)
                    out += bytes(values) if op.fmt == "B" else struct.pack(f"<{len(values)}{op.fmt}", *values)
                else:
                    if len(values) != op.length:
                        raise ValueError(f"array field of {self.cls.__name__}: {len(values)} values, "
                                         f"{op.length} defined")
                    out += b"\x00" * _pad(position, op.size)
                    out += op.fixed.pack(*values)
        return bytes(out)

    def deserialize(self, data: bytes) -> Any:
        view = memoryview(data)
        offset = 4
        values: list[Any] = []
        for op in self.ops:
            position = offset - 4
            if type(op) is _Numbers:
                s = op.structs[position % 8]
                values.extend(s.unpack_from(view, offset))
                offset += s.size
            elif type(op) is _String:
                offset += _pad(position, 4)
                (n,) = _U32.unpack_from(view, offset)
                offset += 4
                values.append(bytes(view[offset:offset + n - 1]).decode("utf-8"))
                offset += n
            else:
                if op.length is None:
                    offset += _pad(position, 4)
                    (n,) = _U32.unpack_from(view, offset)
                    offset += 4
                    if n:
                        offset += _pad(offset - 4, op.size)
                else:
                    n = op.length
                    offset += _pad(position, op.size)
                if op.fmt == "B":
                    values.append(list(view[offset:offset + n]))
                else:
                    values.append(list(struct.unpack_from(f"<{n}{op.fmt}", view, offset)))
                offset += n * op.size
        msg, _ = self._build(values, 0)
        return msg


def compile_codec(cls: type, fields: list[tuple[str, Any]], field_class: Callable[[str], type],
                  field_descs: Callable[[str], list[tuple[str, Any]]]) -> Codec | None:
    """The codec of message class ``cls`` with rosbags field descriptions ``fields``; None if not compilable.

    ``field_class(type_name)`` and ``field_descs(type_name)`` give a nested message's class and fields."""
    ops: list[Any] = []
    pending_paths: list[str] = []
    pending_formats: list[str] = []

    def flush() -> None:
        if pending_paths:
            ops.append(_Numbers(list(pending_paths), list(pending_formats)))
            pending_paths.clear()
            pending_formats.clear()

    def walk(klass: type, descs: list[tuple[str, Any]], prefix: str) -> Callable[[list[Any], int], tuple[Any, int]]:
        parts: list[Any] = []  # None: one value; a builder: a nested message
        for name, (kind, args) in descs:
            path = prefix + name
            if kind == _BASE:
                base, bound = args
                if base in _NUMERIC:
                    pending_paths.append(path)
                    pending_formats.append(_NUMERIC[base])
                elif base == "string" and not bound:
                    flush()
                    ops.append(_String(path))
                else:
                    raise _Unsupported(f"{path}: {base}<={bound}")
                parts.append(None)
            elif kind == _NAME:
                parts.append(walk(field_class(args), field_descs(args), path + "."))
            elif kind in (_ARRAY, _SEQUENCE):
                (sub_kind, sub_args), size = args
                if sub_kind != _BASE or sub_args[0] not in _NUMERIC or sub_args[1] or (kind == _SEQUENCE and size):
                    raise _Unsupported(f"{path}: array or bounded sequence of {sub_args}")
                flush()
                ops.append(_Array(path, _NUMERIC[sub_args[0]], size if kind == _ARRAY else None))
                parts.append(None)
            else:
                raise _Unsupported(f"{path}: kind {kind}")

        def build(values: list[Any], i: int) -> tuple[Any, int]:
            args = []
            for part in parts:
                if part is None:
                    args.append(values[i])
                    i += 1
                else:
                    value, i = part(values, i)
                    args.append(value)
            return klass(*args), i

        return build

    try:
        build = walk(cls, fields, "")
    except _Unsupported:
        return None
    flush()
    return Codec(cls, ops, build)


def install(cls: type, codec: Codec) -> None:
    """Make ``cls.serialize`` / ``cls.deserialize`` use ``codec`` for XCDR1 little-endian samples (what the
    graph's writers write and readers get), Cyclone DDS's own machine for anything else."""
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl._support import Endianness

    def serialize(self: Any, buffer: Any = None, endianness: Any = None, use_version_2: bool | None = None) -> bytes:
        if buffer is None and not use_version_2 and endianness in (None, Endianness.Little) \
                and Endianness.native() == Endianness.Little and type(self) is cls:
            return codec.serialize(self)
        return IdlStruct.serialize(self, buffer=buffer, endianness=endianness, use_version_2=use_version_2)

    def deserialize(klass: type, data: Any, has_header: bool = True, use_version_2: bool | None = None) -> Any:
        if has_header and use_version_2 is None and klass is cls and bytes(data[:4]) == _HEADER:
            return codec.deserialize(data)
        return IdlStruct.deserialize.__func__(klass, data, has_header=has_header, use_version_2=use_version_2)

    cls.serialize = serialize
    cls.deserialize = classmethod(deserialize)
