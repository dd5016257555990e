"""CCSDS Space Packets (issue 22): codec, files, round trips, ccsdspy, damaged streams, CLI (no DDS)."""

from __future__ import annotations

import io
import json
import os
import subprocess

import numpy as np
import pytest

from taiji2_estimator_pkg.io import RawBagError
from taiji2_ground_pkg.raw_data import load_raw_data
from taiji2_runtime.packets.bag_io import read_bag_streams, write_bag
from taiji2_runtime.packets.bulk_decode import decode_packet_buffers
from taiji2_runtime.packets.bulk_encode import encode_stream, encode_streams
from taiji2_runtime.packets.cuc import cuc_decode_ns, cuc_encode, cuc_encode_ns, cuc_pack, cuc_unpack_ns
from taiji2_runtime.packets.definition import STREAM_BY_APID, STREAMS
from taiji2_runtime.packets.files import is_packet_path, read_packets
from taiji2_runtime.packets.packetize import PacketError, decode_packet, encode_packet
from taiji2_runtime.packets.telecommand import decode_torque_tc, encode_torque_tc
from taiji2_runtime.packets.time_correlation import TimeCorrelation

from contract_bags import ground_segment_data, write_ground_segment_bag
from packet_faults import corrupt_stream
from support import PYTHON, python_subprocess_env

EPOCH = TimeCorrelation(1_700_000_000.0)  # the ground-segment bags' stamps start at 1.7e9 s
NAMES = ("star_tracker", "grs1", "grs2", "executed_torque")


def _streams(n=300, seed=5):
    d = ground_segment_data(n, seed)
    s = d["stamps"]
    return {"star_tracker": (s, np.column_stack([d["quat"], d["cov"]])), "grs1": (s, d["volts"][0]),
            "grs2": (s, d["volts"][1]),
            "executed_torque": (s[::10], np.column_stack([d["torque"], np.zeros_like(d["torque"])]))}


def _taiji2(*argv):
    env = python_subprocess_env()
    env.setdefault("ROS_DOMAIN_ID", os.environ.get("ROS_DOMAIN_ID", "0"))
    return subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", *map(str, argv)], capture_output=True,
                          text=True, timeout=120, env=env)


def test_cuc_exact_within_half_resolution():
    ns = np.array([0, 1, 29, 30, 100_000_000, 999_999_999, 1_700_000_000 * 10**9 + 123_456_789, 2**32 * 10**9 - 1])
    coarse, fine = cuc_encode_ns(ns)
    assert fine.max() < 2**24
    back = cuc_decode_ns(coarse, fine)
    assert np.abs(back - ns).max() <= 30  # half of 2**-24 s = 29.8 ns
    with pytest.raises(ValueError, match="outside the CUC range"):
        cuc_encode_ns(np.array([-1]))


def test_cuc_one_time_equals_vectorised():
    """The per-packet encoder (Python integers) gives the counts of the vectorised one, at the rounding edges too."""
    rng = np.random.default_rng(7)
    ns = np.concatenate([rng.integers(0, 2**32 * 10**9 - 10**9, 20_000), np.arange(0, 10**9, 999_983),
                         [0, 29, 30, 31, 999_999_970, 999_999_999]])
    coarse, fine = cuc_encode_ns(ns)
    assert [cuc_encode(int(v)) for v in ns] == list(zip(coarse.tolist(), fine.tolist(), strict=True))
    assert all(abs(cuc_unpack_ns(cuc_pack(int(v))) - int(v)) <= 30 for v in ns[:2000])
    for bad in (-1, 2**32 * 10**9):
        with pytest.raises(ValueError, match="outside the CUC range"):
            cuc_encode(bad)


def test_per_sample_codec_equals_bulk_and_names_defects():
    stream = STREAM_BY_APID[0x111]
    onboard = np.arange(5, dtype=np.int64) * 100_000_000 + 16383 * 10**8
    values = np.random.default_rng(1).normal(size=(5, 6))
    bulk = encode_stream(stream, onboard, values, first_seq_count=16382)  # wraps after two packets
    for k in range(5):
        single = encode_packet(stream, 16382 + k, int(onboard[k]), values[k])
        assert single == bulk[k].tobytes()
        sample = decode_packet(single)
        assert sample.seq_count == (16382 + k) % 16384 and np.array_equal(sample.values, values[k])
        assert abs(sample.onboard_ns - onboard[k]) <= 30
    good = bulk[0].tobytes()
    damaged = bytearray(good)
    damaged[20] ^= 4
    unknown = encode_packet(STREAM_BY_APID[0x101], 0, 0, np.zeros(13)).replace(b"\x09\x01", b"\x09\x05", 1)
    for octets, kind in ((damaged, "crc_error"), (good[:30], "truncated"), (unknown, "crc_error")):
        with pytest.raises(PacketError) as err:
            decode_packet(bytes(octets))
        assert err.value.kind == kind


def test_telecommand_round_trip_through_spacepackets():
    from spacepackets.ecss.tc import PusTc

    tc = encode_torque_tc(16385, 1_234_567_890_123, [1e-3, -2e-3, 3e-3])
    parsed = PusTc.unpack(tc)
    assert (parsed.apid, parsed.service, parsed.message_subtype, parsed.seq_count) == (0x140, 130, 1, 1)
    back = decode_torque_tc(tc)
    assert np.array_equal(back.torque_n_m, [1e-3, -2e-3, 3e-3])
    assert abs(back.execute_onboard_ns - 1_234_567_890_123) <= 30
    with pytest.raises(PacketError, match="crc_error"):
        decode_torque_tc(tc[:-1] + bytes([tc[-1] ^ 1]))


@pytest.mark.parametrize("telecommands", [False, True])
def test_bag_packets_bag_round_trip(tmp_path, telecommands):
    data = write_ground_segment_bag(tmp_path / "bag")
    streams, left_out = read_bag_streams(tmp_path / "bag")
    assert not any(left_out.values())
    octets = encode_streams(streams, EPOCH, telecommands=telecommands)
    decoded = decode_packet_buffers([("mem", octets)], EPOCH)
    for name in NAMES:
        assert np.array_equal(decoded.streams[name].values, streams[name][1])
        assert np.abs(decoded.streams[name].stamp_ns - streams[name][0]).max() <= 30
        assert decoded.report.per_apid[decoded.streams[name].stream.apid]["kept"] == len(streams[name][0])
    if telecommands:
        assert np.array_equal(decoded.telecommands.values, streams["executed_torque"][1])
    write_bag(tmp_path / "bag2", decoded)
    again, _ = read_bag_streams(tmp_path / "bag2")
    assert encode_streams(again, EPOCH, telecommands=telecommands) == octets  # stamps stay on their CUC counts
    a, b = load_raw_data(tmp_path / "bag"), load_raw_data(tmp_path / "bag2")
    assert np.array_equal(a.star_tracker.quat_xyzw, b.star_tracker.quat_xyzw)
    assert np.array_equal(a.star_tracker.cov_rad2, b.star_tracker.cov_rad2)
    assert np.array_equal(a.grs2.voltages_v, b.grs2.voltages_v) and np.array_equal(a.commands.torque_n_m,
                                                                                   b.commands.torque_n_m)
    assert np.abs(b.grs1.stamp_ns - data["stamps"]).max() <= 30


def test_ccsdspy_decodes_with_the_documented_definition(tmp_path):
    """The definition as docs/interfaces.md gives it, typed into NASA's ccsdspy; nothing of ours decodes."""
    import ccsdspy
    from ccsdspy.utils import split_by_apid

    streams = _streams()
    octets = encode_streams(streams, EPOCH)
    head = [ccsdspy.PacketField("cuc_pfield", "uint", 8), ccsdspy.PacketField("cuc_coarse", "uint", 32),
            ccsdspy.PacketField("cuc_fine", "uint", 24)]
    fields = {0x101: ["qx", "qy", "qz", "qw", *[f"cov{i}" for i in range(9)]],
              0x111: ["vx1", "vx2", "vy1", "vy2", "vz1", "vz2"], 0x112: ["vx1", "vx2", "vy1", "vy2", "vz1", "vz2"],
              0x121: ["tx", "ty", "tz", "fx", "fy", "fz"]}
    parts = split_by_apid(io.BytesIO(octets))
    assert set(parts) == set(fields)
    for apid, names in fields.items():
        pkt = ccsdspy.FixedLength([*head, *[ccsdspy.PacketField(n, "float", 64) for n in names],
                                   ccsdspy.PacketField("crc", "uint", 16)])
        got = pkt.load(parts[apid], include_primary_header=True)
        name = STREAM_BY_APID[apid].name
        stamps, values = streams[name]
        n = len(stamps)
        assert np.array_equal(got["CCSDS_SEQUENCE_COUNT"], np.arange(n) % 16384)
        assert set(got["CCSDS_SECONDARY_FLAG"]) == {1} and set(got["CCSDS_PACKET_TYPE"]) == {0}
        assert set(got["cuc_pfield"]) == {0x2F}
        t_ns = got["cuc_coarse"].astype(np.int64) * 10**9 + np.rint(got["cuc_fine"] * 1e9 / 2**24).astype(np.int64)
        assert np.abs(t_ns + EPOCH.offset_ns - stamps).max() <= 30
        assert np.array_equal(np.column_stack([got[k] for k in names]), values)
        from fastcrc import crc16  # the CRC-16-CCITT of the page: poly 0x1021, init 0xFFFF, no reflection
        parts[apid].seek(0)
        raw = parts[apid].read()
        size = len(raw) // n
        assert all(crc16.ibm_3740(raw[k * size:(k + 1) * size - 2]) == got["crc"][k] for k in range(n))


def test_damaged_stream_every_defect_counted():
    streams = _streams(2000, seed=2)
    octets = encode_streams(streams, EPOCH)
    idle = b"\x07\xff\xc0\x00\x00\x03" + b"\x00" * 4
    unknown = encode_packet(STREAM_BY_APID[0x111], 0, 0, np.zeros(6)).replace(b"\x09\x11", b"\x09\x55", 1)
    from taiji2_runtime.packets.packetize import packet_crc
    unknown = unknown[:-2] + packet_crc(unknown[:-2]).to_bytes(2, "big")
    damaged, done = corrupt_stream(octets, seed=4, flip=0.01, drop=0.005, duplicate=0.005, reorder_block=40)
    cut = len(damaged) - 17
    decoded = decode_packet_buffers([("a", idle + damaged[:cut] + idle[:0]), ("b", unknown + idle)], EPOCH)
    r = decoded.report
    defects = r.defects()
    assert defects["crc_error"] + defects.get("corrupt_header", 0) == done["flipped"]
    assert defects["duplicate"] == done["duplicated"]
    assert defects["truncated"] == 1 and r.idle == 2 and r.unknown_apid == {0x155: 1}
    total_gap = sum(c.get("sequence_gap", 0) for c in r.per_apid.values())
    assert total_gap == done["flipped"] + done["dropped"]
    for name in NAMES:  # what is kept is exact and in time order
        s = decoded.streams[name]
        assert np.all(np.diff(s.stamp_ns) > 0)
        rows = np.searchsorted(streams[name][0], s.stamp_ns - 30)
        assert np.array_equal(s.values, streams[name][1][rows])


def test_wraps_and_a_loss_longer_than_half_the_counter():
    stream = STREAM_BY_APID[0x101]
    n = 40_000
    onboard = np.arange(n, dtype=np.int64) * 100_000_000
    values = np.random.default_rng(0).normal(size=(n, 13))
    rows = encode_stream(stream, onboard, values)
    keep = np.ones(n, dtype=bool)
    keep[10_000:19_500] = False  # 9,500 packets lost: more than 8,192, less than 16,384
    decoded = decode_packet_buffers([("x", rows[keep].tobytes())])
    counts = decoded.report.per_apid[0x101]
    assert counts["sequence_gap"] == 9_500 and counts["wraps"] == 2 and counts["kept"] == keep.sum()
    assert np.array_equal(decoded.streams["star_tracker"].values, values[keep])


def test_packet_directory_time_correlation_and_detection(tmp_path):
    streams = _streams()
    corr = TimeCorrelation(1_699_999_000.0, 1.000001)
    (tmp_path / "dir").mkdir()
    for name, (stamps, values) in streams.items():  # one file per APID
        (tmp_path / "dir" / f"{name}.tm").write_bytes(encode_streams({name: (stamps, values)}, corr))
    (tmp_path / "dir" / "time_correlation.yaml").write_text("time_correlation:\n  offset_s: 1699999000.0\n"
                                                            "  rate: 1.000001\n")
    assert is_packet_path(tmp_path / "dir") and not is_packet_path(tmp_path / "dir" / "time_correlation.yaml")
    exp = load_raw_data(tmp_path / "dir")
    assert exp.storage == "ccsds" and exp.packets is not None
    assert np.abs(exp.grs1.stamp_ns - streams["grs1"][0]).max() <= 31
    assert np.array_equal(exp.star_tracker.quat_xyzw, streams["star_tracker"][1][:, :4])
    identity = read_packets(tmp_path / "dir" / "grs1.tm")  # a single file: identity unless told
    assert np.abs(identity.streams["grs1"].stamp_ns - streams["grs1"][0]).max() > 10**8
    (tmp_path / "named.mcap").write_bytes((tmp_path / "dir" / "grs1.tm").read_bytes())  # content, not name
    assert is_packet_path(tmp_path / "named.mcap")


def test_calibrate_packets_equals_bag_and_damaged_within_sigma(tmp_path):
    from taiji2_estimator_pkg.calibration import align_streams, calibrate
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_model.config import load_config
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    config = load_config("type1", overrides={"maneuver.duration_s": 1800.0})
    out = simulate_batch(config, 3, maneuver_torque_commands(config))
    stamps = np.rint(out.t_s * 1e9).astype(np.int64)
    torque = out.truth.torque_command_n_m[::10]
    streams = {"star_tracker": (stamps, np.column_stack([out.st_quat_xyzw, out.st_cov_rad2])),
               "grs1": (stamps, out.voltages_v[:, 0]), "grs2": (stamps, out.voltages_v[:, 1]),
               "executed_torque": (stamps[::10], np.column_stack([torque, np.zeros_like(torque)]))}
    octets = encode_streams(streams)
    (tmp_path / "clean.tm").write_bytes(octets)
    write_bag(tmp_path / "bag", decode_packet_buffers([("clean", octets)]))
    (tmp_path / "damaged.tm").write_bytes(corrupt_stream(octets, seed=5)[0])
    instrument = InstrumentModel.from_layout("type1")

    def estimate(path):
        raw = load_raw_data(path)
        grs = {g: (raw.grs(g).stamp_ns, raw.grs(g).voltages_v) for g in (1, 2)}
        table = calibrate(align_streams(raw.star_tracker.stamp_ns, raw.star_tracker.quat_xyzw, grs,
                                        instrument.sample_rate_hz), instrument)
        return (np.concatenate([np.r_[r.scale_factors, r.com_offset_m] for r in table.grs]),
                np.concatenate([np.sqrt(np.r_[np.diag(r.scale_factors_cov), np.diag(r.com_offset_cov)])
                                for r in table.grs]))

    bag, sigma = estimate(tmp_path / "bag")
    clean, _ = estimate(tmp_path / "clean.tm")
    damaged, _ = estimate(tmp_path / "damaged.tm")
    np.testing.assert_allclose(clean, bag, rtol=1e-9, atol=0)
    assert np.all(np.abs(damaged - clean) < sigma)


def test_cli_export_import_info_and_bad_input(tmp_path):
    write_ground_segment_bag(tmp_path / "bag")
    (tmp_path / "corr.yaml").write_text("offset_s: 1700000000.0\n")
    res = _taiji2("bag", "export", tmp_path / "bag", "--ccsds", tmp_path / "exp.tm", "--time-correlation",
                  tmp_path / "corr.yaml")
    assert res.returncode == 0, res.stderr
    res = _taiji2("bag", "import", tmp_path / "exp.tm", "-o", tmp_path / "back", "--time-correlation",
                  tmp_path / "corr.yaml")
    assert res.returncode == 0, res.stderr
    back, bag = load_raw_data(tmp_path / "back"), load_raw_data(tmp_path / "bag")
    assert np.array_equal(back.grs1.voltages_v, bag.grs1.voltages_v)
    octets = (tmp_path / "exp.tm").read_bytes()
    damaged = bytearray(octets[:-10])
    damaged[500] ^= 0x10
    (tmp_path / "damaged.tm").write_bytes(bytes(damaged))
    res = _taiji2("bag", "info", tmp_path / "damaged.tm", "--json")
    assert res.returncode == 0, res.stderr
    info = json.loads(res.stdout)
    assert info["packets"]["defects"] == {"crc_error": 1, "truncated": 1, "sequence_gap": 1}
    res = _taiji2("bag", "info", tmp_path / "damaged.tm")
    assert "crc_error 1" in res.stdout and "truncated 1" in res.stdout and "Traceback" not in res.stderr
    (tmp_path / "garbage.tm").write_bytes(os.urandom(3000))
    (tmp_path / "short.tm").write_bytes(octets[:40])
    (tmp_path / "late.yaml").write_text("time_correlation: {offset_s: 1800000000.0}\n")
    for argv, words in (
        (("calibrate", tmp_path / "garbage.tm"), "neither a ROS 2 bag nor CCSDS Space Packets"),
        (("bag", "import", tmp_path / "short.tm", "-o", tmp_path / "x"), "not a CCSDS packet file"),
        (("bag", "export", tmp_path / "bag", "--ccsds", tmp_path / "exp.tm"), "already exists"),
        (("bag", "export", tmp_path / "bag", "--ccsds", tmp_path / "neg.tm", "--time-correlation",
          tmp_path / "late.yaml"), "outside the CUC range"),
    ):
        res = _taiji2(*argv)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 2 and len(lines) == 1 and words in lines[0], res.stderr
    with pytest.raises(RawBagError, match="no packets of raw topic"):
        only = encode_streams({"grs1": _streams()["grs1"]}, EPOCH)
        (tmp_path / "only.tm").write_bytes(only)
        load_raw_data(tmp_path / "only.tm")


def test_streams_definition_is_consistent():
    assert [s.packet_octets for s in STREAMS] == [120, 64, 64, 64]
    assert len({s.apid for s in STREAMS}) == 4
