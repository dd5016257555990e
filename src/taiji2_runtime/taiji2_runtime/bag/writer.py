"""Crash-safe rosbag2 writer: a bag that opens at any instant, even after SIGKILL.

rosbags writes a storage file (MCAP or sqlite3) that is only readable once closed, so the writer
keeps two files open and writes every message to both:

* a *segment* file (``<bag>_<k>.mcap``), closed every ``segment_period_s`` of wall time and at
  the end, which is what a cleanly closed bag consists of (one file for recordings shorter than a
  segment);
* a short *journal* file (``<bag>_<k>_part<j>.mcap``), closed every ``journal_period_s``
  (0.5 s) of wall time.

Files are written in ``.incoming/`` and moved into the bag once closed; after each move the
bag's ``metadata.yaml`` is replaced atomically (write + rename) so that it lists exactly the closed
segments plus the closed journals of the open segment. When a segment closes, its journals are
dropped from the metadata, then deleted. A SIGKILL therefore loses at most the open journal (the
last ``journal_period_s`` plus the time to close a file); every listed file is complete. The
metadata follows rosbag2 version 8 (readable by rosbags, ``ros2 bag`` Humble and later, and MCAP
tools, which also find the message definitions in every file). Intermediate metadata is written
as JSON (a YAML subset) for speed; the final one as block YAML.

A storage failure (disk full, file-size limit, I/O error) never ends the recording: the open files
are dropped (at most one journal period of data), the closed journals of the open segment become
files of the bag in their own right, and messages are counted as dropped until a retry (every
``retry_period_s``) opens a new segment that can be written. What the bag listed stays readable.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rosbags.rosbag2.writer
import yaml
from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.metadata import dump_qos_v8 as _rosbags_dump_qos_v8
from rosbags.typesys.store import Typestore

from taiji2_runtime.bag.errors import BagError


class DefinitionUnavailable(KeyError):
    """No message definition whose type hash is the one the graph uses for the type (the topic is left out)."""


def definition_and_hash(store: Typestore, msgtype: str) -> tuple[str, str]:
    """The definition to embed for ``msgtype`` and its type hash, both from one type store.

    The hash must be that of the embedded definition (readers such as rosbags' ``AnyReader`` recompute it and
    refuse the whole bag otherwise) and the definition must be the one on the wire. On the wire the type is
    rosidl's Jazzy one (``typestore.rihs01``, what every endpoint advertises), so the first of ``store`` (the
    workspace's: Humble's standard definitions), Jazzy's definitions, and Jazzy's as rosidl hashes them (``char``
    as ``uint8``) whose hash equals it is used: e.g. ``rosbag2_interfaces/msg/WriteSplitEvent``, which Jazzy
    extended, gets Jazzy's definition with Jazzy's hash. With ``ROS_DISTRO=humble`` (no hashes on the wire)
    ``store``'s definition is embedded with its own hash; a type only ``store`` knows (registered from a bag)
    likewise.

    Raises
    ------
    KeyError
        ``msgtype`` is unknown to ``store``.
    DefinitionUnavailable
        no known definition has the graph's hash.
    """
    from taiji2_runtime.typestore import jazzy_typestore, rihs01, rosidl_hash_typestore

    if msgtype not in store.fielddefs:
        raise KeyError(f"message type {msgtype!r} is unknown to the type store")
    try:
        wire = None if os.environ.get("ROS_DISTRO") == "humble" else rihs01(msgtype)
    except KeyError:
        wire = None
    for candidate in (store, jazzy_typestore(), rosidl_hash_typestore()):
        if msgtype not in candidate.fielddefs:
            continue
        digest = candidate.hash_rihs01(msgtype)
        if wire is None or digest == wire:
            return candidate.generate_msgdef(msgtype, ros_version=2)[0], digest
    raise DefinitionUnavailable(f"no definition of {msgtype} with the graph's type hash {wire}")


@functools.lru_cache(maxsize=1024)
def _dumped_qos(profiles: tuple[Qos, ...]) -> str:
    return _rosbags_dump_qos_v8(list(profiles))


def dump_qos_v8(qos: list[Qos]) -> str:
    """rosbags' ``dump_qos_v8`` (the YAML text of a topic's offered QoS profiles), computed once per profile list.

    Every journal file (2 a second) re-adds each topic and writes its own metadata, and rosbags renders each
    topic's QoS list as YAML with ruamel every time: ~3 ms a topic, which made the bag rotation most of the
    recorder's CPU (cProfile of ``taiji2 bag record`` in ``taiji2 experiment --link deep_space``). The text
    depends only on the (immutable) profiles, so rosbags' writer gets this memoised function as well."""
    return _dumped_qos(tuple(qos))


rosbags.rosbag2.writer.dump_qos_v8 = dump_qos_v8  # Writer.add_connection / Writer.close look it up there

STORAGES = {"mcap": (StoragePlugin.MCAP, ".mcap"), "sqlite3": (StoragePlugin.SQLITE3, ".db3")}
_VERSION = 8
#: what a full disk, a file-size limit or an I/O error raises from the storage plugins
_STORAGE_ERRORS = (OSError, sqlite3.Error)
_INCOMING = ".incoming"


@dataclass
class _Topic:
    handle: int
    name: str
    msgtype: str
    msgdef: str
    digest: str
    qos: list[Qos]


@dataclass
class FileStats:
    """A closed storage file of the bag and what it holds (stamps in ns)."""

    name: str
    start_ns: int = 2**63 - 1
    end_ns: int = 0
    count: int = 0
    per_topic: dict[int, int] = field(default_factory=dict)


class _JournalWriter(Writer):
    """rosbags' :class:`Writer` whose ``close`` renders the file's metadata as JSON (a YAML subset), not with ruamel.

    rosbags renders it twice per file (the storage file's embedded copy and the work directory's
    ``metadata.yaml``, which is discarded here): for a journal, closed twice a second, that was most of what
    was left of the recorder's CPU for the rotation. The same content (rosbags 0.11's ``Writer.close``, no
    compression: the bag writer never sets it); segment files keep rosbags' own ``close``."""

    def close(self) -> None:
        storage = self.storage
        if storage is None or self.compression_mode != CompressionMode.NONE:
            super().close()
            return
        count = sum(self.counts.values())
        timing = {"starting_time": {"nanoseconds_since_epoch": self.min_timestamp},
                  "duration": {"nanoseconds": max(0, self.max_timestamp - self.min_timestamp)}}
        info = {
            "version": self.version, "storage_identifier": self.storage_plugin.name.lower(),
            "relative_file_paths": [storage.path.name], "duration": timing["duration"],
            "starting_time": timing["starting_time"], "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": c.topic, "type": c.msgtype,
                                    "serialization_format": c.ext.serialization_format,
                                    "offered_qos_profiles": dump_qos_v8(c.ext.offered_qos_profiles),
                                    "type_description_hash": c.digest},
                 "message_count": self.counts[c.id]}
                for c in self.connections if isinstance(c.ext, ConnectionExtRosbag2)],
            "compression_format": "", "compression_mode": "",
            "files": [{"path": storage.path.name, **timing, "message_count": count}],
            "custom_data": self.custom_data or None, "ros_distro": "rosbags",
        }
        storage.close(self.version, json.dumps(info))
        self.storage = None
        temporary = self.metapath.with_suffix(".yaml.tmp")
        temporary.write_text(json.dumps({"rosbag2_bagfile_information": info}), "utf8")
        temporary.replace(self.metapath)


class _StorageFile:
    """One rosbags :class:`Writer` in ``.incoming/<name>/`` whose file moves into the bag on close (a journal's:
    :class:`_JournalWriter`)."""

    def __init__(self, bag: Path, name: str, storage: str, topics: list[_Topic], journal: bool = False) -> None:
        plugin, self._suffix = STORAGES[storage]
        self._bag = bag
        self._work = bag / _INCOMING / name
        self.stats = FileStats(name + self._suffix)
        self._writer = (_JournalWriter if journal else Writer)(self._work, version=_VERSION, storage_plugin=plugin)
        self._writer.open()
        self._connections: dict[int, Connection] = {}
        for topic in topics:
            self.add(topic)

    def add(self, topic: _Topic) -> None:
        self._connections[topic.handle] = self._writer.add_connection(
            topic.name, topic.msgtype, msgdef=topic.msgdef, rihs01=topic.digest, offered_qos_profiles=topic.qos)
        self.stats.per_topic.setdefault(topic.handle, 0)

    def write(self, handle: int, stamp_ns: int, data: bytes) -> None:
        self._writer.write(self._connections[handle], stamp_ns, data)
        stats = self.stats
        stats.count += 1
        stats.per_topic[handle] += 1
        if stamp_ns < stats.start_ns:
            stats.start_ns = stamp_ns
        if stamp_ns > stats.end_ns:
            stats.end_ns = stamp_ns

    def close(self, custom_data: dict[str, str]) -> FileStats:
        """Close, move the storage file into the bag, remove the work directory."""
        for key, value in custom_data.items():
            self._writer.set_custom_data(key, value)
        self._writer.close()
        produced = self._work / f"{self._work.name}{self._suffix}"
        os.replace(produced, self._bag / self.stats.name)
        shutil.rmtree(self._work, ignore_errors=True)
        return self.stats

    def abort(self) -> None:
        try:
            self._writer.abort()
        finally:
            shutil.rmtree(self._work, ignore_errors=True)


class BagWriter:
    """Writes a rosbag2 bag that stays readable if the process dies at any instant.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory to create (must not exist).
    store : rosbags.typesys.store.Typestore
        Type store that defines every recorded type (its definitions are embedded in the bag).
    storage : str
        ``"mcap"`` (default) or ``"sqlite3"``.
    journal_period_s : float
        Wall time [s] after which the open journal file is closed and listed: the most a SIGKILL
        can lose.
    segment_period_s : float
        Wall time [s] after which the open segment file is closed and a new one started
        (``inf``: one file per recording).
    retry_period_s : float
        Wall time [s] between attempts to write again after a storage failure (each attempt opens
        two files; what arrives in between is dropped and counted).

    Raises
    ------
    BagError
        If ``path`` exists or cannot be created, or ``storage`` is unknown.
    """

    def __init__(self, path: str | Path, store: Typestore, *, storage: str = "mcap",
                 journal_period_s: float = 0.5, segment_period_s: float = 300.0, retry_period_s: float = 0.5
                 ) -> None:
        self.path = Path(path)
        if storage not in STORAGES:
            raise BagError(self.path, f"unknown storage {storage!r} (expected mcap or sqlite3)")
        if not journal_period_s > 0 or not segment_period_s > 0 or not retry_period_s > 0:
            raise BagError(self.path, "journal, segment and retry periods must be positive")
        if self.path.exists():
            raise BagError(self.path, "already exists; choose another output (-o) or remove it")
        try:
            (self.path / _INCOMING).mkdir(parents=True)
        except OSError as exc:
            raise BagError(self.path, f"cannot create the bag directory ({exc.strerror or exc})") from exc
        self.storage = storage
        self._store = store
        self._journal_period_s = float(journal_period_s)
        self._segment_period_s = float(segment_period_s)
        self._topics: list[_Topic] = []
        self._by_name: dict[tuple[str, str], int] = {}
        self._custom: dict[str, str] = {}
        self._segments: list[FileStats] = []
        self._journals: list[FileStats] = []
        self._segment: _StorageFile | None = None
        self._segment_opened = 0.0
        self._journal: _StorageFile | None = None
        self._journal_opened = 0.0
        self._segment_index = 0
        self._journal_index = 0
        self._closed = False
        self.retry_period_s = float(retry_period_s)
        #: the storage failure in force (None while writing works), the last one, and when (monotonic s)
        self.storage_error: str | None = None
        self.last_storage_error: str | None = None
        self._failed_at = 0.0
        #: messages not written because the storage failed (the dropped open files included)
        self.dropped_count = 0
        #: storage failures so far
        self.failure_count = 0
        self._publish_metadata(final=False)

    # -- topics and custom data ----------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, offered_qos: list[Qos] | None = None) -> int:
        """Register a topic (idempotent per (topic, type)); returns the handle for :meth:`write`.

        Raises
        ------
        KeyError
            If ``msgtype`` is unknown to the type store.
        """
        key = (topic, msgtype)
        if key in self._by_name:
            return self._by_name[key]
        msgdef, digest = definition_and_hash(self._store, msgtype)
        entry = _Topic(len(self._topics), topic, msgtype, msgdef, digest, list(offered_qos or []))
        self._topics.append(entry)
        self._by_name[key] = entry.handle
        for open_file in (self._segment, self._journal):
            if open_file is not None:
                open_file.add(entry)
        return entry.handle

    def set_custom_data(self, key: str, value: str) -> None:
        """Set a ``custom_data`` entry of the metadata (written with the next closed file)."""
        self._custom[str(key)] = str(value)

    @property
    def custom_data(self) -> dict[str, str]:
        """The custom data set so far."""
        return dict(self._custom)

    @property
    def message_count(self) -> int:
        """Messages written so far (including those in open files)."""
        closed = sum(s.count for s in self._segments)
        return closed + (self._segment.stats.count if self._segment is not None else 0)

    # -- writing ---------------------------------------------------------------------------------
    def write(self, handle: int, stamp_ns: int, data: bytes) -> None:
        """Write one serialised message (CDR with encapsulation header) stamped ``stamp_ns`` [ns].

        A storage failure is recorded in :attr:`storage_error` and counted, never raised.
        """
        if self._closed:
            raise BagError(self.path, "write after close")
        now = time.monotonic()
        if self.storage_error is not None and now - self._failed_at < self.retry_period_s:
            self.dropped_count += 1
            return
        try:
            if self._segment is None:
                self._segment = _StorageFile(self.path, f"{self.path.name}_{self._segment_index}", self.storage,
                                             self._topics)
                self._segment_opened = now
            if self._journal is None:
                name = f"{self.path.name}_{self._segment_index}_part{self._journal_index}"
                self._journal = _StorageFile(self.path, name, self.storage, self._topics, journal=True)
                self._journal_index += 1
                self._journal_opened = now
            self._segment.write(handle, stamp_ns, data)
            self._journal.write(handle, stamp_ns, data)
        except _STORAGE_ERRORS as exc:
            self._fail(exc, now, pending=1)
            return
        self.storage_error = None
        if now - self._journal_opened >= self._journal_period_s:
            self.poll(now)

    def poll(self, now: float | None = None) -> None:
        """Close the journal / segment when their wall-time period is over (call a few times per second)."""
        now = time.monotonic() if now is None else now
        try:
            if self._segment is not None and now - self._segment_opened >= self._segment_period_s:
                self._close_segment()
            elif self._journal is not None and now - self._journal_opened >= self._journal_period_s:
                self._close_journal()
        except _STORAGE_ERRORS as exc:
            self._fail(exc, now)

    def close(self) -> None:
        """Close the open files and write the final metadata; removes ``.incoming/``."""
        if self._closed:
            return
        try:
            if self._segment is not None:
                self._close_segment(final=True)
            else:
                self._publish_metadata(final=True)
        except _STORAGE_ERRORS as exc:
            self._fail(exc, time.monotonic())
            try:
                self._publish_metadata(final=True)
            except OSError:
                pass  # the last metadata written still lists only complete files
        self._closed = True
        shutil.rmtree(self.path / _INCOMING, ignore_errors=True)

    def abort(self) -> None:
        """Drop the open files (what was published stays a readable bag)."""
        for open_file in (self._journal, self._segment):
            if open_file is not None:
                open_file.abort()
        self._journal = self._segment = None
        self._closed = True

    # -- internals -------------------------------------------------------------------------------
    def _fail(self, exc: Exception, now: float, pending: int = 0) -> None:
        """Drop the open files after a storage failure; their closed journals stay in the bag."""
        # the open journal's messages: those of the open segment not in a closed journal
        lost = pending + (self._segment.stats.count - sum(j.count for j in self._journals)
                          if self._segment is not None else 0)
        for open_file in (self._journal, self._segment):
            if open_file is not None:
                try:
                    open_file.abort()
                except Exception:  # a writer broken by the failure: its work directory is gone anyway
                    pass
        self._journal = self._segment = None
        # the open segment is lost: its closed journals are the bag's record of that time
        self._segments.extend(self._journals)
        self._journals = []
        self._segment_index += 1
        self._journal_index = 0
        self.dropped_count += lost
        self.failure_count += 1
        self.storage_error = self.last_storage_error = getattr(exc, "strerror", None) or str(exc)
        self._failed_at = now
        try:
            self._publish_metadata(final=False)
        except OSError:
            pass  # the metadata on disk lists the same files (journals were listed already)

    def _close_journal(self) -> None:
        if self._journal is not None:
            self._journals.append(self._journal.close(self._custom))  # on failure still open: _fail drops it
            self._journal = None
            self._publish_metadata(final=False)

    def _close_segment(self, final: bool = False) -> None:
        self._close_journal()
        if self._segment is None:
            return
        self._segments.append(self._segment.close(self._custom))  # on failure still open: _fail drops it
        self._segment = None
        dropped, self._journals = self._journals, []
        self._publish_metadata(final=final)
        for stats in dropped:
            try:
                (self.path / stats.name).unlink()
            except OSError:
                pass
        self._segment_index += 1
        self._journal_index = 0

    def _publish_metadata(self, final: bool) -> None:
        files = [*self._segments, *self._journals]
        counts = [0] * len(self._topics)
        for stats in files:
            for handle, count in stats.per_topic.items():
                counts[handle] += count
        total = sum(s.count for s in files)
        start = min((s.start_ns for s in files if s.count), default=0)
        end = max((s.end_ns for s in files if s.count), default=0)
        info: dict[str, Any] = {
            "version": _VERSION,
            "storage_identifier": self.storage,
            "relative_file_paths": [s.name for s in files],
            "duration": {"nanoseconds": max(0, end - start)},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": total,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.msgtype, "serialization_format": "cdr",
                                    "offered_qos_profiles": dump_qos_v8(t.qos), "type_description_hash": t.digest},
                 "message_count": counts[t.handle]}
                for t in self._topics],
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": s.name, "starting_time": {"nanoseconds_since_epoch": s.start_ns if s.count else 0},
                       "duration": {"nanoseconds": max(0, s.end_ns - s.start_ns) if s.count else 0},
                       "message_count": s.count} for s in files],
            "custom_data": dict(self._custom) or None,
            "ros_distro": "taiji2 (rosbags)",
        }
        document = {"rosbag2_bagfile_information": info}
        text = (yaml.safe_dump(document, sort_keys=False, default_flow_style=False) if final
                else json.dumps(document))
        target = self.path / "metadata.yaml"
        temporary = self.path / "metadata.yaml.tmp"
        temporary.write_text(text, encoding="utf-8")
        os.replace(temporary, target)
