"""Bulk access to the raw CDR bytes and receive stamps of a bag, without a Python loop per message.

MCAP: every chunk is read once (decompressed when needed, checksum verified) and the messages of
each channel are located from the chunk's message-index records with numpy. sqlite3: one table
scan (id ranges read concurrently), each topic's rows aggregated inside SQLite. Anything unusual
(an MCAP file without chunk or message indexes, a storage this module does not know) falls back
to iterating rosbags' reader, so the result is the same for every bag rosbags opens, only slower.

The result per ``(topic, type)`` is a :class:`RawMessages`: receive stamps and the byte ranges of
each serialised message (4-byte CDR encapsulation header included) in one or more byte buffers.
"""

from __future__ import annotations

import gc
import itertools
import os
import struct
import zlib
from collections.abc import Collection, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from taiji2_runtime.bag.errors import BagError
from taiji2_runtime.bag.reading import describe_error, storages_of
from taiji2_runtime.bag.sqlite3_direct import Sqlite3Bag, connect

if TYPE_CHECKING:  # rosbags.rosbag2 is imported where a bag is read through it (~0.04 s)
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.storage_mcap import McapReader

_MESSAGE_OP = 0x05
_CHUNK_HEADER = 9 + 8 + 8 + 8 + 4 + 4  # op, length, start, end, uncompressed size, crc, compression length
_MESSAGE_HEADER = 1 + 8 + 2 + 4 + 8 + 8  # op, length, channel, sequence, log time, publish time

Key = tuple[str, str]


@dataclass
class RawPiece:
    """Serialised messages in one byte buffer.

    Attributes
    ----------
    blob : numpy.ndarray
        uint8 buffer holding the messages (and possibly other bytes).
    offsets : numpy.ndarray
        (n,) int64 start of each message in ``blob``.
    lengths : numpy.ndarray
        (n,) int64 length of each message [bytes].
    """

    blob: np.ndarray
    offsets: np.ndarray
    lengths: np.ndarray

    def message(self, index: int) -> bytes:
        """The bytes of message ``index`` of this piece."""
        start = int(self.offsets[index])
        return self.blob[start:start + int(self.lengths[index])].tobytes()


@dataclass
class RawMessages:
    """All messages of one ``(topic, type)`` of a bag, in bag order (receive stamp, then file order).

    Attributes
    ----------
    topic, msgtype : str
        Topic name and ``pkg/msg/Name`` type.
    log_time_ns : numpy.ndarray
        (n,) int64 bag (receive) stamps [ns].
    pieces : list of RawPiece
        The serialised messages, in order; empty when read without data.
    """

    topic: str
    msgtype: str
    log_time_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    pieces: list[RawPiece] = field(default_factory=list)

    @property
    def count(self) -> int:
        """Number of messages."""
        return int(self.log_time_ns.shape[0])

    def messages(self) -> list[bytes]:
        """Every message as ``bytes`` (a Python loop: for fallbacks and tests, not for bulk work)."""
        return [piece.message(i) for piece in self.pieces for i in range(piece.offsets.shape[0])]


@dataclass
class _Partial:
    times: list[np.ndarray] = field(default_factory=list)
    pieces: list[RawPiece] = field(default_factory=list)


def gather(blob: np.ndarray, offsets: np.ndarray, width: int) -> np.ndarray:
    """(n, width) uint8 copy of the ``width`` bytes at each of ``offsets`` in ``blob``."""
    if offsets.shape[0] == 0:
        return np.zeros((0, width), np.uint8)
    return sliding_window_view(blob, width)[offsets]


def _u64(blob: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(gather(blob, offsets, 8)).view("<u8").reshape(-1).astype(np.int64)


@contextmanager
def _gc_paused() -> Iterator[None]:
    """Pause the cyclic GC while building millions of short-lived tuples (it would rescan them)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class _FastPathUnavailable(Exception):
    """The storage needs the generic rosbags iteration."""


def _mcap_message_indexes(blob: np.ndarray, start: int, length: int) -> dict[int, np.ndarray]:
    """``{channel: (k, 2) uint64 [log_time, offset]}`` from the message-index records of one chunk."""
    result: dict[int, np.ndarray] = {}
    position, end = start, start + length
    raw = blob[start:end].tobytes()
    while position < end:
        local = position - start
        op = raw[local]
        (size,) = struct.unpack_from("<Q", raw, local + 1)
        if op == 0x07:
            channel, array_bytes = struct.unpack_from("<HI", raw, local + 9)
            entries = np.frombuffer(raw, dtype="<u8", count=array_bytes // 8, offset=local + 15).reshape(-1, 2)
            result[channel] = entries
        position += 9 + size
    return result


def _read_mcap(storage: McapReader, path: Path, wanted: dict[int, Key], with_data: bool,
               parts: dict[Key, _Partial]) -> None:
    if not storage.chunks:
        raise _FastPathUnavailable("no chunk index")
    file_bytes = np.memmap(path, dtype=np.uint8, mode="r")
    extra: list[np.ndarray] = []
    extra_size = file_bytes.shape[0]
    per_channel: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {cid: [] for cid in wanted}
    for chunk in storage.chunks:
        if not any(chunk.channel_count.get(cid, 0) for cid in wanted):
            continue
        if not chunk.message_index_offsets or not chunk.message_index_length:
            raise _FastPathUnavailable("chunk without message index")
        data_start = chunk.chunk_start_offset + _CHUNK_HEADER + len(chunk.compression) + 8
        data_end = data_start + chunk.compressed_size
        if data_end > file_bytes.shape[0]:
            raise BagError(path, "corrupt or truncated bag (a chunk extends past the end of the file)")
        (crc,) = struct.unpack_from("<I", file_bytes[chunk.chunk_start_offset + 33:
                                                     chunk.chunk_start_offset + 37].tobytes())
        if with_data and chunk.compression:
            from rosbags.rosbag2.storage_mcap import decompress

            try:
                raw = decompress(file_bytes[data_start:data_end].tobytes(), chunk.compression,
                                 chunk.uncompressed_size, crc)
            except Exception as exc:
                raise BagError(path, describe_error(exc)) from exc
            base = extra_size
            extra.append(np.frombuffer(raw, dtype=np.uint8))
            extra_size += len(raw)
            chunk_size = len(raw)
        else:
            if with_data and crc and zlib.crc32(file_bytes[data_start:data_end]) != crc:
                raise BagError(path, "corrupt bag (chunk checksum mismatch)")
            base = data_start
            chunk_size = chunk.uncompressed_size
        index_start = chunk.chunk_start_offset + chunk.chunk_length
        indexes = _mcap_message_indexes(file_bytes, index_start, chunk.message_index_length)
        for cid in wanted:
            entries = indexes.get(cid)
            if entries is None or entries.shape[0] == 0:
                continue
            relative = entries[:, 1].astype(np.int64)
            if relative.min() < 0 or relative.max() + _MESSAGE_HEADER > chunk_size:
                raise BagError(path, "corrupt bag (message index points outside its chunk)")
            per_channel[cid].append((entries[:, 0].astype(np.int64), relative + base))
    blob = np.concatenate([file_bytes, *extra]) if extra else file_bytes
    if with_data and not extra:
        blob = np.asarray(file_bytes)
    for cid, key in wanted.items():
        found = per_channel[cid]
        if not found:
            continue
        times = np.concatenate([f[0] for f in found])
        records = np.concatenate([f[1] for f in found])
        order = np.argsort(times, kind="stable")
        times, records = times[order], records[order]
        part = parts.setdefault(key, _Partial())
        part.times.append(times)
        if not with_data:
            continue
        head = np.ascontiguousarray(gather(blob, records, 11))
        ops = head[:, 0]
        sizes = head[:, 1:9].copy().view("<u8").reshape(-1).astype(np.int64)
        channels = head[:, 9:11].copy().view("<u2").reshape(-1)
        if np.any(ops != _MESSAGE_OP) or np.any(channels != cid) or np.any(sizes < 22):
            raise _FastPathUnavailable("message index does not match the chunk records")
        offsets = records + _MESSAGE_HEADER
        lengths = sizes - 22
        if np.any(offsets + lengths > blob.shape[0]):
            raise BagError(path, "corrupt bag (a message extends past its chunk)")
        part.pieces.append(RawPiece(blob, offsets, lengths))


#: the table scan is split into this many id ranges, read concurrently (SQLite runs without the GIL)
_SQLITE_PARTS = max(1, min(4, os.cpu_count() or 1))
#: ... and into more for a big file: each range's data stay far below SQLite's largest value (1e9 bytes)
_SQLITE_RANGE_BYTES = 256 * 2**20


def _sqlite_integers(text: str | None) -> np.ndarray:
    """int64 array from SQLite's comma-separated ``group_concat`` of integers (NULL: empty)."""
    if not text:
        return np.zeros(0, np.int64)
    return np.fromstring(text, dtype=np.int64, sep=",")


def _sqlite_scan_query(topic_ids: list[int], with_data: bool) -> str:
    """One row: the topic ids, ids, stamps and data lengths of the wanted rows as text, their data as one blob.

    One aggregate per column over every wanted row (not one per topic: SQLite's cost is per
    aggregate and row); numpy separates the topics afterwards.
    """
    columns = ["group_concat(topic_id, ',')", "group_concat(id, ',')", "group_concat(timestamp, ',')"]
    if with_data:
        columns += ["group_concat(length(data), ',')", "CAST(group_concat(data, x'') AS BLOB)"]
    wanted = ", ".join(str(int(tid)) for tid in topic_ids)
    return f"SELECT {', '.join(columns)} FROM messages WHERE id BETWEEN ? AND ? AND topic_id IN ({wanted})"


def _sqlite_read_range(path: Path, query: str, first_id: int, last_id: int) -> tuple:
    """``query`` over the rows with ids in [first_id, last_id], on a connection of its own (read-only,
    immutable, as rosbags opens the file), so that the ranges are read concurrently."""
    db = connect(path)
    try:
        return db.execute(query, (first_id, last_id)).fetchone()
    finally:
        db.close()


@dataclass
class _SqliteRows:
    """The wanted rows of every id range, in range order: (n,) topic ids, row ids, stamps, lengths;
    ``offsets`` of each row's data in ``blob``."""

    topic_ids: np.ndarray
    row_ids: np.ndarray
    stamps: np.ndarray
    lengths: np.ndarray | None
    offsets: np.ndarray | None
    blob: np.ndarray | None

    @classmethod
    def from_aggregates(cls, rows: list[tuple], with_data: bool) -> _SqliteRows:
        """Parse the aggregate rows of :func:`_sqlite_scan_query`; a NULL anywhere (group_concat skips
        it), a non-integer value or data of another length than ``length(data)`` leaves the fast path."""
        try:
            columns = [np.concatenate([_sqlite_integers(row[c]) for row in rows]) for c in range(4 if with_data else 3)]
        except ValueError as exc:  # a non-integer stamp: let rosbags read it as it can
            raise _FastPathUnavailable(f"sqlite3 column: {exc}") from exc
        if any(column.shape != columns[1].shape for column in columns):  # row ids are never NULL
            raise _FastPathUnavailable("sqlite3 aggregates of unequal length")
        if not with_data:
            return cls(columns[0], columns[1], columns[2], None, None, None)
        blobs = [row[4] for row in rows if row[4]]
        blob = np.frombuffer(blobs[0], dtype=np.uint8) if len(blobs) == 1 else \
            np.concatenate([np.frombuffer(b, dtype=np.uint8) for b in blobs]) if blobs else np.zeros(0, np.uint8)
        lengths = columns[3]
        if int(lengths.sum()) != blob.shape[0]:
            raise _FastPathUnavailable("sqlite3 data of another length than length(data)")
        offsets = np.zeros_like(lengths)
        np.cumsum(lengths[:-1], out=offsets[1:])
        return cls(columns[0], columns[1], columns[2], lengths, offsets, blob)

    def add_topic(self, topic_id: int, key: Key, parts: dict[Key, _Partial]) -> None:
        """The rows of one topic, in bag order (stamp, then id: rosbags' order), into ``parts[key]``."""
        rows = np.flatnonzero(self.topic_ids == topic_id)
        if not rows.size:
            return
        stamps, row_ids = self.stamps[rows], self.row_ids[rows]
        if np.any(stamps[1:] < stamps[:-1]) or np.any(row_ids[1:] <= row_ids[:-1]):
            order = np.lexsort((row_ids, stamps))
            rows, stamps = rows[order], stamps[order]
        part = parts.setdefault(key, _Partial())
        part.times.append(stamps)
        if self.blob is not None:
            part.pieces.append(RawPiece(self.blob, self.offsets[rows], self.lengths[rows]))  # type: ignore[index]


def _read_sqlite(path: Path, wanted: set[Key], with_data: bool, parts: dict[Key, _Partial]) -> None:
    """Every wanted topic in one table scan, its rows aggregated inside SQLite.

    SQLite concatenates the topic ids, ids, stamps and data lengths of the wanted rows as text and
    their data as one blob, so no Python object is made per message; numpy then separates the
    topics and orders each by (timestamp, id), the order of rosbags' reader. The scan is split into
    id ranges read concurrently, one connection each. A value that is not an integer where one
    belongs, a NULL, or data beyond SQLite's largest blob leaves the fast path (the generic
    iteration reads the same rows).
    """
    db = connect(path)
    try:
        ids = {int(tid): (name, mtype) for tid, name, mtype in db.execute("SELECT id, name, type FROM topics")
               if (name, mtype) in wanted}
        first_id, last_id = db.execute("SELECT min(id), max(id) FROM messages").fetchone()
    finally:
        db.close()
    if first_id is None or not ids:
        return
    count = max(_SQLITE_PARTS, -(-path.stat().st_size // _SQLITE_RANGE_BYTES))
    bounds = np.linspace(int(first_id) - 1, int(last_id), count + 1).astype(np.int64)
    ranges = [(int(lo) + 1, int(hi)) for lo, hi in itertools.pairwise(bounds) if hi > lo]
    query = _sqlite_scan_query(sorted(ids), with_data)
    with ThreadPoolExecutor(max_workers=min(len(ranges), _SQLITE_PARTS)) as pool:
        try:
            rows = list(pool.map(lambda r: _sqlite_read_range(path, query, *r), ranges))
        except Exception as exc:  # apsw.TooBigError: the data beyond SQLite's largest blob
            raise _FastPathUnavailable(f"sqlite3 aggregate: {exc}") from exc
    scanned = _SqliteRows.from_aggregates(rows, with_data)
    for tid, key in sorted(ids.items()):
        scanned.add_topic(tid, key, parts)


def _read_generic(reader: Reader, keys: Collection[Key], with_data: bool) -> dict[Key, _Partial]:
    connections = [c for c in reader.connections if (c.topic, c.msgtype) in keys]
    stamps: dict[Key, list[int]] = {k: [] for k in keys}
    datas: dict[Key, list[bytes]] = {k: [] for k in keys}
    if connections:
        for connection, stamp, data in reader.messages(connections):
            key = (connection.topic, connection.msgtype)
            stamps[key].append(stamp)
            if with_data:
                datas[key].append(data)
    parts: dict[Key, _Partial] = {}
    for key in keys:
        part = parts.setdefault(key, _Partial())
        if not stamps[key]:
            continue
        part.times.append(np.asarray(stamps[key], dtype=np.int64))
        if with_data:
            lengths = np.fromiter(map(len, datas[key]), dtype=np.int64, count=len(datas[key]))
            offsets = np.zeros_like(lengths)
            np.cumsum(lengths[:-1], out=offsets[1:])
            part.pieces.append(RawPiece(np.frombuffer(b"".join(datas[key]), np.uint8), offsets, lengths))
    return parts


def _decompressed(part: _Partial) -> _Partial:
    """The messages of a bag written with ``compression_mode: message`` (each one zstd-compressed by
    rosbag2, the only format rosbag2 and rosbags know), decompressed one by one into one buffer."""
    try:
        from compression import zstd  # type: ignore[import-not-found]  # Python >= 3.14
    except ImportError:
        from backports import zstd  # type: ignore[no-redef]  # rosbags' own dependency before 3.14
    pieces = []
    for piece in part.pieces:
        spans = zip(piece.offsets.tolist(), piece.lengths.tolist(), strict=True)
        messages = [zstd.decompress(piece.blob[o:o + n].tobytes()) for o, n in spans]
        lengths = np.fromiter(map(len, messages), dtype=np.int64, count=len(messages))
        offsets = np.zeros_like(lengths)
        np.cumsum(lengths[:-1], out=offsets[1:])
        pieces.append(RawPiece(np.frombuffer(b"".join(messages), np.uint8), offsets, lengths))
    return _Partial(part.times, pieces)


def _read_fast(reader: Reader, keys: list[Key], with_data: bool) -> dict[Key, _Partial]:
    try:
        return _read_fast_storages(reader, keys, with_data)
    except AttributeError as exc:  # rosbags internals changed (pinned 0.11.9): take the generic path
        raise _FastPathUnavailable(str(exc)) from exc


def _read_fast_storages(reader: Reader, keys: list[Key], with_data: bool) -> dict[Key, _Partial]:
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    parts: dict[Key, _Partial] = {}
    with _gc_paused():
        for storage in storages_of(reader):
            if isinstance(storage, McapReader):
                wanted = {cid: (ch.topic, ch.schema) for cid, ch in storage.channels.items()
                          if (ch.topic, ch.schema) in keys}
                if wanted:
                    _read_mcap(storage, Path(str(storage.path)), wanted, with_data, parts)
            elif isinstance(storage, Sqlite3Reader):
                _read_sqlite(Path(str(storage.path)), set(keys), with_data, parts)
            else:
                raise _FastPathUnavailable(type(storage).__name__)
    return parts


def read_raw_messages(reader: Reader, topics: Collection[str] | None = None, *,
                      with_data: bool = True) -> dict[Key, RawMessages]:
    """Receive stamps and serialised bytes of every message of ``topics`` (default: all).

    Parameters
    ----------
    reader : rosbags.rosbag2.Reader
        An open reader (see :func:`taiji2_runtime.bag.reading.open_reader`).
    topics : collection of str, optional
        Topics to read; default every topic.
    with_data : bool
        False reads only the stamps (MCAP: from the indexes, without touching message data).

    Returns
    -------
    dict
        ``{(topic, type): RawMessages}`` for every connection of the selected topics (also those
        without messages).

    Raises
    ------
    BagError
        If a storage file is corrupt.
    """
    keys = sorted({(c.topic, c.msgtype) for c in reader.connections if topics is None or c.topic in topics})
    bag_path = Path(str(reader.path))
    try:
        try:
            parts = _read_fast(reader, keys, with_data)
            if with_data and reader.compression_mode == "message":
                parts = {key: _decompressed(part) for key, part in parts.items()}
        except _FastPathUnavailable:
            with _gc_paused():
                parts = _read_generic(reader, keys, with_data)
    except BagError:
        raise
    except Exception as exc:  # struct, numpy, apsw, decompression: the storage is damaged
        raise BagError(bag_path, describe_error(exc)) from exc
    return _assemble(keys, parts)


def read_sqlite3_bag(bag: Sqlite3Bag, topics: Collection[str] | None = None, *,
                     with_data: bool = True) -> dict[Key, RawMessages]:
    """:func:`read_raw_messages` of a bag opened by :func:`~taiji2_runtime.bag.sqlite3_direct.open_sqlite3_bag`.

    Raises
    ------
    Exception
        Whatever the storage raises (apsw's errors, a non-integer stamp): the caller then reads
        the bag through rosbags' ``Reader``, which words the problem.
    """
    keys = sorted({(c.topic, c.msgtype) for c in bag.connections if topics is None or c.topic in topics})
    parts: dict[Key, _Partial] = {}
    with _gc_paused():
        for path in bag.files:
            _read_sqlite(path, set(keys), with_data, parts)
    return _assemble(keys, parts)


def _assemble(keys: list[Key], parts: dict[Key, _Partial]) -> dict[Key, RawMessages]:
    result: dict[Key, RawMessages] = {}
    for key in keys:
        part = parts.get(key, _Partial())
        times = np.concatenate(part.times) if part.times else np.zeros(0, np.int64)
        result[key] = RawMessages(key[0], key[1], times, part.pieces)
    return result
