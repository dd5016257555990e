"""The ground station on Yamcs (issue 40 items 2 and 3): a real Yamcs 5.12 server (Java, from PyPI) started on a
data directory, fed through its TCP data link by the ground station front end, archiving every packet; the
calibration's loader reads the archive through the API and gets what the packet file gives.

One Yamcs per module (it starts in 2-8 s, about 250 MB); ports are chosen free for the run. Skipped with
one line where the Java runtime or the Yamcs jars are not installed (they are in requirements-dev.txt).
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from taiji2_ground_pkg.mcs.errors import GroundError
from taiji2_ground_pkg.mcs.yamcs_api import parse_yamcs_url, wait_for_link_count
from taiji2_ground_pkg.raw_data import load_raw_data
from taiji2_runtime.packets.bulk_encode import encode_streams
from taiji2_runtime.packets.walk import walk_packets

from contract_bags import ground_segment_data
from support import PYTHON, free_port, python_subprocess_env, require_yamcs, running_yamcs

require_yamcs()

N_SAMPLES = 3000  # 300 s at 10 Hz: 9,300 packets


@pytest.fixture(scope="module")
def yamcs(tmp_path_factory):
    with running_yamcs(tmp_path_factory.mktemp("yamcs")) as server:
        yield server


def _packets() -> bytes:
    d = ground_segment_data(N_SAMPLES, 7)
    s = d["stamps"] - d["stamps"][0] + 10**9  # onboard time from 1 s
    return encode_streams({"star_tracker": (s, np.column_stack([d["quat"], d["cov"]])), "grs1": (s, d["volts"][0]),
                           "grs2": (s, d["volts"][1]),
                           "executed_torque": (s[::10], np.column_stack([d["torque"], np.zeros_like(d["torque"])]))})


def test_station_feeds_yamcs_and_the_archive_calibrates_as_the_packet_file(yamcs, tmp_path):
    from taiji2_ground_pkg.mcs.station import StationFrontEnd

    octets = _packets()
    walk = walk_packets(octets)
    packets = [octets[a:b] for a, b in zip(walk.starts.tolist(), walk.ends.tolist(), strict=True)]
    station = StationFrontEnd(yamcs.station_port)
    try:
        station.send(packets[: len(packets) // 2])  # queued until Yamcs's link connects (its 10-s retry)
        station.send(packets[len(packets) // 2:])
        assert wait_for_link_count(yamcs.url, len(packets)) == len(packets)
        assert station.queued() == 0 and station.sent_packets == len(packets) and station.connections == 1
    finally:
        station.close()
    (tmp_path / "sent.tm").write_bytes(octets)
    from_file = load_raw_data(tmp_path / "sent.tm")
    from_archive = load_raw_data(yamcs.url)
    # every packet archived, and the same samples, to the bit
    assert from_archive.packets.per_apid == from_file.packets.per_apid
    for stream in ("star_tracker", "grs1", "grs2"):
        assert np.array_equal(getattr(from_archive, stream).stamp_ns, getattr(from_file, stream).stamp_ns), stream
    assert np.array_equal(from_archive.grs1.voltages_v, from_file.grs1.voltages_v)
    assert np.array_equal(from_archive.star_tracker.quat_xyzw, from_file.star_tracker.quat_xyzw)
    # a time range of generation times: the first 100 s after the mission epoch + 1 s
    part = load_raw_data(yamcs.url + "?start=2035-01-01T00:00:01Z&stop=2035-01-01T00:01:41Z",
                         required=("/taiji2/star_tracker",))
    assert len(part.star_tracker.stamp_ns) == 1000


def test_bad_addresses_are_one_line_naming_the_address(yamcs):
    for url, words in (("yamcs://127.0.0.1/taiji2", "yamcs://HOST:PORT/INSTANCE"),
                       ("yamcs://127.0.0.1:8090/", "name one Yamcs instance"),
                       ("yamcs://127.0.0.1:8090/taiji2?begin=1", "unknown option"),
                       ("yamcs://127.0.0.1:8090/taiji2?start=yesterday", "not an ISO 8601 time")):
        with pytest.raises(GroundError, match=words):
            parse_yamcs_url(url)
    other = yamcs.url.replace("/taiji2", "/nosuch")
    with pytest.raises(ValueError, match="no instance 'nosuch'"):
        load_raw_data(other)
    # through the command line: one line naming the address as given, exit status 2
    silent = f"yamcs://127.0.0.1:{free_port()}/taiji2"
    proc = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "calibrate", silent], env=python_subprocess_env(),
                          capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"error: taiji2 calibrate: {silent}: cannot read the Yamcs archive: "), lines[0]


def test_serve_prints_the_address_once_ready_and_stops_cleanly_on_sigterm(tmp_path):
    http = free_port()
    proc = subprocess.Popen([PYTHON, "-m", "taiji2_apps.cli.main", "ground", "serve", "--data-dir",
                             str(tmp_path / "ground"), "--http-port", str(http), "--station-port",
                             str(free_port())], env=python_subprocess_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline().strip()  # printed once the instance runs
        assert line == f"yamcs://127.0.0.1:{http}/taiji2", proc.stderr.read() if not line else line
        proc.terminate()
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert "Yamcs stopped" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
