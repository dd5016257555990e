"""The packet-file reader fed arbitrary octets (test/fuzz_decoders.py): no exception escapes, every defect is
counted, work and memory within a linear budget. A seeded sample here; benchmarks/bench_fuzz.py runs 100,000."""

from __future__ import annotations

from hypothesis import given

from taiji2_runtime.packets.bulk_decode import decode_packet_buffers
from taiji2_runtime.packets.walk import walk_packets

from fuzz_decoders import IDLE, Budget, check_packet_file, fuzz_settings, telemetry_corpus, telemetry_octets


@fuzz_settings(400)
@given(telemetry_octets())
def test_any_octets_are_read_without_exception_counted_and_bounded(octets):
    check_packet_file(octets, Budget())


def test_a_damaged_packet_then_a_long_idle_fill_is_read_in_linear_work():
    """Found by the fuzzing: the resynchronisation followed an idle chain by recursion, once per idle packet
    (RecursionError after ~1,000 of them, work growing with the square of the chain)."""
    damaged = bytearray(telemetry_corpus()[0])
    damaged[20] ^= 0x01
    small, large = Budget(), Budget()
    for budget, k in ((small, 2_000), (large, 20_000)):
        octets = bytes(damaged) + IDLE * k
        walk = budget.run(lambda octets=octets: walk_packets(octets))
        assert walk.idle == k and walk.idle_octets == 7 * k and sum(walk.crc_error.values()) == 1
    # ten times the fill, at most about ten times the work (a quadratic walk: a hundred times)
    assert large.calls <= 12 * small.calls, (small.calls, large.calls)
    report = decode_packet_buffers([("f", bytes(damaged) + IDLE * 3_000 + telemetry_corpus()[1])]).report
    assert report.idle == 3_000 and report.defects().get("crc_error") == 1
