"""The decoders that read bytes from outside, fed arbitrary octets (docs/security.md, "Decoders").

Three decoders, each with the properties every input must keep:

* ``packet_file``: the packet-file reader (:func:`decode_packet_buffers`, what ``taiji2 calibrate FILE`` runs);
* ``downlink``: the ground receiver's intake of a ``SpacePackets`` burst (telemetry, verification reports, the
  frame security report);
* ``uplink``: the onboard executor's intake of a telecommand burst (TC frames, SDLS verification, then the
  TC[11,4] acceptance of what authenticated).

Properties, per input: no exception escapes; every unit that is not taken is counted as a reject (nothing
dropped silently); nothing of a refused frame is scheduled; the work and the memory of the call are within a
linear budget in the input's size (:class:`Budget`: Python and C calls seen by a profile hook, and tracemalloc's
peak; counted, not timed, so the bound does not depend on the machine). Inputs are hypothesis strategies over a
corpus of genuine units: random octets, and genuine units concatenated, bit-flipped, truncated, with wrong
length fields, wrong APIDs, huge lengths, inserted garbage, idle fill, and CRC/FECF refitted after the damage
(what a faulty ground station or an attacker sends). Authentic frames with garbage inside reach the TC
acceptance. Shared by test/packets/test_fuzz_packet_file.py, test/nodes/test_fuzz_intake.py and
benchmarks/bench_fuzz.py (at least 100,000 cases per decoder).
"""

from __future__ import annotations

import sys
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from taiji2_runtime import link_topics as lt
from taiji2_runtime.packets.bulk_decode import decode_packet_buffers
from taiji2_runtime.packets.definition import STREAMS, TC_APID
from taiji2_runtime.packets.packetize import encode_packet, packet_crc
from taiji2_runtime.packets.scheduling import Activity, encode_insert_activities, encode_report
from taiji2_runtime.packets.sdls import (
    FrameSecurityReport,
    FrameSigner,
    encode_frame_security_report,
)
from taiji2_runtime.packets.sdls_keys import KeyTable, SecurityAssociation, new_key_table
from taiji2_runtime.packets.tc_frame import FECF_OCTETS, FrameError, frame_crc, split_frames
from taiji2_runtime.packets.telecommand import encode_torque_tc
from taiji2_runtime.packets.walk import walk_packets

_NS = 1_000_000_000
IDLE = bytes([0x07, 0xFF, 0xC0, 0x00, 0x00, 0x00, 0x00])
#: the linear budgets [calls per input octet, calls] and [bytes per input octet, bytes]: what one input may cost
#: at most. Measured on this corpus, one call costs ~2-30 calls per octet plus a fixed part; the budgets are 10x
#: that, so they hold on any build of the same code, and a walk whose work grows with the square of the input
#: (an idle chain followed once per packet, 20 kB: ~10^7 calls) exceeds them by orders of magnitude.
CALLS_PER_OCTET, CALLS_FIXED = 300, 200_000
BYTES_PER_OCTET, BYTES_FIXED = 200, 4 << 20


def fuzz_settings(max_examples: int) -> settings:
    """Seeded (derandomised), no example database, no deadline (a wall-clock limit would fail on a busy
    machine: the budget bounds the work instead); the health checks on slow or large examples are off, the
    inputs are large on purpose, and one node serves every example (a running node gets burst after burst)."""
    return settings(max_examples=max_examples, derandomize=True, database=None, deadline=None,
                    suppress_health_check=list(HealthCheck))


# -- budget ---------------------------------------------------------------------------------------
@dataclass
class Budget:
    """Calls and peak memory of the last :meth:`run`; :meth:`check` against the linear budget."""

    calls: int = 0
    peak_bytes: int = 0

    def run(self, fn: Callable[[], Any]) -> Any:
        calls = 0

        def hook(_frame: Any, event: str, _arg: Any) -> None:
            nonlocal calls
            if event in ("call", "c_call"):
                calls += 1

        # traced only during the call (tracing everything would slow hypothesis's own generation fivefold)
        tracemalloc.start()
        sys.setprofile(hook)
        try:
            return fn()
        finally:
            sys.setprofile(None)
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            self.calls, self.peak_bytes = calls, peak

    def check(self, octets: int) -> None:
        assert self.calls <= CALLS_FIXED + CALLS_PER_OCTET * octets, (self.calls, octets)
        assert self.peak_bytes <= BYTES_FIXED + BYTES_PER_OCTET * octets, (self.peak_bytes, octets)


# -- corpus ---------------------------------------------------------------------------------------
def telemetry_corpus() -> list[bytes]:
    """One genuine telemetry packet of each stream, two consecutive of the star tracker, and a torque TC."""
    out = []
    for k, stream in enumerate(STREAMS):
        for j in range(2 if k == 0 else 1):
            out.append(encode_packet(stream, 100 + j, (1_000 + j) * _NS // 10, np.linspace(0.1, 1.0,
                                                                                          len(stream.fields))))
    out.append(encode_torque_tc(7, 1_200 * _NS, np.array([1e-6, -2e-6, 3e-7])))
    return out


def report_corpus() -> list[bytes]:
    """Verification reports TM[1,1]/[1,7]/[1,2] and a frame security report (APID 0x141)."""
    table = encode_insert_activities(3, [Activity(200 * _NS, (1e-6, 0.0, 0.0))])
    reports = [encode_report(subtype, table, 150 * _NS, 10 + subtype, 5 if subtype == 2 else 0)
               for subtype in (1, 7, 2)]
    fsr = FrameSecurityReport(True, False, True, False, 1, 3, 4, {"bad_mac": 2})
    return [*reports, encode_frame_security_report(fsr, 160 * _NS, 20)]


def uplink_keys() -> KeyTable:
    """The onboard key table of the uplink corpus: SPI 1 (authenticated encryption, as Yamcs signs) and SPI 2
    (authentication), both active, so that both SDLS services are fuzzed."""
    fresh = new_key_table((1, 2))
    return KeyTable([SecurityAssociation(1, fresh.get(1).key, service="authenticated_encryption"), fresh.get(2)])


def table(seq: int, first_s: float = 2_000.0, n: int = 3) -> bytes:
    """A genuine TC[11,4] of ``n`` activities from ``first_s``."""
    return encode_insert_activities(seq, [Activity(round((first_s + k) * _NS), (1e-6 * (k + 1), 0.0, 0.0))
                                          for k in range(n)])


# -- mutations ------------------------------------------------------------------------------------
def _refit_crc(unit: bytearray) -> bytearray:
    if len(unit) >= 2:
        unit[-2:] = packet_crc(bytes(unit[:-2])).to_bytes(2, "big")
    return unit


def _refit_fecf(unit: bytearray) -> bytearray:
    if len(unit) >= FECF_OCTETS:
        unit[-FECF_OCTETS:] = frame_crc(bytes(unit[:-FECF_OCTETS])).to_bytes(FECF_OCTETS, "big")
    return unit


@st.composite
def mutated_unit(draw: st.DrawFn, corpus: list[bytes], refit: Callable[[bytearray], bytearray]) -> bytes:
    """A corpus unit with 0-4 damages (the kinds of the module docstring)."""
    unit = bytearray(draw(st.sampled_from(corpus)))
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(("flip", "truncate", "length", "apid", "insert", "huge", "refit")))
        if kind == "flip" and unit:
            bit = draw(st.integers(0, 8 * len(unit) - 1))
            unit[bit // 8] ^= 1 << (bit % 8)
        elif kind == "truncate":
            del unit[draw(st.integers(0, len(unit))):]
        elif kind == "length" and len(unit) >= 6:
            unit[4:6] = draw(st.integers(0, 0xFFFF)).to_bytes(2, "big")
        elif kind == "apid" and len(unit) >= 2:
            apid = draw(st.integers(0, 0x7FF))
            unit[0] = (unit[0] & 0xF8) | (apid >> 8)
            unit[1] = apid & 0xFF
        elif kind == "insert":
            at = draw(st.integers(0, len(unit)))
            unit[at:at] = draw(st.binary(min_size=1, max_size=64))
        elif kind == "huge" and len(unit) >= 6:
            unit[2:6] = b"\xff\xff\xff\xff"
        elif kind == "refit":
            refit(unit)
    return bytes(unit)


@st.composite
def stream_of(draw: st.DrawFn, unit: st.SearchStrategy[bytes]) -> bytes:
    """What a link or a file delivers: random octets, or 1-8 (possibly damaged) units back to back with
    idle fill, repeats and garbage between them."""
    if draw(st.integers(0, 4)) == 0:
        return draw(st.binary(max_size=2048))
    parts: list[bytes] = []
    for _ in range(draw(st.integers(1, 8))):
        kind = draw(st.integers(0, 9))
        if kind == 0:
            parts.append(IDLE * draw(st.integers(1, 3000)))
        elif kind == 1:
            parts.append(draw(st.binary(min_size=1, max_size=128)))
        elif kind == 2 and parts:
            parts.append(parts[-1])
        else:
            parts.append(draw(unit))
    return b"".join(parts)


def telemetry_octets() -> st.SearchStrategy[bytes]:
    """Octets for the packet-file reader and the downlink intake."""
    return stream_of(mutated_unit(telemetry_corpus() + report_corpus(), _refit_crc))


def _packets_by_length(octets: bytes) -> int | None:
    """How many packets ``octets`` divide into by their length fields (None: they do not)."""
    pos = count = 0
    while pos < len(octets):
        if len(octets) - pos < 7:
            return None
        pos += ((octets[pos + 4] << 8) | octets[pos + 5]) + 7
        count += 1
    return count if pos == len(octets) else None


@st.composite
def downlink_burst(draw: st.DrawFn) -> tuple[bytes, int]:
    """(octets, number of reception times) for the ground intake: mostly as many times as the octets hold
    packets by their length fields, sometimes not."""
    octets = draw(telemetry_octets())
    units = _packets_by_length(octets)
    return octets, (draw(st.integers(0, 4)) if units is None else units) + draw(st.sampled_from((0, 0, 0, 1, -1)))


@st.composite
def uplink_burst(draw: st.DrawFn, signer: FrameSigner, genuine: list[bytes]) -> tuple[bytes, int]:
    """(octets, number of arrival times) for the onboard intake: streams of damaged genuine frames, or an
    authentic frame around garbage (an insider or a ground fault: it must fail acceptance, never be scheduled),
    with a times list that may not match."""
    if draw(st.integers(0, 3)) == 0:
        inner = draw(st.one_of(st.binary(min_size=1, max_size=200),
                               mutated_unit([table(k) for k in range(3)], _refit_crc)).filter(bool))
        octets = signer.sign(inner[:1000])
    else:
        octets = draw(stream_of(mutated_unit(genuine, _refit_fecf)))
    try:
        frames = len(split_frames(octets))
    except FrameError:
        frames = draw(st.integers(0, 4))
    return octets, frames + draw(st.sampled_from((0, 0, 0, 1, -1)))


# -- checks ---------------------------------------------------------------------------------------
def check_packet_file(octets: bytes, budget: Budget) -> None:
    """The packet-file reader on ``octets`` (properties of the module docstring)."""
    decoded = budget.run(lambda: decode_packet_buffers([("fuzz", octets)]))
    budget.check(len(octets))
    report = decoded.report
    assert report.octets == len(octets)
    walk = walk_packets(octets)
    for apid, counts in report.per_apid.items():  # every sound packet is kept or counted dropped
        if apid in {s.apid for s in STREAMS} or apid == TC_APID:
            dropped = sum(counts[k] for k in ("crc_error", "truncated", "wrong_length", "bad_time_field",
                                                "bad_header", "wrong_service", "duplicate"))
            walked = walk.crc_error[apid] + walk.truncated[apid]  # damaged packets: not among the sound ones
            assert counts["packets"] == counts["kept"] + dropped - walked, (apid, dict(counts))
    # every octet outside a sound or an idle packet is counted as a defect
    outside = len(octets) - int((walk.ends - walk.starts).sum()) - walk.idle_octets
    if outside > 0:
        assert walk.skipped_octets or walk.crc_error or walk.truncated or walk.corrupt_header, walk


@dataclass
class DownlinkIntake:
    """The ground receiver under fuzz (its node made by the caller) and what it had counted."""

    node: Any
    seen: dict[str, int] = field(default_factory=dict)

    def counted(self) -> int:
        rx = self.node._rx
        received = sum(c["received"] for c in rx.counts().values())
        return received + sum(rx.rejected.values()) + self.node._report_packets

    def check(self, octets: bytes, times: int, budget: Budget) -> None:
        before = self.counted()
        msg = lt.burst([octets], list(range(1, times + 1)), max(times, 0))
        budget.run(lambda: self.node._on_burst(msg))
        budget.check(len(octets))
        try:
            units = len(lt.split(msg))
        except ValueError:
            units = 1  # the whole burst, refused as one
        assert self.counted() - before == units, (before, self.counted(), units)


@dataclass
class UplinkIntake:
    """The onboard executor under fuzz (its node made by the caller, with :func:`uplink_keys`)."""

    node: Any

    def counted(self) -> int:
        v = self.node.verifier
        return v.accepted + sum(v.refused.values())

    def check(self, octets: bytes, times: int, budget: Budget) -> None:
        before, accepted, scheduled = self.counted(), self.node.verifier.accepted, self.node.schedule.inserted
        msg = lt.burst([octets], [10 * _NS] * max(times, 0), 10 * _NS)
        # the burst, then the onboard clock reaching its arrival (the tick reads the frames held)
        budget.run(lambda: (self.node._on_telecommands(msg), self.node._take_arrived(10 * _NS)))
        budget.check(len(octets))
        try:
            frames = split_frames(octets)
            units = len(frames) if len(frames) == max(times, 0) else 1
        except FrameError:
            units = 1
        assert self.counted() - before == units, (before, self.counted(), units)
        if self.node.verifier.accepted == accepted:  # nothing authenticated: nothing scheduled
            assert self.node.schedule.inserted == scheduled
