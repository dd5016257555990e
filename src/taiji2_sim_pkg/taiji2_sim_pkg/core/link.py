"""The deep-space link between the spacecraft and the ground (docs/link.md): plain Python, no middleware.

:class:`LinkModel` is the YAML model (presets in ``config/link.yaml``: ``ideal``, ``deep_space``).
:class:`Downlink` is the telemetry path as an event model advanced by *data time*: packets are
offered in onboard-time order; :meth:`Downlink.advance` runs the transmitter up to the time through
which every packet is known and returns the deliveries the ground has received by then. So the
model needs no clock of its own, is exact in accelerated time and deterministic for a seed whatever
the middleware's timing. What it models:

* contact windows (ground-station passes, ground time): the spacecraft transmits during
  ``[start - light_time, end - light_time)`` so that the ground receives during the pass; a missed
  pass (fault) transmits nothing;
* one-way light time; a downlink rate (each packet takes ``8 (octets + overhead) / rate`` s and
  is sent only if it ends inside the window);
* onboard mass memory: a packet generated outside a contact is stored; when the memory is full the
  oldest stored packets are overwritten (counted per APID);
* during a contact, real-time packets (generated in the contact) go first, stored packets are played
  back, oldest first, whenever no real-time packet waits (so the ground receives out of time order);
  real-time packets left at the window's end join the memory;
* loss of each transmitted packet: independent (``random_loss_probability``) and bursty
  (Gilbert-Elliott two-state channel); duplicates (a delivered packet delivered again later).

Each delivery carries ``transmitted_through_s``: every packet generated before it had been
transmitted (or lost, or overwritten) when this one was sent: the ground's cue that a gap older than
it will never be filled (onboard it is the oldest packet still queued, which a spacecraft reports in
its frames).

:class:`Uplink` carries telecommand packets sent by the ground during passes, rate limited, with the
light time; a pass whose uplink is lost (fault) or a random loss drops a packet.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections import Counter, deque
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

__all__ = ["ContactSchedule", "Delivery", "Downlink", "LinkError", "LinkModel", "StreamStats", "Uplink",
           "UplinkDelivery", "link_presets", "load_link_model"]

PRESETS_FILE = "link.yaml"
_INF = math.inf


class LinkError(ValueError):
    """A link model that cannot be used; the message names the key and the problem."""


@dataclass(frozen=True)
class ContactSchedule:
    """Ground-station passes (ground time, s): always in contact, periodic, or an explicit list.

    Attributes
    ----------
    always : bool
        Permanent contact (the ``ideal`` link).
    period_s, first_start_s, duration_s : float
        Periodic passes ``[first_start_s + k period_s, ... + duration_s)``, k = 0, 1, ...
    windows : tuple of (float, float)
        Explicit passes (sorted, disjoint); used when not empty.
    """

    always: bool = True
    period_s: float = 0.0
    first_start_s: float = 0.0
    duration_s: float = 0.0
    windows: tuple[tuple[float, float], ...] = ()

    @classmethod
    def from_yaml(cls, value: Any) -> ContactSchedule:
        if value == "always":
            return cls()
        if not isinstance(value, Mapping):
            raise LinkError(f"contacts: expected 'always' or a mapping, got {value!r}")
        if "windows" in value:
            try:
                windows = tuple((float(a), float(b)) for a, b in value["windows"])
            except (TypeError, ValueError):
                raise LinkError("contacts.windows: expected [[start_s, end_s], ...], "
                                f"got {value['windows']!r}") from None
            if any(b <= a for a, b in windows) or any(w[0] < v[1] for v, w in itertools.pairwise(windows)):
                raise LinkError("contacts.windows: each window must end after it starts, sorted and disjoint")
            return cls(always=False, windows=windows)
        try:
            period, first, duration = (float(value[k]) for k in ("period_s", "first_start_s", "duration_s"))
        except KeyError as exc:
            raise LinkError(f"contacts: missing key {exc.args[0]} (period_s, first_start_s, duration_s)") from None
        if not 0.0 < duration <= period:
            raise LinkError(f"contacts: need 0 < duration_s <= period_s, got {duration} and {period}")
        return cls(always=False, period_s=period, first_start_s=first, duration_s=duration)

    def passes(self, from_s: float = -_INF) -> Iterator[tuple[int, float, float]]:
        """``(index, start_s, end_s)`` of the passes that end after ``from_s``, in time order (endless
        for a periodic schedule; one endless pass for ``always``)."""
        if self.always:
            yield 0, -_INF, _INF
            return
        if self.windows:
            for k, (a, b) in enumerate(self.windows):
                if b > from_s:
                    yield k, a, b
            return
        k = 0 if from_s == -_INF else max(0, math.floor((from_s - self.first_start_s - self.duration_s)
                                                         / self.period_s))
        while True:
            start = self.first_start_s + k * self.period_s
            if start + self.duration_s > from_s:
                yield k, start, start + self.duration_s
            k += 1

    def to_dict(self) -> Any:
        if self.always:
            return "always"
        if self.windows:
            return {"windows": [list(w) for w in self.windows]}
        return {"period_s": self.period_s, "first_start_s": self.first_start_s, "duration_s": self.duration_s}


@dataclass(frozen=True)
class LinkModel:
    """One link model (``config/link.yaml`` documents every key)."""

    name: str = "ideal"
    light_time_s: float = 0.0
    contacts: ContactSchedule = field(default_factory=ContactSchedule)
    downlink_rate_bps: float = _INF
    uplink_rate_bps: float = _INF
    packet_overhead_octets: int = 0
    storage_capacity_octets: float = _INF
    random_loss_probability: float = 0.0
    p_good_to_bad: float = 0.0
    p_bad_to_good: float = 1.0
    loss_in_bad: float = 1.0
    loss_in_good: float = 0.0
    duplicate_probability: float = 0.0
    duplicate_delay_s: float = 0.0
    uplink_loss_probability: float = 0.0
    onboard_schedule_capacity: int = 1_000_000
    command_lead_s: float = 0.0
    missed_contacts: frozenset[int] = frozenset()
    lost_uplinks: frozenset[int] = frozenset()

    @property
    def is_ideal(self) -> bool:
        """Today's lossless, zero-latency network."""
        return (self.contacts.always and self.light_time_s == 0.0 and math.isinf(self.downlink_rate_bps)
                and self.random_loss_probability == 0.0 and self.p_good_to_bad == 0.0
                and self.duplicate_probability == 0.0 and math.isinf(self.storage_capacity_octets))

    @property
    def burst_loss_fraction(self) -> float:
        """Long-run loss of the Gilbert-Elliott channel alone."""
        pgb, pbg = self.p_good_to_bad, self.p_bad_to_good
        bad = pgb / (pgb + pbg) if pgb + pbg > 0 else 0.0
        return bad * self.loss_in_bad + (1.0 - bad) * self.loss_in_good

    def with_faults(self, missed_contacts: Sequence[int] = (), lost_uplinks: Sequence[int] = ()) -> LinkModel:
        """This model with more faults."""
        return replace(self, missed_contacts=self.missed_contacts | frozenset(int(k) for k in missed_contacts),
                       lost_uplinks=self.lost_uplinks | frozenset(int(k) for k in lost_uplinks))

    def to_dict(self) -> dict[str, Any]:
        """The model as its YAML mapping (JSON-ready; infinities as the string 'inf')."""

        def num(v: float) -> Any:
            return "inf" if isinstance(v, float) and math.isinf(v) else v

        return {"name": self.name, "light_time_s": self.light_time_s, "contacts": self.contacts.to_dict(),
                "downlink_rate_bps": num(self.downlink_rate_bps), "uplink_rate_bps": num(self.uplink_rate_bps),
                "packet_overhead_octets": self.packet_overhead_octets,
                "storage_capacity_octets": num(self.storage_capacity_octets),
                "random_loss_probability": self.random_loss_probability,
                "burst_loss": {"p_good_to_bad": self.p_good_to_bad, "p_bad_to_good": self.p_bad_to_good,
                               "loss_in_bad": self.loss_in_bad, "loss_in_good": self.loss_in_good},
                "duplicate_probability": self.duplicate_probability, "duplicate_delay_s": self.duplicate_delay_s,
                "uplink_loss_probability": self.uplink_loss_probability,
                "onboard_schedule_capacity": self.onboard_schedule_capacity, "command_lead_s": self.command_lead_s,
                "faults": {"missed_contacts": sorted(self.missed_contacts), "lost_uplinks": sorted(self.lost_uplinks)}}


def _presets_path() -> Path:
    from taiji2_model.package_files import config_dirs

    for directory in config_dirs("taiji2_sim_pkg"):
        if (directory / PRESETS_FILE).is_file():
            return directory / PRESETS_FILE
    raise LinkError(f"link presets file {PRESETS_FILE} not found in the package's config directories")


def link_presets() -> dict[str, dict[str, Any]]:
    """The preset mappings of ``config/link.yaml`` by name."""
    with _presets_path().open(encoding="utf-8") as handle:
        return yaml.safe_load(handle)


def _probability(key: str, value: Any) -> float:
    p = float(value)
    if not 0.0 <= p <= 1.0:
        raise LinkError(f"{key}: a probability in [0, 1], got {value!r}")
    return p


def _from_mapping(name: str, raw: Mapping[str, Any]) -> LinkModel:
    base = link_presets()["ideal"]
    unknown = set(raw) - set(base)
    if unknown:
        raise LinkError(f"link model {name}: unknown key(s) {', '.join(sorted(unknown))} (see config/link.yaml)")
    values = {**base, **raw}
    burst = {**base["burst_loss"], **(values.get("burst_loss") or {})}
    faults = {**base["faults"], **(values.get("faults") or {})}

    def positive(key: str, allow_zero: bool = False) -> float:
        v = float(values[key])
        if not (v >= 0.0 if allow_zero else v > 0.0) or math.isnan(v):
            raise LinkError(f"{key}: must be {'>= 0' if allow_zero else '> 0'}, got {values[key]!r}")
        return v

    return LinkModel(
        name=name, light_time_s=positive("light_time_s", True), contacts=ContactSchedule.from_yaml(values["contacts"]),
        downlink_rate_bps=positive("downlink_rate_bps"), uplink_rate_bps=positive("uplink_rate_bps"),
        packet_overhead_octets=int(positive("packet_overhead_octets", True)),
        storage_capacity_octets=positive("storage_capacity_octets"),
        random_loss_probability=_probability("random_loss_probability", values["random_loss_probability"]),
        p_good_to_bad=_probability("burst_loss.p_good_to_bad", burst["p_good_to_bad"]),
        p_bad_to_good=_probability("burst_loss.p_bad_to_good", burst["p_bad_to_good"]),
        loss_in_bad=_probability("burst_loss.loss_in_bad", burst["loss_in_bad"]),
        loss_in_good=_probability("burst_loss.loss_in_good", burst["loss_in_good"]),
        duplicate_probability=_probability("duplicate_probability", values["duplicate_probability"]),
        duplicate_delay_s=positive("duplicate_delay_s", True),
        uplink_loss_probability=_probability("uplink_loss_probability", values["uplink_loss_probability"]),
        onboard_schedule_capacity=int(positive("onboard_schedule_capacity")),
        command_lead_s=positive("command_lead_s", True),
        missed_contacts=frozenset(int(k) for k in faults["missed_contacts"]),
        lost_uplinks=frozenset(int(k) for k in faults["lost_uplinks"]))


def load_link_model(source: str | Path | Mapping[str, Any]) -> LinkModel:
    """A preset name (``ideal``, ``deep_space``), a YAML file of one model, or a mapping.

    Raises
    ------
    LinkError
        Unknown preset, unreadable file, unknown key, or a value out of range (named).
    """
    if isinstance(source, Mapping):
        return _from_mapping("custom", source)
    presets = link_presets()
    if str(source) in presets:
        return _from_mapping(str(source), presets[str(source)])
    path = Path(source)
    if not path.is_file():
        raise LinkError(f"link model {source!r}: neither a preset ({', '.join(presets)}) nor a YAML file")
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise LinkError(f"link model {path}: cannot read ({exc})") from None
    if not isinstance(raw, Mapping):
        raise LinkError(f"link model {path}: expected a mapping of the keys of config/link.yaml")
    return _from_mapping(path.stem, raw)


@dataclass
class StreamStats:
    """What the link did to one APID's packets."""

    generated: int = 0
    delivered: int = 0  # delivered at least once
    lost: int = 0  # transmitted and lost
    duplicated: int = 0  # extra copies delivered
    reordered: int = 0  # delivered after a packet of this APID generated later
    overwritten: int = 0  # overwritten in the onboard memory before transmission
    latency_s: list[float] = field(default_factory=list)  # reception - generation of each first delivery
    last_generated_delivered_s: float = -_INF

    def to_dict(self) -> dict[str, Any]:
        lat = np.asarray(self.latency_s)
        return {"generated": self.generated, "delivered": self.delivered, "lost": self.lost,
                "duplicated": self.duplicated, "reordered": self.reordered, "overwritten": self.overwritten,
                "latency_median_s": float(np.median(lat)) if lat.size else None,
                "latency_max_s": float(lat.max()) if lat.size else None}


@dataclass(frozen=True)
class Delivery:
    """One packet received on the ground."""

    receive_s: float
    generated_s: float
    apid: int
    packet: bytes
    transmitted_through_s: float
    duplicate: bool = False


class _Random:
    """Uniform draws in blocks (one numpy Generator; deterministic for a seed)."""

    def __init__(self, seed: int) -> None:
        self._rng = np.random.default_rng(seed)
        self._block = np.empty(0)
        self._i = 0

    def __call__(self) -> float:
        if self._i >= self._block.shape[0]:
            self._block = self._rng.random(4096)
            self._i = 0
        self._i += 1
        return float(self._block[self._i - 1])


class Downlink:
    """Telemetry from the spacecraft to the ground (see the module docstring).

    Parameters
    ----------
    model : LinkModel
    seed : int
        Seed of the loss and duplicate draws.
    """

    def __init__(self, model: LinkModel, seed: int = 0) -> None:
        self.model = model
        self._draw = _Random(seed)
        self._bad = False
        self._t_free = -_INF  # the transmitter is free from this onboard time on
        self._known_s = -_INF  # every packet generated at or before this time has been offered
        self._rt: deque[tuple[float, int, bytes]] = deque()
        self._store: deque[tuple[float, int, bytes]] = deque()
        self._store_octets = 0
        self._out: list[tuple[float, int, Delivery]] = []  # heap on reception time
        self._n_out = 0
        self.stats: dict[int, StreamStats] = {}
        self.overwrite_started_s: float | None = None
        self.contacts_used: set[int] = set()
        self.memory_peak_octets = 0
        lt = model.light_time_s
        self._windows = ((k, a - lt, b - lt) for k, a, b in model.contacts.passes() if k not in model.missed_contacts
                         or model.contacts.always)
        self._window: tuple[int, float, float] | None = next(self._windows, None)

    # -- onboard side ------------------------------------------------------------------------------------
    def _stats(self, apid: int) -> StreamStats:
        s = self.stats.get(apid)
        if s is None:
            s = self.stats[apid] = StreamStats()
        return s

    def _in_contact(self, t: float) -> bool:
        w = self._window_at_or_after(t)
        return w is not None and w[1] <= t < w[2]

    def _window_at_or_after(self, t: float) -> tuple[int, float, float] | None:
        while self._window is not None and self._window[2] <= t:
            self._window = next(self._windows, None)
        return self._window

    def _store_add(self, item: tuple[float, int, bytes]) -> None:
        self._store.append(item)
        self._store_octets += len(item[2])
        while self._store_octets > self.model.storage_capacity_octets and self._store:
            old = self._store.popleft()
            self._store_octets -= len(old[2])
            self._stats(old[1]).overwritten += 1
            if self.overwrite_started_s is None:
                self.overwrite_started_s = item[0]
        self.memory_peak_octets = max(self.memory_peak_octets, self._store_octets)

    def offer(self, generated_s: float, apid: int, packet: bytes) -> None:
        """One packet generated onboard at ``generated_s`` (non-decreasing over calls)."""
        if generated_s < self._known_s:
            raise ValueError(f"packet generated at {generated_s} s offered after one of {self._known_s} s")
        self._run(generated_s, strict=True)
        self._known_s = generated_s
        self._stats(apid).generated += 1
        item = (generated_s, apid, bytes(packet))
        if self._in_contact(generated_s):
            self._rt.append(item)
        else:
            self._store_add(item)
        if self._t_free < generated_s:
            self._t_free = generated_s

    def advance(self, through_s: float) -> list[Delivery]:
        """Every packet generated up to ``through_s`` has been offered: run the transmitter and return the
        deliveries received before ``through_s + light time`` (final: nothing later can be received earlier),
        in reception order."""
        self._known_s = max(self._known_s, through_s)
        self._run(through_s, strict=False)
        return self._take(through_s + self.model.light_time_s)

    def drain(self, max_passes: int = 1000) -> list[Delivery]:
        """No more data: transmit what is still onboard over the following passes (at most ``max_passes``);
        returns every remaining delivery. What could not be sent stays counted in :attr:`stored_at_end`."""
        self._known_s = _INF
        start = self._window[0] if self._window is not None else 0
        while (self._rt or self._store) and self._window is not None and self._window[0] - start <= max_passes:
            self._run(self._window[2], strict=False)
            if (self._rt or self._store) and self._window is not None:
                self._t_free = max(self._t_free, self._window[2])
                self._run(self._t_free, strict=False)
        return self._take(_INF)

    @property
    def stored_at_end(self) -> Counter:
        """Packets per APID still onboard (never transmitted)."""
        return Counter(item[1] for item in (*self._rt, *self._store))

    @property
    def stored_octets(self) -> int:
        return self._store_octets + sum(len(i[2]) for i in self._rt)

    def _take(self, before_s: float) -> list[Delivery]:
        out = []
        while self._out and self._out[0][0] < before_s:
            out.append(heapq.heappop(self._out)[2])
        return out

    def _lost(self) -> bool:
        m = self.model
        if m.p_good_to_bad > 0.0 or self._bad:
            self._bad = (self._draw() >= m.p_bad_to_good) if self._bad else (self._draw() < m.p_good_to_bad)
            p = m.loss_in_bad if self._bad else m.loss_in_good
            if p > 0.0 and self._draw() < p:
                return True
        return m.random_loss_probability > 0.0 and self._draw() < m.random_loss_probability

    def _run(self, until_s: float, strict: bool) -> None:
        """Start every transmission that starts before ``until_s`` (``strict``) or at it."""
        m = self.model
        rate = m.downlink_rate_bps
        lt = m.light_time_s
        while True:
            c = self._t_free
            if c > until_s or (strict and c == until_s) or c == _INF:
                return
            w = self._window_at_or_after(c)
            if w is None:
                self._t_free = _INF
                return
            if c < w[1]:  # between passes: whatever real-time data are left join the memory
                while self._rt:
                    self._store_add(self._rt.popleft())
                self._t_free = w[1]
                continue
            queue = self._rt if self._rt and self._rt[0][0] <= c else self._store
            if not queue or queue[0][0] > c:
                self._t_free = min(until_s, w[2]) if not math.isinf(until_s) else w[2]
                if self._t_free == c:
                    return
                continue
            t_gen, apid, packet = queue[0]
            duration = 8.0 * (len(packet) + m.packet_overhead_octets) / rate
            if c + duration > w[2]:  # does not fit in this pass
                self._t_free = w[2]
                continue
            queue.popleft()
            if queue is self._store:
                self._store_octets -= len(packet)
            self.contacts_used.add(w[0])
            heads = [q[0][0] for q in (self._rt, self._store) if q]
            through = min([c, *heads])
            self._t_free = c + duration
            receive = self._t_free + lt
            s = self._stats(apid)
            if self._lost():
                s.lost += 1
                continue
            s.delivered += 1
            s.latency_s.append(receive - t_gen)
            if t_gen < s.last_generated_delivered_s:
                s.reordered += 1
            else:
                s.last_generated_delivered_s = t_gen
            self._push(Delivery(receive, t_gen, apid, packet, through))
            if m.duplicate_probability > 0.0 and self._draw() < m.duplicate_probability:
                s.duplicated += 1
                self._push(Delivery(receive + m.duplicate_delay_s, t_gen, apid, packet, through, duplicate=True))

    def _push(self, d: Delivery) -> None:
        self._n_out += 1
        heapq.heappush(self._out, (d.receive_s, self._n_out, d))


@dataclass(frozen=True)
class UplinkDelivery:
    """One telecommand packet: sent by the ground at ``sent_s`` in pass ``contact``; arrives onboard at
    ``arrival_s`` unless ``lost``."""

    sent_s: float
    arrival_s: float
    contact: int
    packet: bytes
    lost: bool
    reason: str = ""


class Uplink:
    """Telecommands from the ground to the spacecraft: sent in passes, one after another at the uplink rate,
    arriving one light time later; lost in a pass with an uplink fault or at random."""

    def __init__(self, model: LinkModel, seed: int = 0) -> None:
        self.model = model
        self._draw = _Random(seed + 0x5EED)
        self._t_free = -_INF
        self.sent = 0
        self.lost = 0

    def send(self, ready_s: float, packet: bytes) -> UplinkDelivery | None:
        """Send ``packet`` at the first chance from ground time ``ready_s`` on; None if no pass is left."""
        m = self.model
        duration = 8.0 * (len(packet) + m.packet_overhead_octets) / m.uplink_rate_bps
        t = max(ready_s, self._t_free)
        for k, a, b in m.contacts.passes(t):
            if k in m.missed_contacts and not m.contacts.always:
                continue
            start = max(t, a)
            if start + duration <= b:
                self._t_free = start + duration
                self.sent += 1
                reason = ("uplink fault in this pass" if k in m.lost_uplinks else
                          "random loss" if m.uplink_loss_probability > 0 and self._draw() < m.uplink_loss_probability
                          else "")
                self.lost += bool(reason)
                return UplinkDelivery(start, start + duration + m.light_time_s, k, bytes(packet), bool(reason),
                                      reason)
            if m.contacts.always:
                break
        return None
