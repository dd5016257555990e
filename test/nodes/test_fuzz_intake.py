"""The onboard uplink intake and the ground downlink intake fed arbitrary bursts (test/fuzz_decoders.py): no
exception escapes, every frame or packet is accepted or counted as refused, nothing of a refused frame is
scheduled, work and memory within a linear budget. One running node per test takes every burst, as a node in
orbit or on the ground would; its handler is called directly (no spinning). A seeded sample here;
benchmarks/bench_fuzz.py runs 100,000 bursts per decoder."""

from __future__ import annotations

from hypothesis import given

from taiji2_ground_pkg.nodes.ground_receiver import GroundReceiver
from taiji2_runtime.packets.sdls import FrameSigner
from taiji2_runtime.packets.sdls_keys import write_key_file
from taiji2_sim_pkg.nodes.onboard_executor import OnboardExecutor

from fuzz_decoders import (
    Budget,
    DownlinkIntake,
    UplinkIntake,
    downlink_burst,
    fuzz_settings,
    table,
    uplink_burst,
    uplink_keys,
)

KEYS = uplink_keys()
SIGNER = FrameSigner(KEYS, 2)
#: genuine frames of SPI 1 and 2 (an eavesdropper has them: the data travel in the clear)
GENUINE = [FrameSigner(KEYS, 1).sign(table(0)), SIGNER.sign(table(1, 2_100.0)), SIGNER.sign(table(2, 2_200.0))]


def test_any_uplink_burst_is_verified_counted_and_bounded(context, tmp_path):
    node = OnboardExecutor(context=context, cli_args=["--ros-args", "-p",
                                                      f"key_file:={write_key_file(tmp_path / 'k.json', KEYS)}"])
    intake = UplinkIntake(node)

    @fuzz_settings(300)
    @given(uplink_burst(SIGNER, GENUINE))
    def fuzz(burst):
        intake.check(*burst, Budget())

    try:
        fuzz()
        # the fuzz reached past authentication: garbage inside authentic frames failed acceptance (TM[1,2])
        assert node.verifier.accepted > 0 and node._invalid > 0, (node.verifier.accepted, node._invalid)
        assert sum(node.verifier.refused.values()) > 0
    finally:
        node.destroy_node()


def test_any_downlink_burst_is_decoded_counted_and_bounded(context):
    node = GroundReceiver(context=context)
    intake = DownlinkIntake(node)

    @fuzz_settings(300)
    @given(downlink_burst())
    def fuzz(burst):
        intake.check(*burst, Budget())

    try:
        fuzz()
        state = node.reception()
        assert state["rejected"] and node._report_packets > 0, state
    finally:
        node.destroy_node()
