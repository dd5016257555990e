"""SDLS authentication of TC frames (CCSDS 355.0-B, AES-256-GCM): the primitive against NIST, round trip, every
refusal reason, the anti-replay window, the frame security report, and a seeded fuzz of the verifier (no DDS)."""

from __future__ import annotations

import random

import pytest
from cryptography.hazmat.primitives.ciphers.aead import AESGCM

from taiji2_runtime.packets.packetize import PacketError
from taiji2_runtime.packets.sdls import (
    MAX_DATA_OCTETS,
    REFUSAL_REASONS,
    FrameRefused,
    FrameSigner,
    FrameVerifier,
    decode_frame_security_report,
    encode_frame_security_report,
    is_frame_security_report,
)
from taiji2_runtime.packets.sdls_keys import REVOKED, KeyTable, SecurityAssociation
from taiji2_runtime.packets.tc_frame import FECF_OCTETS, HEADER_OCTETS, encode_frame, frame_crc

KEYS = KeyTable([SecurityAssociation(1, bytes(range(32))), SecurityAssociation(2, bytes(range(32, 64))),
                 SecurityAssociation(7, bytes(range(64, 96)))])


def _refit_fecf(frame: bytes | bytearray) -> bytes:
    """``frame`` with its FECF recomputed (what an attacker who changes a frame does)."""
    body = bytes(frame[:-FECF_OCTETS])
    return body + frame_crc(body).to_bytes(2, "big")


def _reason(verifier: FrameVerifier, frame: bytes) -> str:
    with pytest.raises(FrameRefused) as e:
        verifier.verify(frame)
    return e.value.reason


# NIST CAVP gcmEncryptExtIV256.rsp, [Keylen = 256] [IVlen = 96] [PTlen = 0] [AADlen = 128] [Taglen = 128],
# Count = 0 and 1: the authentication-only case SDLS uses (empty plaintext, the frame as AAD)
NIST_GCM_256_AAD_ONLY = [
    ("78dc4e0aaf52d935c3c01eea57428f00ca1fd475f5da86a49c8dd73d68c8e223", "d79cf22d504cc793c3fb6c8a",
     "b96baa8c1c75a671bfb2d08d06be5f36", "3e5d486aa2e30b22e040b85723a06e76"),
    ("4457ff33683cca6ca493878bdc00373893a9763412eef8cddb54f91318e0da88", "699d1f29d7b8c55300bb1fd2",
     "6749daeea367d0e9809e2dc2f309e6e3", "d60c74d2517fde4a74e0cd4709ed43a9"),
]


@pytest.mark.parametrize(("key", "iv", "aad", "tag"), NIST_GCM_256_AAD_ONLY)
def test_aes_gcm_known_answer_nist(key, iv, aad, tag):
    aead = AESGCM(bytes.fromhex(key))
    assert aead.encrypt(bytes.fromhex(iv), b"", bytes.fromhex(aad)) == bytes.fromhex(tag)
    # and the signer computes its MAC exactly so: a frame whose key/IV/AAD are the vector's carries its tag
    table = KeyTable([SecurityAssociation(1, bytes.fromhex(key))])
    signer = FrameSigner(table, 1, first_sequence=int(iv, 16))
    frame = signer.sign(b"\x00")
    body = frame[:-FECF_OCTETS - 16]
    assert frame[-FECF_OCTETS - 16:-FECF_OCTETS] == aead.encrypt(bytes.fromhex(iv), b"", body)


def test_round_trip_layout_and_data_in_the_clear():
    signer = FrameSigner(KEYS, 2, first_sequence=5)
    verifier = FrameVerifier(KEYS)
    data = bytes(range(200))
    frame = signer.sign(data)
    assert len(frame) == HEADER_OCTETS + 2 + 12 + len(data) + 16 + FECF_OCTETS
    assert frame[5:7] == b"\x00\x02" and int.from_bytes(frame[7:19], "big") == 5
    assert frame[19:19 + len(data)] == data  # authentication only: the data stay in the clear
    assert verifier.verify(frame) == data
    assert verifier.verify(signer.sign(b"next")) == b"next"
    assert verifier.last_sequence == {2: 6} and verifier.accepted == 2
    assert signer.sign(bytes(MAX_DATA_OCTETS))  # the largest frame
    with pytest.raises(ValueError):
        signer.sign(bytes(MAX_DATA_OCTETS + 1))
    with pytest.raises(ValueError):
        signer.sign(b"")


def test_the_default_spi_is_the_newest_active_and_a_revoked_one_cannot_sign():
    assert FrameSigner(KEYS).spi == 7
    assert FrameSigner(KEYS.with_state(7, REVOKED)).spi == 2
    with pytest.raises(ValueError, match="revoked"):
        FrameSigner(KEYS.with_state(7, REVOKED), 7)
    with pytest.raises(ValueError, match="not in the key table"):
        FrameSigner(KEYS, 3)


def _tamper(frame: bytes, index: int) -> bytes:
    bad = bytearray(frame)
    bad[index] ^= 0x01
    return _refit_fecf(bad)


@pytest.mark.parametrize("where", ["primary_header_sequence", "spi_low_bit_to_other_known", "iv", "data", "mac"])
def test_any_tampered_byte_is_refused(where):
    signer = FrameSigner(KEYS, 2)
    frame = signer.sign(b"time-tagged table")
    index = {"primary_header_sequence": 4, "spi_low_bit_to_other_known": 6, "iv": 18, "data": 25,
             "mac": len(frame) - FECF_OCTETS - 1}[where]
    verifier = FrameVerifier(KEYS)
    # SPI 2 -> 3 is unknown; every other change fails the MAC
    expected = "unknown_spi" if where.startswith("spi") else "bad_mac"
    assert _reason(verifier, _tamper(frame, index)) == expected
    assert verifier.accepted == 0 and verifier.refused[expected] == 1
    assert verifier.verify(frame) == b"time-tagged table"  # the genuine one still passes (nothing advanced)


def test_a_tampered_frame_keeping_its_old_fecf_fails_the_fecf():
    frame = bytearray(FrameSigner(KEYS, 1).sign(b"abc"))
    frame[20] ^= 0x80
    assert _reason(FrameVerifier(KEYS), bytes(frame)) == "bad_fecf"


def test_replay_and_window():
    signer = FrameSigner(KEYS, 1)
    verifier = FrameVerifier(KEYS, window=10)
    first = signer.sign(b"a")
    verifier.verify(first)
    assert _reason(verifier, first) == "replay"
    older = FrameSigner(KEYS, 1).sign(b"b")  # another signer starting again at 1
    assert _reason(verifier, older) == "replay"
    far = FrameSigner(KEYS, 1, first_sequence=12).sign(b"c")  # 11 above the last accepted 1
    assert _reason(verifier, far) == "out_of_window"
    edge = FrameSigner(KEYS, 1, first_sequence=11).sign(b"d")  # exactly the window above
    assert verifier.verify(edge) == b"d"
    assert verifier.verify(far) == b"c"  # 12 is now within the window
    # each SPI has its own counter
    assert verifier.verify(FrameSigner(KEYS, 2).sign(b"e")) == b"e"


def test_revoked_unknown_and_missing_spi():
    frame = FrameSigner(KEYS, 7).sign(b"rotated out")
    onboard = KEYS.with_state(7, REVOKED)
    assert _reason(FrameVerifier(onboard), frame) == "revoked_spi"
    assert _reason(FrameVerifier(KeyTable([SecurityAssociation(1, bytes(32))])), frame) == "unknown_spi"
    verifier = FrameVerifier(KEYS)
    # a plain TC frame without SDLS: a short one has no room for the security header and trailer
    assert _reason(verifier, encode_frame(b"\x18\x00\xc0\x00\x00\x01\x00", 0)) == "no_spi"
    zero_spi = bytearray(frame)
    zero_spi[5:7] = b"\x00\x00"
    assert _reason(verifier, _refit_fecf(zero_spi)) == "no_spi"


def test_truncated_oversized_and_bad_header():
    frame = FrameSigner(KEYS, 1).sign(bytes(900))
    verifier = FrameVerifier(KEYS, max_frame_octets=512)
    assert _reason(verifier, frame) == "oversized"  # longer than this mission's maximum
    verifier = FrameVerifier(KEYS)
    assert _reason(verifier, frame[:-1]) == "truncated"
    assert _reason(verifier, frame[:3]) == "truncated"
    assert _reason(verifier, frame + b"\x00") == "oversized"
    assert _reason(FrameVerifier(KEYS, spacecraft_id=0x001), frame) == "bad_header"
    assert _reason(FrameVerifier(KEYS, virtual_channel_id=1), frame) == "bad_header"
    type_ad = bytearray(frame)
    type_ad[0] &= 0xDF  # bypass flag 0: Type-AD, needs a FARM this spacecraft does not run
    assert _reason(verifier, _refit_fecf(type_ad)) == "bad_header"
    assert verifier.accepted == 0 and sum(verifier.refused.values()) == 4


def test_frame_security_report_packet():
    signer = FrameSigner(KEYS, 2, first_sequence=300)
    verifier = FrameVerifier(KEYS)
    verifier.verify(signer.sign(b"x"))
    _reason(verifier, _tamper(signer.sign(b"y"), 20))
    report = verifier.report()
    assert (report.alarm, report.bad_mac, report.bad_sn, report.bad_sa, report.last_spi, report.last_sn_lsb) == (
        True, True, False, False, 2, 300 & 0xFF)
    assert report.fsr_word() >> 28 == 0b1100  # control word type 1, FSR version 100
    packet = encode_frame_security_report(report, 123 * 10**9, 9)
    assert is_frame_security_report(packet)
    decoded, onboard_ns = decode_frame_security_report(packet)
    assert decoded == report and onboard_ns == 123 * 10**9
    assert not verifier.report().bad_mac  # flags cover the refusals since the previous report; alarm stays
    assert verifier.report().alarm
    with pytest.raises(PacketError):
        decode_frame_security_report(packet[:-3])


def test_fuzzed_frames_never_raise_anything_else_and_are_never_accepted():
    rng = random.Random(41)
    signer = FrameSigner(KEYS, 1)
    verifier = FrameVerifier(KEYS.with_state(7, REVOKED), window=64)
    genuine = [signer.sign(rng.randbytes(rng.randrange(1, 960))) for _ in range(40)]
    for f in genuine:
        verifier.verify(f)
    revoked = FrameSigner(KEYS, 7)
    cases = 0
    seen: dict[str, int] = {}
    for _ in range(4000):
        base = rng.choice(genuine)
        kind = rng.randrange(7)
        if kind == 0:  # random octets
            candidate = rng.randbytes(rng.randrange(0, 1100))
        elif kind == 1:  # bit flips, FECF refitted half the time
            bad = bytearray(base)
            for _ in range(rng.randrange(1, 4)):
                bad[rng.randrange(len(bad))] ^= 1 << rng.randrange(8)
            candidate = _refit_fecf(bad) if rng.random() < 0.5 else bytes(bad)
        elif kind == 2:  # cut short
            candidate = base[:rng.randrange(len(base))]
        elif kind == 3:  # octets appended
            candidate = base + rng.randbytes(rng.randrange(1, 64))
        elif kind == 4:  # a replay
            candidate = base
        elif kind == 5:  # a random body in a valid header and FECF
            candidate = encode_frame(rng.randbytes(rng.randrange(0, 1000)), rng.randrange(256))
        else:  # signed with the revoked key, or far ahead of the window
            candidate = revoked.sign(b"z") if rng.random() < 0.5 else FrameSigner(
                KEYS, 1, first_sequence=10**6 + rng.randrange(10**6)).sign(b"w")
        with pytest.raises(FrameRefused) as e:
            verifier.verify(candidate)
        assert e.value.reason in REFUSAL_REASONS
        seen[e.value.reason] = seen.get(e.value.reason, 0) + 1
        cases += 1
    assert verifier.accepted == len(genuine)
    assert sum(verifier.refused.values()) == cases == 4000
    assert set(seen) >= {"truncated", "oversized", "bad_fecf", "bad_mac", "replay", "revoked_spi", "out_of_window",
                         "unknown_spi"}, seen


# --- the authenticated-encryption service: Yamcs's frames -------------------------------------------------------

#: a frame made by Yamcs 5.12.8's own classes (SecurityAssociationAes256Gcm128 through its TcFrameFactory, driven
#: from its bundled JavaScript engine on 2026-11-30): spacecraft 0x2A2, VC 0, SPI 5, IV 0 (Yamcs's first), the key
#: the ASCII of "0123456789abcdef" twice, the packet 1801C000000701020304050607
YAMCS_KEY = b"0123456789abcdef" * 2
YAMCS_PACKET = bytes.fromhex("1801C000000701020304050607")
YAMCS_FRAME = bytes.fromhex("22A2003100" "0005" "000000000000000000000000" "D672610112045E5AEC29848E1F"
                            "A13246E7F80B6498A143F9AD4D12A5E1" "9C3F")


def test_a_frame_yamcs_made_is_verified_and_decrypted():
    keys = KeyTable([SecurityAssociation(5, YAMCS_KEY, service="authenticated_encryption")])
    verifier = FrameVerifier(keys)
    verifier.last_sequence[5] = -1  # Yamcs's IV counter starts at 0, which this verifier's anti-replay refuses
    assert verifier.verify(YAMCS_FRAME) == YAMCS_PACKET
    # and our signer of that service makes the same security header, ciphertext and MAC from the same IV (the
    # frame sequence number, outside the masked header, and with it the FECF may differ)
    signer = FrameSigner(keys, 5, first_sequence=1)
    ours = signer.sign(YAMCS_PACKET)
    iv1 = (1).to_bytes(12, "big")
    expected = AESGCM(YAMCS_KEY).encrypt(iv1, YAMCS_PACKET, bytes([0, 0, 0, 0, 0, 0, 5]) + bytes(12))
    assert ours[5:7] == b"\x00\x05" and ours[7:19] == iv1 and ours[19:-2] == expected
    assert verifier.verify(ours) == YAMCS_PACKET  # IV 1, after Yamcs's 0


def test_the_authenticated_encryption_service_refuses_tampering_and_the_other_service():
    keys = KeyTable([SecurityAssociation(5, YAMCS_KEY, service="authenticated_encryption")])
    for k in (7, 19, 25, len(YAMCS_FRAME) - 10):  # SPI, ciphertext, MAC: each flipped bit is refused
        frame = bytearray(YAMCS_FRAME)
        frame[k] ^= 0x01
        verifier = FrameVerifier(keys)
        verifier.last_sequence[5] = -1
        assert _reason(verifier, _refit_fecf(frame)) in ("bad_mac", "unknown_spi"), k
    # the same key under the authentication service does not accept Yamcs's frame (the services differ)
    clear = FrameVerifier(KeyTable([SecurityAssociation(5, YAMCS_KEY)]))
    clear.last_sequence[5] = -1
    assert _reason(clear, YAMCS_FRAME) == "bad_mac"
