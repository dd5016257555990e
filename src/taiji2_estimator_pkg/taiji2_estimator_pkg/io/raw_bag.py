"""Load the raw topics of an experiment bag into numpy arrays, for offline calibration.

Reads any ROS 2 bag that follows the raw-data contract (``docs/interfaces.md``): MCAP or
sqlite3, written by this project, by ``ros2 bag`` or by any other tool, with or without truth
topics and provenance. Messages are decoded in bulk (numpy views of the fixed CDR layout; see
:mod:`taiji2_runtime.bag.bulk_decode`), so a 3-hour two-GRS bag loads in a fraction of a second.

What is checked here is the *structure*: presence and type of each raw topic, embedded
definitions, decodability, ``frame_id`` / ``grs_id`` against the topic, duplicate and out-of-order
header stamps. Messages that cannot be trusted structurally are dropped and counted per reason;
stamp problems are only counted (flagged), the samples stay, in bag order. Value checks (NaN/Inf,
quaternion norm and sign, saturation, gaps) belong to the estimator core, which gets every value.

Times: ``stamp_ns`` is the header stamp [ns] exactly, ``t_s`` the same in seconds (float64),
``receive_ns`` the bag (receive) stamp [ns].
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from taiji2_model.contract import (
    COMMAND_TOPIC,
    GRS_IDS,
    GRS_TOPICS,
    RAW_FRAME_IDS,
    RAW_TOPICS,
    STAR_TRACKER_TOPIC,
)
from taiji2_runtime.bag.bulk_decode import decode_messages
from taiji2_runtime.bag.bulk_read import Key, RawMessages, read_raw_messages, read_sqlite3_bag
from taiji2_runtime.bag.errors import BagError
from taiji2_runtime.bag.reading import TypeCheck, check_types, custom_data, open_reader, storage_identifier
from taiji2_runtime.bag.sqlite3_direct import open_sqlite3_bag
from taiji2_runtime.typestore import contract_typestore

__all__ = ["CommandData", "GrsData", "RawBagError", "RawExperiment", "StarTrackerData", "TopicReport",
           "load_raw_bag"]

_NS = 1_000_000_000


class RawBagError(BagError):
    """A bag that cannot give the raw data (unreadable, not a bag, a raw topic missing or unusable)."""


@dataclass
class TopicReport:
    """Structural findings on one raw topic.

    Attributes
    ----------
    topic, expected_type : str
        The contract's topic and type.
    found_types : list of str
        Types the bag holds on the topic.
    messages : int
        Messages on the topic in the bag (all types).
    loaded : int
        Samples in the arrays.
    dropped : collections.Counter
        Messages left out, per reason: ``wrong_type``, ``undecodable``, ``frame_id_mismatch``,
        ``grs_id_mismatch``.
    flagged : collections.Counter
        Samples kept but suspicious, per reason: ``duplicate_stamp`` (equal to the latest earlier
        stamp), ``out_of_order_stamp`` (earlier than it).
    notes : list of str
        Details (the wrong types and frame ids seen, the first decode errors).
    """

    topic: str
    expected_type: str
    found_types: list[str] = field(default_factory=list)
    messages: int = 0
    loaded: int = 0
    dropped: Counter = field(default_factory=Counter)
    flagged: Counter = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)

    @property
    def clean(self) -> bool:
        """True when nothing was dropped or flagged."""
        return not self.dropped and not self.flagged

    def line(self) -> str:
        """One-line summary."""
        parts = [f"{self.topic}: {self.loaded}/{self.messages} loaded"]
        if self.dropped:
            parts.append("dropped " + ", ".join(f"{k} {v}" for k, v in sorted(self.dropped.items())))
        if self.flagged:
            parts.append("flagged " + ", ".join(f"{k} {v}" for k, v in sorted(self.flagged.items())))
        if self.notes:
            parts.append("; ".join(self.notes))
        return "; ".join(parts)


@dataclass(frozen=True)
class StarTrackerData:
    """Star-tracker readouts (n samples, bag order).

    Attributes
    ----------
    stamp_ns, receive_ns : numpy.ndarray
        (n,) int64 header and bag stamps [ns].
    t_s : numpy.ndarray
        (n,) header stamp [s].
    quat_xyzw : numpy.ndarray
        (n, 4) orientation of the CRF in the inertial frame (x, y, z, w), as read.
    cov_rad2 : numpy.ndarray
        (n, 9) row-major attitude covariance [rad^2].
    """

    stamp_ns: np.ndarray
    receive_ns: np.ndarray
    t_s: np.ndarray
    quat_xyzw: np.ndarray
    cov_rad2: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class GrsData:
    """Electrode voltages of one GRS (n samples, bag order).

    Attributes
    ----------
    stamp_ns, receive_ns : numpy.ndarray
        (n,) int64 header and bag stamps [ns].
    t_s : numpy.ndarray
        (n,) header stamp [s].
    voltages_v : numpy.ndarray
        (n, 6) vx1, vx2, vy1, vy2, vz1, vz2 [V].
    grs_id : int
        1 or 2 (every kept sample has it).
    frame_id : str
        ``tmrf1`` or ``tmrf2`` (every kept sample has it).
    """

    stamp_ns: np.ndarray
    receive_ns: np.ndarray
    t_s: np.ndarray
    voltages_v: np.ndarray
    grs_id: int
    frame_id: str

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class CommandData:
    """Maneuver commands (n samples, bag order).

    Attributes
    ----------
    stamp_ns, receive_ns : numpy.ndarray
        (n,) int64 header and bag stamps [ns].
    t_s : numpy.ndarray
        (n,) header stamp [s].
    torque_n_m : numpy.ndarray
        (n, 3) commanded torque about the CRF axes [N m].
    force_n : numpy.ndarray
        (n, 3) commanded force [N].
    """

    stamp_ns: np.ndarray
    receive_ns: np.ndarray
    t_s: np.ndarray
    torque_n_m: np.ndarray
    force_n: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class RawExperiment:
    """The raw telemetry of one experiment bag.

    Attributes
    ----------
    path : pathlib.Path
        The bag.
    storage : str
        ``mcap`` or ``sqlite3``.
    star_tracker : StarTrackerData
    grs1, grs2 : GrsData or None
        None only when the topic was not required and is absent.
    commands : CommandData or None
        None only when the topic was not required and is absent.
    report : dict
        ``{topic: TopicReport}`` for every raw topic.
    custom_data : dict
        The bag's metadata custom data (provenance), possibly empty.
    packets : taiji2_runtime.packets.report.PacketReport or None
        Per-APID counts when the input was a CCSDS packet file or directory (``storage == "ccsds"``).
    """

    path: Path
    storage: str
    star_tracker: StarTrackerData | None
    grs1: GrsData | None
    grs2: GrsData | None
    commands: CommandData | None
    report: dict[str, TopicReport]
    custom_data: dict[str, str]
    packets: Any = None

    def grs(self, grs_id: int) -> GrsData | None:
        """GRS data by id (1 or 2)."""
        return {1: self.grs1, 2: self.grs2}[grs_id]

    def report_lines(self) -> list[str]:
        """One line per raw topic."""
        return [self.report[t].line() for t in RAW_TOPICS if t in self.report]


def _stamp_flags(stamp_ns: np.ndarray, report: TopicReport) -> None:
    if stamp_ns.shape[0] < 2:
        return
    latest = np.maximum.accumulate(stamp_ns)[:-1]
    following = stamp_ns[1:]
    duplicates = int(np.count_nonzero(following == latest))
    backwards = int(np.count_nonzero(following < latest))
    if duplicates:
        report.flagged["duplicate_stamp"] = duplicates
    if backwards:
        report.flagged["out_of_order_stamp"] = backwards


def _merge(parts: list[RawMessages]) -> RawMessages:
    if len(parts) == 1:
        return parts[0]
    times = np.concatenate([p.log_time_ns for p in parts])
    return RawMessages(parts[0].topic, parts[0].msgtype, times, [piece for p in parts for piece in p.pieces])


def _decode_topic(topic: str, raw: RawMessages, report: TopicReport) -> dict[str, np.ndarray]:
    """Decoded columns of the kept messages of one raw topic, in bag order, plus ``receive_ns``."""
    decoded = decode_messages(contract_typestore(), raw.msgtype, raw.pieces)
    columns = decoded.columns
    keep = decoded.valid.copy()
    if decoded.errors:
        report.dropped["undecodable"] += len(decoded.errors)
        first = next(iter(sorted(decoded.errors.items())))
        report.notes.append(f"message {first[0]} {first[1]}")
    frame = columns["header.frame_id"]
    expected_frame = RAW_FRAME_IDS[topic].encode()
    wrong_frame = keep & (frame != expected_frame)
    if wrong_frame.any():
        report.dropped["frame_id_mismatch"] += int(wrong_frame.sum())
        seen = sorted({v.decode(errors="replace") for v in np.unique(frame[wrong_frame])})
        report.notes.append(f"frame_id {', '.join(repr(s) for s in seen[:3])} instead of {expected_frame.decode()!r}")
        keep &= ~wrong_frame
    if topic in GRS_IDS:
        wrong_id = keep & (columns["grs_id"] != GRS_IDS[topic])
        if wrong_id.any():
            report.dropped["grs_id_mismatch"] += int(wrong_id.sum())
            seen_ids = sorted({int(v) for v in np.unique(columns["grs_id"][wrong_id])})
            report.notes.append(f"grs_id {seen_ids[:3]} instead of {GRS_IDS[topic]}")
            keep &= ~wrong_id
    order = np.argsort(raw.log_time_ns, kind="stable")
    if np.array_equal(order, np.arange(order.shape[0])):
        order = None
    result: dict[str, np.ndarray] = {}
    for name, column in [*columns.items(), ("receive_ns", raw.log_time_ns)]:
        if order is not None:
            column = column[order]
        result[name] = column
    if order is not None:
        keep = keep[order]
    if not keep.all():
        for name in result:
            result[name] = result[name][keep]
    stamp = result["header.stamp.sec"].astype(np.int64) * _NS + result["header.stamp.nanosec"].astype(np.int64)
    result["stamp_ns"] = stamp
    report.loaded = int(stamp.shape[0])
    _stamp_flags(stamp, report)
    return result


def _star_tracker(c: dict[str, np.ndarray]) -> StarTrackerData:
    quat = np.column_stack([c["attitude.x"], c["attitude.y"], c["attitude.z"], c["attitude.w"]])
    return StarTrackerData(c["stamp_ns"], c["receive_ns"].astype(np.int64), c["stamp_ns"] / _NS, quat,
                           np.asarray(c["attitude_covariance"], dtype=np.float64))


def _grs(c: dict[str, np.ndarray], topic: str) -> GrsData:
    volts = np.column_stack([c[k] for k in ("vx1", "vx2", "vy1", "vy2", "vz1", "vz2")])
    return GrsData(c["stamp_ns"], c["receive_ns"].astype(np.int64), c["stamp_ns"] / _NS, volts, GRS_IDS[topic],
                   RAW_FRAME_IDS[topic])


def _commands(c: dict[str, np.ndarray]) -> CommandData:
    torque = np.column_stack([c["wrench.torque.x"], c["wrench.torque.y"], c["wrench.torque.z"]])
    force = np.column_stack([c["wrench.force.x"], c["wrench.force.y"], c["wrench.force.z"]])
    return CommandData(c["stamp_ns"], c["receive_ns"].astype(np.int64), c["stamp_ns"] / _NS, torque, force)


def _read_raw_topics(bag: Path) -> tuple[str, dict[str, str], dict[str, TypeCheck], dict[Key, RawMessages]]:
    """Storage id, custom data, type checks and raw messages of the raw topics of ``bag``.

    A plain sqlite3 directory bag is read directly (without rosbags' per-topic count scan on
    opening); if that fails in any way, or for any other bag, through rosbags' ``Reader``, whose
    errors become :class:`RawBagError`.
    """
    direct = open_sqlite3_bag(bag) if bag.is_dir() else None
    if direct is not None:
        try:
            connections = [c for c in direct.connections if c.topic in RAW_TOPICS]
            raw = read_sqlite3_bag(direct, topics=set(RAW_TOPICS))
            return "sqlite3", direct.custom_data, check_types(connections, contract_typestore()), raw
        except Exception:  # the storage is damaged or unusual: rosbags reads it or names the problem
            pass
    try:
        with open_reader(bag) as reader:
            connections = [c for c in reader.connections if c.topic in RAW_TOPICS]
            checks = check_types(connections, contract_typestore())
            raw = read_raw_messages(reader, topics=set(RAW_TOPICS))
            return storage_identifier(reader), custom_data(reader), checks, raw
    except RawBagError:
        raise
    except BagError as exc:
        raise RawBagError(exc.path, exc.problem) from exc


def load_raw_bag(path: str | Path, *, required: Iterable[str] = tuple(RAW_TOPICS)) -> RawExperiment:
    """Load the raw topics of the experiment bag at ``path``.

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory (with ``metadata.yaml``) or a single ``.mcap`` / ``.db3`` file (packet files:
        :func:`taiji2_ground_pkg.raw_data.load_raw_data`).
    required : iterable of str
        Raw topics that must be present with usable messages (default: all four of the contract).

    Returns
    -------
    RawExperiment
        Arrays per raw topic and the per-topic structural report.

    Raises
    ------
    RawBagError
        (a ValueError) with a one-line message naming the file and the problem: not a bag,
        truncated or corrupt storage, a required raw topic missing, of the wrong type, with a
        definition that differs from the contract's, or without any usable message.
    """
    bag = Path(path)
    required = list(required)
    unknown = [t for t in required if t not in RAW_TOPICS]
    if unknown:
        raise ValueError(f"not raw-contract topics: {', '.join(unknown)}")
    storage, custom, checks, raw = _read_raw_topics(bag)
    reports = {topic: TopicReport(topic, msgtype) for topic, msgtype in RAW_TOPICS.items()}
    usable: dict[str, list[RawMessages]] = {}
    for (topic, msgtype), messages in raw.items():
        report = reports[topic]
        report.found_types.append(msgtype)
        report.messages += messages.count
        if msgtype != RAW_TOPICS[topic]:
            report.dropped["wrong_type"] += messages.count
            report.notes.append(f"{messages.count} messages of type {msgtype}")
            continue
        check = checks.get(msgtype)
        if check is not None and not check.usable:
            raise RawBagError(bag, f"raw topic {topic} ({msgtype}): {check.note}")
        usable.setdefault(topic, []).append(messages)
    problems = []
    for topic in required:
        report = reports[topic]
        if not report.found_types:
            problems.append(f"missing raw topic {topic} ({RAW_TOPICS[topic]})")
        elif topic not in usable:
            problems.append(f"raw topic {topic} has type {', '.join(report.found_types)}, expected {RAW_TOPICS[topic]}")
        elif sum(m.count for m in usable[topic]) == 0:
            problems.append(f"raw topic {topic} has no messages")
    if problems:
        raise RawBagError(bag, "; ".join(problems))
    columns = {}
    for topic, parts in usable.items():
        decoded = _decode_topic(topic, _merge(parts), reports[topic])
        if reports[topic].loaded:
            columns[topic] = decoded
        elif topic in required:
            raise RawBagError(bag, f"raw topic {topic} has no usable message ({reports[topic].line()})")
    return RawExperiment(
        path=bag, storage=storage,
        star_tracker=_star_tracker(columns[STAR_TRACKER_TOPIC]) if STAR_TRACKER_TOPIC in columns else None,
        grs1=_grs(columns[GRS_TOPICS[0]], GRS_TOPICS[0]) if GRS_TOPICS[0] in columns else None,
        grs2=_grs(columns[GRS_TOPICS[1]], GRS_TOPICS[1]) if GRS_TOPICS[1] in columns else None,
        commands=_commands(columns[COMMAND_TOPIC]) if COMMAND_TOPIC in columns else None,
        report=reports, custom_data=custom)
