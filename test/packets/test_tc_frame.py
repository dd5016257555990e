"""TC transfer frames (CCSDS 232.0-B): header fields, FECF, delimiting (no DDS)."""

from __future__ import annotations

import pytest

from taiji2_runtime.packets.scheduling import MAX_ACTIVITIES_PER_TC, Activity, encode_insert_activities
from taiji2_runtime.packets.sdls import MAX_DATA_OCTETS
from taiji2_runtime.packets.tc_frame import (
    MAX_FRAME_OCTETS,
    SPACECRAFT_ID,
    FrameError,
    TcFrameHeader,
    decode_frame,
    encode_frame,
    split_frames,
)


def test_header_fields_round_trip_and_layout():
    h = TcFrameHeader(spacecraft_id=0x3FF, virtual_channel_id=63, frame_octets=1024, sequence=255,
                      bypass=True, control_command=True)
    packed = h.pack()
    # version 00, bypass 1, control 1, spare 00, SCID 0x3FF | VCID 111111, length 1023 | sequence
    assert packed == bytes([0b0011_0011, 0xFF, 0b1111_1111, 0xFF, 0xFF])
    assert TcFrameHeader.unpack(packed) == h
    with pytest.raises(ValueError):
        TcFrameHeader(0, 0, MAX_FRAME_OCTETS + 1, 0).pack()


def test_frame_round_trip_and_fecf():
    frame = encode_frame(b"\x01\x02\x03", 7)
    assert len(frame) == 5 + 3 + 2
    header, data = decode_frame(frame)
    assert data == b"\x01\x02\x03"
    assert (header.spacecraft_id, header.virtual_channel_id, header.sequence, header.bypass,
            header.control_command, header.frame_octets) == (SPACECRAFT_ID, 0, 7, True, False, 10)
    bad = bytearray(frame)
    bad[6] ^= 0x10
    with pytest.raises(FrameError) as e:
        decode_frame(bytes(bad))
    assert e.value.kind == "bad_fecf"


@pytest.mark.parametrize(("octets", "kind"), [(b"", "truncated"), (b"\x22\xa2", "truncated")])
def test_short_octets_are_truncated(octets, kind):
    with pytest.raises(FrameError) as e:
        decode_frame(octets)
    assert e.value.kind == kind


def test_length_field_against_octets():
    frame = encode_frame(b"abcdef", 0)
    with pytest.raises(FrameError, match="truncated"):
        decode_frame(frame[:-1])
    with pytest.raises(FrameError, match="oversized"):
        decode_frame(frame + b"\x00")
    with pytest.raises(FrameError, match="oversized"):
        decode_frame(frame, max_octets=len(frame) - 1)


def test_split_frames_by_length_field():
    frames = [encode_frame(bytes([k]) * (k + 1), k) for k in range(5)]
    assert split_frames(b"".join(frames)) == frames
    assert split_frames(b"") == []
    with pytest.raises(FrameError, match="cut short"):
        split_frames(b"".join(frames)[:-1])
    with pytest.raises(FrameError, match="trailing"):
        split_frames(b"".join(frames) + b"\x00\x00")


def test_a_full_tc_11_4_fits_one_secured_frame():
    acts = [Activity(10**12 + k * 10**8, (1e-6, 0.0, -1e-6)) for k in range(MAX_ACTIVITIES_PER_TC)]
    assert len(encode_insert_activities(0, acts)) <= MAX_DATA_OCTETS
