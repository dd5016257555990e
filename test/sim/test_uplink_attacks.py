"""The intruder's frames (taiji2_sim_pkg.uplink_attacks) against the onboard verifier: after the genuine frames,
every attack frame is refused with the reason it was built for, and none authenticates. No DDS."""

from __future__ import annotations

import pytest

from taiji2_runtime.packets.scheduling import Activity, encode_insert_activities
from taiji2_runtime.packets.sdls import FrameRefused, FrameSigner, FrameVerifier
from taiji2_runtime.packets.sdls_keys import KeyTable, SecurityAssociation, new_key_table
from taiji2_sim_pkg.uplink_attacks import ATTACK_KINDS, build_attacks

_NS = 1_000_000_000


def _genuine(keys: KeyTable, n: int = 5) -> tuple[list[bytes], list[int]]:
    signer = FrameSigner(keys)  # SPI 2, the newest active
    frames = [signer.sign(encode_insert_activities(k, [Activity((500 + 20 * k) * _NS, (1e-6, 0.0, 0.0))]))
              for k in range(n)]
    return frames, [(100 + 10 * k) * _NS for k in range(n)]


def test_every_attack_frame_is_refused_with_its_reason():
    onboard = new_key_table((1, 2), revoked=(1,))
    leaked = KeyTable([SecurityAssociation(1, onboard.get(1).key)])  # the intruder's copy of the revoked key
    verifier = FrameVerifier(onboard)
    genuine, arrivals = _genuine(onboard)
    for frame in genuine:
        verifier.verify(frame)
    attacks = build_attacks(genuine, arrivals, list(ATTACK_KINDS), leaked, instances=4, flood=40, seed=3)
    assert {a.kind for a in attacks} == set(ATTACK_KINDS)
    assert sum(a.kind == "garbage" for a in attacks) == 40
    for attack in sorted(attacks, key=lambda a: a.arrival_ns):
        with pytest.raises(FrameRefused) as refused:
            verifier.verify(attack.frame)
        if attack.expected != "any":
            assert refused.value.reason == attack.expected, (attack.kind, refused.value)
    assert verifier.accepted == len(genuine)
    assert sum(verifier.refused.values()) == len(attacks)
    assert all(a.arrival_ns > arrivals[0] for a in attacks)


def test_attacks_need_what_they_model():
    genuine, arrivals = _genuine(new_key_table((1, 2), revoked=(1,)))
    with pytest.raises(ValueError, match="revoked"):
        build_attacks(genuine, arrivals, ["revoked"], None)
    with pytest.raises(ValueError, match="choose from"):
        build_attacks(genuine, arrivals, ["jamming"], None)
    with pytest.raises(ValueError, match="no genuine frame"):
        build_attacks([], [], ["replay"], None)
