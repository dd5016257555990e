"""A link experiment feeding the ground station's Yamcs (issue 40 items 2-5): every packet the ground receives
reaches Yamcs's archive through its TCP data link, the calibration from the archive equals the calibration
of the ground's recording of the same run, the live estimates are Yamcs parameters with their alarms, and
the tables are commanded through Yamcs with their verification in its command history.

The short link of test_link_faults.py (fast passes, 600 s of data); one real Yamcs, started for the module.
"""

from __future__ import annotations

import json
import secrets

import numpy as np
import pytest

from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL
from taiji2_ground_pkg.mcs.yamcs_api import connect, parse_yamcs_url
from taiji2_ground_pkg.mcs.yamcs_instance import SdlsFrameLink
from taiji2_runtime.packets.sdls_keys import KeyTable, SecurityAssociation, load_key_file, write_key_file

from support import FAST_LINK_YAML, free_port, require_yamcs, run_taiji2, running_yamcs

require_yamcs()


@pytest.fixture(scope="module")
def sdls_keys(tmp_path_factory):
    """The spacecraft's key file, whose SPI 1 Yamcs signs with (authenticated encryption, Yamcs's service)."""
    table = KeyTable([SecurityAssociation(1, secrets.token_bytes(32), service="authenticated_encryption")])
    return write_key_file(tmp_path_factory.mktemp("keys") / "sdls_keys.json", table)


@pytest.fixture(scope="module")
def yamcs(tmp_path_factory, sdls_keys):
    # Yamcs signs the telecommands itself, as SDLS frames sent to a UDP port of the ground station
    frames = SdlsFrameLink(key=load_key_file(sdls_keys).get(1).key, spi=1, port=free_port())
    with running_yamcs(tmp_path_factory.mktemp("yamcs"), frames) as server:
        yield server


def _parameters(url):
    """Every ground parameter's value and monitoring result in the instance's realtime processor."""
    from taiji2_ground_pkg.mcs.ground_parameters import parameter_specs

    address = parse_yamcs_url(url)
    client = connect(address.server)  # as the operator (authentication is on)
    try:
        processor = client.get_processor(address.instance, "realtime")
        found = {}
        for spec in parameter_specs():
            pv = processor.get_parameter_value(f"/taiji2/{spec.name}")
            if pv is not None:
                found[spec.name] = (pv.eng_value, pv.monitoring_result)
        return found
    finally:
        client.close()


def _calibration(source):
    proc = run_taiji2("calibrate", str(source), "--json", timeout=300)
    assert proc.returncode in (0, 3), proc.stderr[-3000:]
    return json.loads(proc.stdout)


@pytest.mark.slow
def test_a_link_run_feeds_yamcs_and_its_archive_calibrates_as_the_ground_recording(tmp_path, yamcs, sdls_keys):
    link, bag, out = tmp_path / "link.yaml", tmp_path / "ground_bag", tmp_path / "out"
    link.write_text(FAST_LINK_YAML % 10**12)
    proc = run_taiji2("experiment", "--link", str(link), "--duration-s", "600", "--ground", yamcs.url,
                      "--station-port", str(yamcs.station_port), "--frame-port", str(yamcs.frames.port),
                      "--key-file", str(sdls_keys), "--record", str(bag), "--out", str(out), timeout=900)
    assert proc.returncode in (0, 3), proc.stderr[-3000:]
    ground = json.loads((out / "results.json").read_text())["link"]["yamcs"]
    # every packet the ground station received went to Yamcs, and Yamcs's link read every one
    assert ground["station"]["received"] > 0 and ground["station"]["queued"] == 0, ground
    assert ground["sent"] == ground["station"]["received"] == ground["read_by_yamcs"], ground
    assert f"sent {ground['sent']} to Yamcs; its link read {ground['read_by_yamcs']}" in proc.stdout
    # commanded through Yamcs: every table issued there, sent on its link, signed by the station, accepted and
    # executed onboard, each stage in Yamcs's command history (from the onboard TM[1,1] and TM[1,7])
    results = json.loads((out / "results.json").read_text())
    tables = results["link"]["commanding"]["tables"]
    commands = ground["commands"]
    assert tables > 0 and commands["issued"] == tables and not commands["failed"], commands
    for stage in ("Queued", "Released", "Sent", "Acceptance", "Execution"):
        assert commands[stage] == tables, (stage, commands)
    assert ground["station"]["uplinked"] == ground["station"]["planned"] == tables, ground["station"]
    # Yamcs signed them (its SDLS frame link) and the spacecraft's verifier, another implementation, accepted each
    assert ground["station"]["signed_by"] == "yamcs" and not ground["station"]["frames_refused"], ground["station"]
    assert results["link"]["commanding"]["acknowledged"] == tables  # the onboard reports name Yamcs's counts
    assert [h["seq_count"] for h in commands["history"]] == sorted({h["seq_count"] for h in commands["history"]})
    # the archive calibrates as the ground's recording: the same estimates, to the last digit
    from_archive, from_bag = _calibration(yamcs.url), _calibration(bag)
    for g in ("grs1", "grs2"):
        for key in ("scale_factors", "scale_factors_cov", "com_offset", "com_offset_cov"):
            assert from_archive[g][key] == from_bag[g][key], (g, key)
    # and diagnose reads the archive as the recording: the same samples on its grid, the same answer (600 s is
    # below its minimum: the check is that both paths reach the same data, cheaply)
    diagnoses = []
    for source, name in ((yamcs.url, "d_archive"), (bag, "d_bag")):
        proc = run_taiji2("diagnose", str(source), "--json", "--out", str(tmp_path / name), timeout=300)
        assert proc.returncode in (0, 3), proc.stderr[-3000:]
        diagnoses.append(json.loads(proc.stdout))
    assert diagnoses[0]["inputs"] == diagnoses[1]["inputs"] and diagnoses[0]["inputs"]["samples"] == 6000
    assert diagnoses[0]["status"] == diagnoses[1]["status"]
    # the live estimates are Yamcs parameters: the final ones, to the bit, each sigma checked against its
    # requirement by Yamcs's alarm (WARNING above it)
    # (the station's report is its last before shutdown: how many pushes it counts by then depends on the wall
    # time the run took; its writer pushes what is left as it closes, so the values below are the check)
    assert ground["station"]["parameter_failures"] == 0, ground
    values = _parameters(yamcs.url)
    for g in (1, 2):
        final = results[f"grs{g}"]
        for i, axis in enumerate(("Pphi", "Ptheta", "Ppsi")):
            value, rel = values[f"grs{g}_G_{axis}"], values[f"grs{g}_G_{axis}_rel_sigma"]
            assert value[0] == final["scale_factors"][i], (g, axis)
            sigma = np.sqrt(final["scale_factors_cov"][i][i])
            assert rel[0] == pytest.approx(sigma / abs(final["scale_factors"][i]), rel=1e-12)
            assert rel[1] == ("WARNING" if rel[0] > SCALE_FACTOR_REQUIREMENT_REL else "IN_LIMITS"), (g, axis, rel)
        for i, axis in enumerate("xyz"):
            value, sigma = values[f"grs{g}_d_{axis}"], values[f"grs{g}_d_{axis}_sigma"]
            assert value[0] == final["com_offset"][i], (g, axis)
            assert sigma[0] == pytest.approx(np.sqrt(final["com_offset_cov"][i][i]), rel=1e-12)
            assert sigma[1] == ("WARNING" if sigma[0] > COM_OFFSET_REQUIREMENT_M else "IN_LIMITS"), (g, axis, sigma)
    assert values["ground_missing_fraction"] == (0.0, "IN_LIMITS")  # this link loses nothing
    # and each stream's link statistics: the ground's final counts
    for name, counts in results["link"]["ground"].items():
        assert values[f"link_{name}_missing_fraction"] == (0.0, "IN_LIMITS"), name
        for k in ("received", "duplicate", "out_of_order", "missing", "held"):
            assert values[f"link_{name}_{k}"][0] == counts[k], (name, k, counts)
    # the verdict's requirement status (the run's one verdict evaluation), with its alarm
    verdict = results["verdict"]
    met = len(verdict["met"]) + bool((verdict["range"] or {}).get("met"))
    total = len(verdict["over_requirement"]) + (verdict["range"] is not None)
    assert values["verdict_requirements_met"][0] == met
    assert values["verdict_requirements_not_met"] == (total - met, "WARNING" if total > met else "IN_LIMITS")


def test_a_ground_url_without_a_running_yamcs_is_one_line_before_any_node(tmp_path):
    link = tmp_path / "link.yaml"
    link.write_text(FAST_LINK_YAML % 10**12)

    url = f"yamcs://127.0.0.1:{free_port()}/taiji2"
    proc = run_taiji2("experiment", "--link", str(link), "--duration-s", "600", "--ground", url,
                      "--out", str(tmp_path / "out"))
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and lines[-1].startswith(f"error: taiji2 experiment: --ground {url}: no running"), lines
    assert not list((tmp_path / "out").glob("*.log"))  # no node was started
