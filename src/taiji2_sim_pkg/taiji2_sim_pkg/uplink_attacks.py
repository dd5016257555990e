"""What an intruder on the uplink sends: TC transfer frames built to be refused (docs/security.md, "Attacks").

The intruder has what an eavesdropper near the ground station or the spacecraft has: the genuine frames as they
fly (SDLS authentication mode leaves them in the clear), and, for the ``revoked`` attack, a key the operators
have since revoked (a leaked old key). It never has an active key. Each kind, ``instances`` frames:

* ``forged``: a table of its own (thrusters at full torque) signed with a key of its own under the active SPI of
  the genuine frames (refused ``bad_mac``), and under an SPI the spacecraft does not know (``unknown_spi``);
* ``replay``: copies of genuine frames, arriving after them (``replay``);
* ``bit_flip``: a genuine frame with one bit of its data flipped, the FECF refitted (``bad_mac``) or not
  (``bad_fecf``);
* ``revoked``: a table of its own signed with the leaked revoked key (``revoked_spi``);
* ``garbage``: ``flood`` random frames with a plausible primary header (``bad_fecf``, ``bad_header``, ...).

Every frame arrives 1 s after the genuine frame it is modelled on (or the first genuine one). Pure bytes in and
out; the node :mod:`taiji2_sim_pkg.nodes.uplink_intruder` puts them on the uplink.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taiji2_runtime.packets.scheduling import MAX_ACTIVITIES_PER_TC, Activity, encode_insert_activities
from taiji2_runtime.packets.sdls import SECURITY_HEADER_OCTETS, FrameSigner
from taiji2_runtime.packets.sdls_keys import KeyTable, new_key_table
from taiji2_runtime.packets.tc_frame import FECF_OCTETS, HEADER_OCTETS, TcFrameHeader, frame_crc

__all__ = ["ATTACK_KINDS", "AttackFrame", "build_attacks"]

ATTACK_KINDS = ("forged", "replay", "bit_flip", "revoked", "garbage")
_NS = 1_000_000_000
#: the intruder's own table: every thruster torque at 1e-4 N m (far beyond the maneuver's) for 12 s
_HOSTILE = [Activity(0, (1e-4, -1e-4, 1e-4))] * MAX_ACTIVITIES_PER_TC


@dataclass(frozen=True)
class AttackFrame:
    """One frame the intruder sends: its kind, the refusal it should meet onboard, its octets and arrival [ns]."""

    kind: str
    expected: str
    frame: bytes
    arrival_ns: int


def _hostile_table(release_ns: int, seq: int) -> bytes:
    return encode_insert_activities(seq, [Activity(release_ns + k * _NS, a.torque_n_m) for k, a in enumerate(_HOSTILE)])


def _spi_of(frame: bytes) -> int:
    return int.from_bytes(frame[HEADER_OCTETS:HEADER_OCTETS + 2], "big")


def build_attacks(genuine: list[bytes], arrival_ns: list[int], kinds: list[str], leaked: KeyTable | None, *,
                  instances: int = 3, flood: int = 50, seed: int = 0) -> list[AttackFrame]:
    """The intruder's frames against the ``genuine`` frames it saw (arriving onboard at ``arrival_ns``).

    Raises
    ------
    ValueError
        An unknown kind; ``replay``/``bit_flip``/``forged`` without a genuine frame to model them on;
        ``revoked`` without a leaked key.
    """
    unknown = sorted(set(kinds) - set(ATTACK_KINDS))
    if unknown:
        raise ValueError(f"attacks {unknown}: choose from {', '.join(ATTACK_KINDS)}")
    if not genuine:
        raise ValueError("no genuine frame seen: nothing to model the attacks on")
    rng = np.random.default_rng(seed)
    out: list[AttackFrame] = []
    picks = [int(i) for i in rng.choice(len(genuine), size=instances, replace=instances > len(genuine))]
    later = [arrival_ns[i] + _NS for i in picks]
    first = arrival_ns[0] + _NS
    # a release an hour after the first genuine arrival: inside the run, beyond any time margin
    release = arrival_ns[0] + 3600 * _NS
    if "forged" in kinds:
        own = new_key_table((_spi_of(genuine[0]),))  # the active SPI, a key of the intruder's own
        signer = FrameSigner(own, first_sequence=1 << 40)
        stranger = FrameSigner(new_key_table((0x7777,)))
        for k, t in enumerate(later):
            frame = (signer if k % 2 == 0 else stranger).sign(_hostile_table(release, 9000 + k))
            out.append(AttackFrame("forged", "bad_mac" if k % 2 == 0 else "unknown_spi", frame, t))
    if "replay" in kinds:
        out.extend(AttackFrame("replay", "replay", genuine[i], t) for i, t in zip(picks, later, strict=True))
    if "bit_flip" in kinds:
        for k, (i, t) in enumerate(zip(picks, later, strict=True)):
            frame = bytearray(genuine[i])
            data_start = HEADER_OCTETS + SECURITY_HEADER_OCTETS
            bit = int(rng.integers(8 * data_start, 8 * (len(frame) - FECF_OCTETS - 16)))
            frame[bit // 8] ^= 1 << (bit % 8)
            refit = k % 2 == 0
            if refit:
                frame[-FECF_OCTETS:] = frame_crc(bytes(frame[:-FECF_OCTETS])).to_bytes(FECF_OCTETS, "big")
            out.append(AttackFrame("bit_flip", "bad_mac" if refit else "bad_fecf", bytes(frame), t))
    if "revoked" in kinds:
        if leaked is None or not len(leaked):
            raise ValueError("revoked: no leaked key to sign with")
        signer = FrameSigner(leaked, first_sequence=1 << 41)
        out.extend(AttackFrame("revoked", "revoked_spi", signer.sign(_hostile_table(release, 9100 + k)), t)
                   for k, t in enumerate(later))
    if "garbage" in kinds:
        for k in range(flood):
            size = int(rng.integers(HEADER_OCTETS + FECF_OCTETS, 256))
            header = TcFrameHeader(int(rng.integers(0, 1024)), int(rng.integers(0, 64)), size, k & 0xFF).pack()
            out.append(AttackFrame("garbage", "any", header + rng.bytes(size - HEADER_OCTETS), first + k))
    return out
