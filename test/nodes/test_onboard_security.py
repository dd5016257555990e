"""The onboard executor authenticates every uplinked TC frame first (SDLS, docs/security.md): each refusal reason
refused and counted (on /diagnostics and in a frame security report in telemetry), nothing of a refused frame
scheduled; an authentic but invalid TC gets TM[1,2]; a seeded fuzz never raises and never schedules anything.
The handler is called directly (no spinning): fast and deterministic."""

from __future__ import annotations

import json
import random

import pytest

from taiji2_runtime import link_topics as lt
from taiji2_runtime.packets.scheduling import (
    ACCEPTANCE_FAILURE_CODES,
    Activity,
    decode_report,
    encode_insert_activities,
)
from taiji2_runtime.packets.sdls import FrameSigner, decode_frame_security_report, is_frame_security_report
from taiji2_runtime.packets.sdls_keys import REVOKED, new_key_table, write_key_file
from taiji2_runtime.packets.tc_frame import FECF_OCTETS, frame_crc
from taiji2_sim_pkg.nodes.onboard_executor import OnboardExecutor

_NS = 1_000_000_000
ARRIVAL_NS = 100 * _NS


@pytest.fixture
def keys(tmp_path):
    """Ground and onboard key files: SPI 1 and 2 active on the ground; onboard SPI 1 revoked (rotated out)."""
    ground = new_key_table((1, 2))
    onboard = ground.with_state(1, REVOKED)
    return ground, write_key_file(tmp_path / "onboard.json", onboard)


def _executor(context, key_file, *extra):
    return OnboardExecutor(context=context, cli_args=["--ros-args", "-p", f"key_file:={key_file}",
                                                      "-p", "time_margin_s:=2.0", *extra])


def _table(seq: int, first_s: float = 200.0) -> bytes:
    return encode_insert_activities(seq, [Activity(round((first_s + k) * _NS), (1e-6 * (k + 1), 0.0, 0.0))
                                          for k in range(12)])


def _deliver(onboard, frames, t_ns=ARRIVAL_NS):
    """A burst of ``frames`` arriving at ``t_ns``, then the onboard clock reaching ``t_ns`` (the tick reads them)."""
    onboard._on_telecommands(lt.burst(list(frames), [t_ns] * len(frames), t_ns))
    onboard._take_arrived(t_ns)


def _refit(frame: bytes | bytearray) -> bytes:
    body = bytes(frame[:-FECF_OCTETS])
    return body + frame_crc(body).to_bytes(2, "big")


def _packets(onboard):
    """The distinct report packets queued (each verification report is queued twice: report_repeat_s)."""
    return list(dict.fromkeys(p for _, p in onboard._reports))


def _diagnostics(onboard):
    got = []
    onboard._diag_pub.publish = got.append
    onboard._publish_diagnostics()
    status = got[-1].status[0]
    return status, {kv.key: json.loads(kv.value) for kv in status.values}


def test_genuine_frames_are_scheduled_and_reported(context, keys):
    ground, onboard_file = keys
    onboard = _executor(context, onboard_file)
    try:
        signer = FrameSigner(ground)  # SPI 2, the newest active
        _deliver(onboard, [signer.sign(_table(0)), signer.sign(_table(1, 300.0))])
        assert onboard.schedule.inserted == 24 and onboard._tables == 2
        assert [decode_report(p).subtype for p in _packets(onboard)] == [1, 7, 1, 7]
        status, values = _diagnostics(onboard)
        assert values["frames_accepted"] == 2 and sum(values["frames_refused"].values()) == 0
        assert values["last_spi"] == 2 and status.message == "nominal"
    finally:
        onboard.destroy_node()


def _attacks(ground, genuine: bytes) -> dict[str, bytes]:
    """One frame per refusal reason."""
    other = new_key_table((2,))
    tampered_data = bytearray(genuine)
    tampered_data[40] ^= 0x04
    tampered_header = bytearray(genuine)
    tampered_header[4] ^= 0x01  # the frame sequence number: covered by the MAC
    tampered_mac = bytearray(genuine)
    tampered_mac[-FECF_OCTETS - 3] ^= 0x80
    plain = bytearray(genuine)
    plain[5:7] = b"\x00\x00"
    return {
        "bad_mac": _refit(tampered_data),
        "bad_mac_header": _refit(tampered_header),
        "bad_mac_trailer": _refit(tampered_mac),
        "bad_mac_other_key": FrameSigner(other, 2).sign(_table(5)),  # a forger's own key under a known SPI
        "replay": genuine,
        "revoked_spi": FrameSigner(ground, 1).sign(_table(6)),
        "unknown_spi": FrameSigner(new_key_table((9,)), 9).sign(_table(7)),
        "no_spi": _refit(plain),
        "truncated": genuine[:-5],
        "oversized": genuine + b"\x00\x01",
        "bad_fecf": genuine[:-1] + bytes([genuine[-1] ^ 0xFF]),
        "out_of_window": FrameSigner(ground, 2, first_sequence=10_000).sign(_table(8)),
    }


@pytest.mark.parametrize("attack", ["bad_mac", "bad_mac_header", "bad_mac_trailer", "bad_mac_other_key", "replay",
                                    "revoked_spi", "unknown_spi", "no_spi", "truncated", "oversized", "bad_fecf",
                                    "out_of_window"])
def test_each_refusal_reason_refused_counted_and_nothing_scheduled(context, keys, attack):
    ground, onboard_file = keys
    onboard = _executor(context, onboard_file, "-p", "replay_window:=100")
    try:
        signer = FrameSigner(ground, 2)
        genuine = signer.sign(_table(0))
        _deliver(onboard, [genuine])
        inserted, reports = onboard.schedule.inserted, len(_packets(onboard))
        frame = _attacks(ground, genuine)[attack]
        # truncated/oversized frames alone in a burst: the burst's octets do not divide into frames (truncated),
        # or divide into a frame and a stray remainder; either way nothing of it is read
        _deliver(onboard, [frame], ARRIVAL_NS + _NS)
        reason = attack.split("_header")[0].split("_trailer")[0].split("_other")[0]
        assert onboard.schedule.inserted == inserted and onboard._tables == 1  # nothing scheduled
        new = _packets(onboard)[reports:]
        assert len(new) == 1 and is_frame_security_report(new[0])  # only the frame security report
        fsr, _ = decode_frame_security_report(new[0])
        assert fsr.alarm and fsr.accepted == 1
        expected = "truncated" if attack == "oversized" else reason  # a stray 2 octets cannot be a frame
        assert fsr.refused[expected] == 1 and sum(fsr.refused.values()) == 1, fsr.refused
        status, values = _diagnostics(onboard)
        assert values["frames_refused"][expected] == 1 and "refused" in status.message
        # the genuine uplink goes on: the next genuine frame is accepted
        _deliver(onboard, [signer.sign(_table(1, 400.0))], ARRIVAL_NS + 2 * _NS)
        assert onboard.schedule.inserted == inserted + 12
    finally:
        onboard.destroy_node()


def test_oversized_frame_against_the_onboard_maximum(context, keys):
    ground, onboard_file = keys
    onboard = _executor(context, onboard_file, "-p", "max_frame_octets:=512")
    try:
        _deliver(onboard, [FrameSigner(ground, 2).sign(_table(0))])  # a 976-octet frame
        assert onboard.schedule.inserted == 0 and onboard.verifier.refused["oversized"] == 1
    finally:
        onboard.destroy_node()


def test_authentic_but_invalid_telecommand_gets_tm_1_2(context, keys):
    ground, onboard_file = keys
    onboard = _executor(context, onboard_file)
    try:
        bad = bytearray(_table(3))
        bad[-1] ^= 0xFF  # the packet's CRC: signed as it is by the key holder, refused at acceptance
        _deliver(onboard, [FrameSigner(ground, 2).sign(bytes(bad))])
        assert onboard.schedule.inserted == 0 and onboard.verifier.accepted == 1
        (report,) = [decode_report(p) for p in _packets(onboard)]
        code = ACCEPTANCE_FAILURE_CODES["crc_error"]
        assert (report.subtype, report.tc_seq_count, report.failure_code) == (2, 3, code)
    finally:
        onboard.destroy_node()


def test_without_keys_everything_is_refused(context, keys):
    ground, _ = keys
    onboard = OnboardExecutor(context=context)
    try:
        _deliver(onboard, [FrameSigner(ground, 2).sign(_table(0))])
        assert onboard.schedule.inserted == 0 and onboard.verifier.refused["unknown_spi"] == 1
    finally:
        onboard.destroy_node()


def test_fuzzed_uplink_never_raises_and_never_schedules(context, keys):
    ground, onboard_file = keys
    onboard = _executor(context, onboard_file, "-p", "replay_window:=64")
    rng = random.Random(4102)
    try:
        signer = FrameSigner(ground, 2)
        genuine = [signer.sign(_table(k, 200.0 + 20 * k)) for k in range(10)]
        _deliver(onboard, genuine)
        assert onboard.schedule.inserted == 120
        baseline = len(onboard._reports)
        revoked = FrameSigner(ground, 1)
        sent = 0
        for _ in range(150):  # bursts of 1-20 frames: 1500 frames or so
            burst = []
            for _ in range(rng.randrange(1, 21)):
                base = rng.choice(genuine)
                kind = rng.randrange(5)
                if kind == 0:
                    burst.append(rng.randbytes(rng.randrange(5, 1100)))
                elif kind == 1:
                    bad = bytearray(base)
                    for _ in range(rng.randrange(1, 4)):
                        bad[rng.randrange(len(bad))] ^= 1 << rng.randrange(8)
                    burst.append(_refit(bad) if rng.random() < 0.7 else bytes(bad))
                elif kind == 2:
                    burst.append(base)
                elif kind == 3:
                    burst.append(revoked.sign(_table(99)))
                else:
                    burst.append(_refit(base[:rng.randrange(20, len(base))] + base[-FECF_OCTETS:]))
            sent += len(burst)
            data = b"".join(burst)
            times = [ARRIVAL_NS + _NS] * rng.choice([len(burst), len(burst) + 1])
            msg = lt.burst([data], [0], ARRIVAL_NS + _NS)
            msg.times_ns = times
            onboard._on_telecommands(msg)
            onboard._take_arrived(ARRIVAL_NS + _NS)
        assert onboard.schedule.inserted == 120 and onboard._tables == 10 and onboard.verifier.accepted == 10
        new = _packets(onboard)[baseline:]
        assert new and all(is_frame_security_report(p) for p in new)  # no TM[1,x]: nothing was accepted
        assert sum(onboard.verifier.refused.values()) >= 150
        assert sent > 1000
    finally:
        onboard.destroy_node()


@pytest.mark.parametrize("intruder_first", [False, True])
def test_the_intruders_frames_are_all_refused_and_the_genuine_tables_fly(context, keys, tmp_path, intruder_first):
    """uplink_intruder against the executor, handlers called directly: every kind, every frame refused with the
    reason it was built for, the genuine tables scheduled as sent (the running graph: test/faults)."""
    from taiji2_runtime.packets.sdls_keys import KeyTable, SecurityAssociation
    from taiji2_sim_pkg.nodes.uplink_intruder import UplinkIntruder

    ground, onboard_file = keys
    leaked = write_key_file(tmp_path / "leaked.json", KeyTable([SecurityAssociation(1, ground.get(1).key)]))
    onboard = _executor(context, onboard_file)
    intruder = UplinkIntruder(context=context, cli_args=["--ros-args", "-p", f"leaked_key_file:={leaked}"])
    sent = []
    intruder._tc_pub.publish = sent.append
    try:
        signer = FrameSigner(ground)  # SPI 2
        genuine = lt.burst([signer.sign(_table(0)), signer.sign(_table(1, 300.0))], [ARRIVAL_NS] * 2, ARRIVAL_NS)
        intruder._on_uplink(genuine)
        intruder._on_uplink(sent[0])  # its own burst comes back to it: it attacks once
        assert len(sent) == 1
        # the bursts in either order (two writers: DDS keeps no order between them): the frames are read in
        # the order they arrive onboard, so a replay always comes after its genuine frame
        for burst in ((sent[0], genuine) if intruder_first else (genuine, sent[0])):
            onboard._on_telecommands(burst)
        onboard._take_arrived(max(sent[0].times_ns))
        report = intruder.report()
        assert report["sent"] == {"forged": 3, "replay": 3, "bit_flip": 3, "revoked": 3, "garbage": 50}
        assert onboard.verifier.accepted == 2 and onboard.schedule.inserted == 24
        assert sum(onboard.verifier.refused.values()) == report["frames"] == 62
        for reason, n in report["expected_refusals"].items():
            if reason != "any":
                assert onboard.verifier.refused[reason] >= n, (reason, dict(onboard.verifier.refused))
        # the frame security reports in telemetry: times never go back and the latest counts every frame
        reports = [decode_frame_security_report(p) for _, p in onboard._reports if is_frame_security_report(p)]
        times = [t for _, t in reports]
        assert times == sorted(times) and reports[-1][0].total() == 64, times
    finally:
        intruder.destroy_node()
        onboard.destroy_node()
