"""Decode many CDR messages of one type at once into numpy columns.

A ROS 2 message made of primitives, fixed-size arrays, nested messages and strings (no sequences)
has a fixed byte layout once the lengths of its strings are known: XCDR1 aligns each primitive to
its own size, relative to the end of the 4-byte encapsulation header, and prefixes strings with a
uint32 length that counts the terminating NUL. So messages are grouped by their string lengths
(read with numpy, string after string) and by size; each group is gathered into an (n, size) byte
array whose fields are numpy views. Only little-endian CDR with the exact expected size (or that
size padded to a multiple of 4) is decoded in bulk; every other message is deserialised on its own
with the rosbags type store, and one that fails there is reported as undecodable, never guessed.

Columns are keyed by the dotted field path (``header.stamp.sec``, ``attitude.x``,
``attitude_covariance``); fixed arrays give (n, k) columns, strings ``numpy.bytes_`` columns.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

from taiji2_runtime.bag.bulk_read import RawPiece, gather

# rosbags node kinds (rosbags.typesys.base.Nodetype): BASE=1, NAME=2, ARRAY=3, SEQUENCE=4
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4
_CDR_LE = (0x00, 0x01)
_MAX_GROUPS = 256

_PRIMITIVES: dict[str, str] = {
    "bool": "?", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1",
    "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8", "uint64": "<u8",
    "float32": "<f4", "float64": "<f8",
}


@dataclass(frozen=True)
class Leaf:
    """One primitive field, fixed primitive array or string of a flattened message.

    Attributes
    ----------
    path : str
        Dotted path, e.g. ``header.stamp.sec``.
    base : str
        ROS base type name (``float64``, ``string``, ...).
    count : int
        Number of elements (1 for scalars, k for ``T[k]``).
    is_array : bool
        True for fixed-size arrays (columns are (n, count)).
    """

    path: str
    base: str
    count: int = 1
    is_array: bool = False

    @property
    def dtype(self) -> np.dtype:
        """numpy dtype of one element (bytes for strings)."""
        return np.dtype(_PRIMITIVES.get(self.base, "S1"))

    @property
    def size(self) -> int:
        """Element size = CDR alignment [bytes]."""
        return int(self.dtype.itemsize)


def flatten_type(store: Typestore, msgtype: str) -> list[Leaf] | None:
    """The leaves of ``msgtype`` in serialisation order; None if it has sequences or unknown parts."""
    leaves: list[Leaf] = []

    def walk(typename: str, prefix: str) -> bool:
        if typename not in store.fielddefs:
            return False
        _consts, fields = store.fielddefs[typename]
        for name, (kind, args) in fields:
            path = f"{prefix}{name}"
            if kind == _BASE:
                base = args[0]
                if base not in _PRIMITIVES and base != "string":
                    return False
                if base == "string" and args[1]:
                    pass  # bounded strings serialise like strings
                leaves.append(Leaf(path, base))
            elif kind == _NAME:
                if not walk(args, f"{path}."):
                    return False
            elif kind == _ARRAY:
                (sub_kind, sub_args), size = args
                if sub_kind == _BASE and sub_args[0] in _PRIMITIVES:
                    leaves.append(Leaf(path, sub_args[0], int(size), True))
                elif sub_kind == _BASE and sub_args[0] == "string":
                    for i in range(size):
                        leaves.append(Leaf(f"{path}[{i}]", "string"))
                elif sub_kind == _NAME:
                    for i in range(size):
                        if not walk(sub_args, f"{path}[{i}]."):
                            return False
                else:
                    return False
            else:
                return False
        return True

    return leaves if walk(msgtype, "") else None


def _align(position: int, size: int) -> int:
    return (position + size - 1) // size * size


@dataclass
class DecodedColumns:
    """Columns of n messages of one type.

    Attributes
    ----------
    columns : dict
        ``{path: array}`` with n rows each; rows of undecodable messages hold zeros.
    valid : numpy.ndarray
        (n,) bool, False for undecodable messages.
    errors : dict
        ``{row: reason}`` of every undecodable message.
    bulk_rows : int
        Rows decoded in bulk (the rest went through the per-message deserialiser).
    """

    columns: dict[str, np.ndarray]
    valid: np.ndarray
    errors: dict[int, str] = field(default_factory=dict)
    bulk_rows: int = 0


@dataclass
class _Group:
    piece: int
    local: np.ndarray     # message indices within the piece
    offsets: np.ndarray   # payload start (after the encapsulation header) in the piece's blob
    lengths: np.ndarray   # payload sizes [bytes]
    strings: tuple[int, ...] = ()


def _layout(leaves: list[Leaf], string_lengths: tuple[int, ...]) -> tuple[list[int], int, int | None]:
    """Leaf offsets for the known string lengths: (offsets, size, position of the next unknown string)."""
    position = 0
    offsets: list[int] = []
    known = iter(string_lengths)
    for leaf in leaves:
        if leaf.base == "string":
            position = _align(position, 4)
            offsets.append(position)
            length = next(known, None)
            if length is None:
                return offsets, position, position
            position += 4 + length
        else:
            position = _align(position, leaf.size)
            offsets.append(position)
            position += leaf.size * leaf.count
    return offsets, position, None


def _split_groups(leaves: list[Leaf], pieces: list[RawPiece]) -> tuple[list[_Group], list[tuple[int, int]]]:
    """Groups of messages sharing one layout, and the (piece, index) pairs left to the fallback."""
    pending: list[_Group] = []
    fallback: list[tuple[int, int]] = []
    for p, piece in enumerate(pieces):
        if piece.offsets.shape[0] == 0:
            continue
        header = gather(piece.blob, piece.offsets, 2)
        little = (header[:, 0] == _CDR_LE[0]) & (header[:, 1] == _CDR_LE[1]) & (piece.lengths >= 4)
        fallback.extend((p, int(i)) for i in np.flatnonzero(~little))
        keep = np.flatnonzero(little)
        pending.append(_Group(p, keep, piece.offsets[keep] + 4, piece.lengths[keep] - 4))
    done: list[_Group] = []
    while pending:
        group = pending.pop()
        _offsets, _size, next_string = _layout(leaves, group.strings)
        if next_string is None:
            done.append(group)
            continue
        inside = group.lengths >= next_string + 4
        fallback.extend((group.piece, int(i)) for i in group.local[~inside])
        sel = np.flatnonzero(inside)
        blob = pieces[group.piece].blob
        values = np.ascontiguousarray(gather(blob, group.offsets[sel] + next_string, 4)).view("<u4").reshape(-1)
        if values.shape[0] and np.all(values == values[0]):  # the common case: one length (no sort)
            unique, inverse = values[:1], np.zeros(values.shape[0], dtype=np.intp)
        else:
            unique, inverse = np.unique(values, return_inverse=True)
        if len(pending) + len(done) + unique.shape[0] > _MAX_GROUPS:
            fallback.extend((group.piece, int(i)) for i in group.local[sel])
            continue
        for k, length in enumerate(unique):
            members = sel[inverse.reshape(-1) == k]
            if int(length) < 1:  # a CDR string length counts its NUL: 0 is malformed
                fallback.extend((group.piece, int(i)) for i in group.local[members])
                continue
            pending.append(_Group(group.piece, group.local[members], group.offsets[members],
                                  group.lengths[members], (*group.strings, int(length))))
    return done, fallback


def _from_message(msg: Any, path: str) -> Any:
    value = msg
    for part in path.split("."):
        if part.endswith("]"):
            name, index = part[:-1].split("[")
            value = getattr(value, name)[int(index)]
        else:
            value = getattr(value, part)
    return value


def _record_dtype(leaves: list[Leaf], offsets: list[int], string_lengths: tuple[int, ...], size: int) -> np.dtype:
    """Structured dtype of one message of this layout: each leaf at its offset (strings: their
    characters without the length prefix and NUL; empty strings read one byte of the NUL, b"")."""
    names, formats, positions = [], [], []
    lengths = iter(string_lengths)
    for leaf, offset in zip(leaves, offsets, strict=True):
        names.append(leaf.path)
        if leaf.base == "string":
            length = next(lengths)
            formats.append(f"S{max(length - 1, 1)}")
            positions.append(offset + 4)
        else:
            formats.append((leaf.dtype, (leaf.count,)) if leaf.is_array else leaf.dtype)
            positions.append(offset)
    return np.dtype({"names": names, "formats": formats, "offsets": positions, "itemsize": size})


def decode_messages(store: Typestore, msgtype: str, pieces: list[RawPiece],
                    leaves: list[Leaf] | None = None) -> DecodedColumns:
    """Decode every message of ``pieces`` (all of type ``msgtype``) into columns, in piece order.

    Parameters
    ----------
    store : rosbags.typesys.store.Typestore
        Type store that knows ``msgtype`` (used for the layout and for per-message fallbacks).
    msgtype : str
        ``pkg/msg/Name`` of every message.
    pieces : list of RawPiece
        The serialised messages (with their 4-byte encapsulation headers).
    leaves : list of Leaf, optional
        Precomputed :func:`flatten_type` result.

    Returns
    -------
    DecodedColumns

    Raises
    ------
    ValueError
        If ``msgtype`` has sequences or parts unknown to ``store`` (not decodable into columns).
    """
    leaves = leaves if leaves is not None else flatten_type(store, msgtype)
    if leaves is None:
        raise ValueError(f"{msgtype} has sequences or unknown parts: it cannot be decoded into columns")
    n = int(sum(p.offsets.shape[0] for p in pieces))
    valid = np.zeros(n, dtype=bool)
    errors: dict[int, str] = {}
    groups, fallback = _split_groups(leaves, pieces)
    numeric: dict[str, np.ndarray] = {}
    strings: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for leaf in leaves:
        if leaf.base == "string":
            strings[leaf.path] = []
        else:
            shape = (n, leaf.count) if leaf.is_array else (n,)
            numeric[leaf.path] = np.zeros(shape, dtype=leaf.dtype)
    bases = np.cumsum([0] + [p.offsets.shape[0] for p in pieces])
    bulk_rows = 0
    for group in groups:
        offsets, size, _ = _layout(leaves, group.strings)
        fits = (group.lengths == size) | ((group.lengths == _align(size, 4)) & (group.lengths - size <= 3))
        fallback.extend((group.piece, int(i)) for i in group.local[~fits])
        sel = np.flatnonzero(fits)
        if sel.shape[0] == 0:
            continue
        rows = bases[group.piece] + group.local[sel]
        # consecutive rows (the common case): slice assignments instead of scattering
        target: np.ndarray | slice = slice(int(rows[0]), int(rows[-1]) + 1) \
            if int(rows[-1]) - int(rows[0]) + 1 == rows.shape[0] else rows
        data = np.ascontiguousarray(gather(pieces[group.piece].blob, group.offsets[sel], size))
        # every field a view of the gathered bytes (a structured dtype of this layout): one copy per column
        record = data.view(_record_dtype(leaves, offsets, group.strings, size)).reshape(-1)
        for leaf in leaves:
            if leaf.base == "string":
                strings[leaf.path].append((rows, record[leaf.path]))
            else:
                numeric[leaf.path][target] = record[leaf.path]
        valid[target] = True
        bulk_rows += int(rows.shape[0])
    columns: dict[str, np.ndarray] = dict(numeric)
    fallback_text: dict[str, list[tuple[int, bytes]]] = {path: [] for path in strings}
    for piece_index, index in fallback:
        row = int(bases[piece_index]) + index
        raw = pieces[piece_index].message(index)
        try:
            msg = store.deserialize_cdr(raw, msgtype)
            values = {leaf.path: _from_message(msg, leaf.path) for leaf in leaves}
        except Exception as exc:  # malformed CDR: undecodable, reported per message
            errors[row] = f"undecodable ({type(exc).__name__}: {' '.join(str(exc).split())[:80]})"
            continue
        for leaf in leaves:
            value = values[leaf.path]
            if leaf.base == "string":
                fallback_text[leaf.path].append((row, str(value).encode()))
            else:
                numeric[leaf.path][row] = value
        valid[row] = True
    for path, parts in strings.items():
        width = max([p[1].dtype.itemsize for p in parts] + [len(t) for _, t in fallback_text[path]] + [1])
        column = np.zeros(n, dtype=f"S{width}")
        for rows, text in parts:
            column[rows] = text
        for row, text in fallback_text[path]:
            column[row] = text
        columns[path] = column
    return DecodedColumns(columns, valid, errors, bulk_rows)


def encode_messages(store: Typestore, msgtype: str, columns: dict[str, Any], count: int) -> list[bytes]:
    """Serialise ``count`` messages of ``msgtype`` from columns: the inverse of :func:`decode_messages`.

    Parameters
    ----------
    store : rosbags.typesys.store.Typestore
        Type store that knows ``msgtype``.
    msgtype : str
        ``pkg/msg/Name`` (primitives, fixed arrays, nested messages and strings only).
    columns : dict
        ``{path: value}`` per leaf (see :func:`flatten_type`): an array with ``count`` rows (strings:
        ``str`` / ``bytes`` items) or one scalar / string for every message; missing leaves are zero
        or empty.
    count : int
        Number of messages.

    Returns
    -------
    list of bytes
        Little-endian CDR with the encapsulation header, byte-identical to rosbags' ``serialize_cdr``.

    Raises
    ------
    ValueError
        If ``msgtype`` has sequences or parts unknown to ``store``.
    """
    leaves = flatten_type(store, msgtype)
    if leaves is None:
        raise ValueError(f"{msgtype} has sequences or unknown parts: it cannot be encoded from columns")
    texts: dict[str, list[bytes]] = {}
    for leaf in leaves:
        if leaf.base != "string":
            continue
        value = columns.get(leaf.path, b"")
        items = [value] * count if isinstance(value, str | bytes) else list(value)
        texts[leaf.path] = [v.encode() if isinstance(v, str) else bytes(v) for v in items]
    keys = list(zip(*(tuple(len(t) + 1 for t in texts[p]) for p in texts), strict=True)) if texts else [()] * count
    groups: dict[tuple[int, ...], list[int]] = {}
    for row, key in enumerate(keys):
        groups.setdefault(key, []).append(row)
    out: list[bytes] = [b""] * count
    for string_lengths, rows_list in groups.items():
        rows = np.asarray(rows_list, dtype=np.int64)
        offsets, size, _ = _layout(leaves, string_lengths)
        data = np.zeros((rows.shape[0], size + 4), dtype=np.uint8)
        data[:, 1] = 1  # CDR little endian, options 0
        body = data[:, 4:]
        lengths = iter(string_lengths)
        for leaf, offset in zip(leaves, offsets, strict=True):
            if leaf.base == "string":
                length = next(lengths)
                body[:, offset:offset + 4] = np.frombuffer(np.uint32(length).tobytes(), np.uint8)
                if length > 1:
                    chars = np.frombuffer(b"".join(texts[leaf.path][r] for r in rows_list), np.uint8)
                    body[:, offset + 4:offset + 3 + length] = chars.reshape(rows.shape[0], length - 1)
                continue
            value = columns.get(leaf.path, 0)
            array = np.asarray(value, dtype=leaf.dtype)
            shape = (count, leaf.count) if leaf.is_array else (count,)
            if array.shape != shape:
                array = np.broadcast_to(array, shape)
            block = np.ascontiguousarray(array[rows]).reshape(rows.shape[0], -1)
            width = leaf.size * leaf.count
            body[:, offset:offset + width] = block.view(np.uint8).reshape(rows.shape[0], width)
        flat = data.tobytes()
        step = size + 4
        for k, row in enumerate(rows_list):
            out[row] = flat[k * step:(k + 1) * step]
    return out
