"""The first hour of a new user (issue 27): commands check their input and say what is wrong in one
line, help is complete and plain, outputs say what they are and land where documented.

Every command here starts no node graph (`taiji2 experiment`'s arguments are refused before any node
starts); the graph runs of `taiji2 experiment` are in test/nodes/test_experiment_cli.py.
"""

from __future__ import annotations

import argparse
import json
import subprocess

import numpy as np
import pytest

from support import REPO, python_subprocess_env, run_taiji2

_taiji2 = run_taiji2


def _one_error_line(proc: subprocess.CompletedProcess) -> str:
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


# -- row 3: taiji2 experiment checks its arguments before it starts a node ------------------------------

def _in_process(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    from taiji2_apps.cli.main import main

    status = main(argv)
    out, err = capsys.readouterr()
    return status, out, err


@pytest.mark.parametrize(("args", "expected"), [
    (["--duration-s", "0"], "--duration-s 0: must be at least one sample"),
    (["--duration-s", "-5"], "--duration-s -5: must be at least one sample"),
    (["--duration-s", "nan"], "--duration-s nan"),
    (["--layout", "type3"], "layout: unknown layout 'type3' (built-in: type1, type2)"),  # spacecraft_sim's words
    (["--method", "nosuch"], "method: 'nosuch' is not one of gls, paper"),  # the estimators' words
    (["--override", "nosuch.key=1"], "--override nosuch.key=1: nosuch: override key does not exist"),
    (["--override", "noise.srp.enabled"], "is not 'dotted.key=value'"),
    (["--maneuver", "no_such_file.yaml"], "cannot be read"),
    (["--seed", "-7"], "--seed -7"),
    (["--timeout-s", "0"], "--timeout-s 0"),
])
def test_experiment_refuses_bad_arguments_in_one_line_before_any_node(monkeypatch, capsys, args, expected):
    import subprocess as sp

    def no_node(*_args, **_kwargs):
        raise AssertionError("a node was started")

    monkeypatch.setattr(sp, "Popen", no_node)
    status, out, err = _in_process(["experiment", *args], capsys)
    lines = err.strip().splitlines()
    assert status == 2 and out == "" and len(lines) == 1 and lines[0].startswith("error: taiji2 experiment: "), err
    assert expected in lines[0]


@pytest.mark.parametrize(("argv", "words"), [
    (["experiment", "--seed", "abc"], "error: taiji2 experiment: argument --seed: invalid int value: 'abc'"),
    (["calibrate"], "error: taiji2 calibrate: the following arguments are required"),
    (["experiment", "--no-such-option"], "error: taiji2 experiment: unrecognized arguments: --no-such-option"),
    (["no-such-verb"], "error: taiji2: argument <verb>: invalid choice: 'no-such-verb'"),
])
def test_argument_errors_of_every_verb_are_one_line_with_status_2(capsys, argv, words):
    """argparse's own errors (types, missing, unknown options and verbs) in the one-line form of every other
    bad input, with the way to the usage, not the usage itself."""
    from taiji2_apps.cli.main import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert exit_info.value.code == 2 and out == "" and len(lines) == 1, err
    assert lines[0].startswith(words) and lines[0].endswith("--help)"), lines[0]


def test_experiment_bad_argument_from_the_command_line(tmp_path):
    env = dict(python_subprocess_env(), TMPDIR=str(tmp_path))
    proc = _taiji2("experiment", "--duration-s", "0", env=env)
    assert proc.returncode == 2 and "--duration-s 0" in _one_error_line(proc) and proc.stdout == ""
    assert list(tmp_path.iterdir()) == [], "a node log directory was made"


def test_experiment_refuses_an_existing_record_bag(tmp_path):
    (tmp_path / "bag").mkdir()
    proc = _taiji2("experiment", "--record", str(tmp_path / "bag"))
    assert proc.returncode == 2 and "already exists" in _one_error_line(proc)


def test_a_failed_node_is_reported_with_its_own_error_line(tmp_path):
    from taiji2_apps.runner import error_line, failure_message

    log = tmp_path / "com_offset_estimator.log"
    log.write_text("[INFO] [1.0] [com_offset_estimator]: method gls\n"
                   "error: com_offset_estimator: layout 'x': no such file or built-in layout\n")
    assert error_line(log) == "error: com_offset_estimator: layout 'x': no such file or built-in layout"

    text = failure_message("com_offset_estimator", 2, log)
    assert "exited with status 2: error: com_offset_estimator: layout 'x'" in text and str(log) in text
    log.write_text("Traceback (most recent call last):\n  File x\nZeroDivisionError: division by zero\n")
    assert error_line(log) == "ZeroDivisionError: division by zero"
    assert error_line(tmp_path / "missing.log") is None


def test_experiment_default_maneuver_is_the_shipped_design_and_paper_is_the_preset():
    from taiji2_apps.experiment_setup import plan_experiment

    plan = plan_experiment("type1", "", None, None, [], 1, "gls")
    assert plan.maneuver_kind == "design" and plan.maneuver_file.endswith("maneuvers/type1.yaml")
    assert plan.duration_s == 12909.0 and plan.maneuver_covers_run  # 3.59 h: inside the GRS range with the noise
    assert plan.commander_parameters() == ["-p", "maneuver:=design"]
    paper = plan_experiment("type1", "", "paper", 20000.0, [], 1, "gls")
    assert paper.maneuver_kind == "paper" and paper.maneuver_file is None
    # the preset flies the whole run (it stopped at 3 h before)
    assert paper.commander_parameters() == ["-p", "maneuver:=paper", "-p", "duration_s:=20000.0"]
    assert paper.maneuver_covers_run
    # type2 ships a design too (10.45 h); a config file of one's own gets the paper's preset
    type2 = plan_experiment("type2", "", None, None, [], 1, "gls")
    assert type2.maneuver_kind == "design" and type2.maneuver_file.endswith("maneuvers/type2.yaml")
    assert type2.duration_s == 37631.0
    from taiji2_model.config import builtin_layouts

    assert plan_experiment("type2", str(builtin_layouts()["type2"]), None, None, [], 1, "gls").maneuver_kind == \
        "paper"


# -- row 4: error messages in the user's terms -----------------------------------------------------------

def test_plot_refuses_a_duration_without_estimates():
    proc = _taiji2("plot", "--duration-s", "0")
    assert proc.returncode == 2 and "--duration-s 0: must be at least 200 s" in _one_error_line(proc)


def test_simulate_effect_parameters_are_checked_and_defaults_said(tmp_path):
    proc = _taiji2("simulate", "--duration-s", "10", "--effect", "actuation_delay:nosuch=1",
                   "--out", str(tmp_path / "a"))
    line = _one_error_line(proc)
    assert proc.returncode == 2 and "unknown parameter 'nosuch'" in line and "delay_s=0.0" in line
    assert "__init__" not in line
    proc = _taiji2("simulate", "--duration-s", "10", "--effect", "actuation_delay", "--out", str(tmp_path / "b"))
    assert proc.returncode == 0, proc.stderr
    assert "defaults used for delay_s=0.0" in proc.stderr and "inactive with these values" in proc.stderr
    proc = _taiji2("simulate", "--duration-s", "10", "--effect", "actuation_delay:delay_s=-1",
                   "--out", str(tmp_path / "c"))
    assert proc.returncode == 0, proc.stderr
    assert "delay_s=-1: negative, the torque acts 1 s before its command's stamp" in proc.stderr


def test_an_unknown_log_level_names_the_severities():
    proc = _taiji2("run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "--log-level", "nosuch",
                   timeout=60)
    line = _one_error_line(proc)
    assert proc.returncode == 2 and "--log-level 'nosuch'" in line
    assert "debug, info, warn, error, fatal" in line


def test_diagnose_says_no_such_bag_as_the_other_verbs(tmp_path):
    for verb in ("diagnose", "calibrate"):
        proc = _taiji2(verb, str(tmp_path / "nosuch"))
        assert proc.returncode == 2 and "no such bag" in _one_error_line(proc), verb


# -- row 5: progress on stderr ----------------------------------------------------------------------------

# test_plot_cli.py checks it on its plot run (one plot run in the suite, not two)


# -- row 6: output that says what it is -------------------------------------------------------------------

def test_calibrate_table_has_no_truth_columns_without_truth():
    from taiji2_estimator_pkg.report import EstimateTable, GrsResult, format_table

    def grs(gid, truth):
        return GrsResult(gid, np.full(3, 5.5e-8), np.eye(3) * 1e-22, np.array([1e-4, 0.18, 2e-4]), np.eye(3) * 1e-8,
                         scale_factors_truth=np.full(3, 5.5e-8) if truth else None,
                         com_offset_truth_m=np.array([1e-4, 0.18, 2e-4]) if truth else None)

    real = format_table(EstimateTable("gls", [grs(1, False), grs(2, False)]))
    assert "truth" not in real and "err/sig" not in real and "error %" not in real
    simulated = format_table(EstimateTable("gls", [grs(1, True), grs(2, True)]))
    assert "truth" in simulated and "err/sig" in simulated
    # the req column judges the 1-sigma, as the verdict does, with or without the truth (here: G 1-sigma 1e-11 of
    # 5.5e-8 ok; d 1-sigma 100 um ok), never the error of the draw
    off = grs(1, True)
    off.com_offset_m = off.com_offset_m + 150e-6  # 1.5 sigma, beyond 100 um
    rows = [line for line in format_table(EstimateTable("gls", [off, grs(2, True)])).splitlines()
            if line.startswith("  GRS1") and "samples" not in line]
    assert len(rows) == 6 and all(line.endswith(" ok") for line in rows), rows
    assert all(line.endswith(" ok") for line in real.splitlines() if line.startswith("  GRS") and "samples" not in line)
    wide = grs(2, False)
    wide.com_offset_cov = np.eye(3) * (150e-6) ** 2
    assert format_table(EstimateTable("gls", [grs(1, False), wide])).count(" MISS") == 3


def test_diagnose_says_what_shrink_is():
    from taiji2_apps.cli.diagnose import _share

    assert _share(1.0) == "100 %" and _share(0.456) == "46 %" and _share(None) == "-"
    import inspect

    from taiji2_apps.cli import diagnose

    assert "the part of the gap at its locations that it closes; held-out" in inspect.getsource(diagnose._main)


def _write_bursty_bag(path):
    """A sensor stream stamped every 0.1 s of data time, received in wall-clock bursts (accelerated time)."""
    from taiji2_runtime.bag.bulk_decode import encode_messages
    from taiji2_runtime.bag.writer import BagWriter
    from taiji2_runtime.interfaces import typestore

    store, msgtype = typestore(), "taiji2_msgs/msg/GrsVoltages"
    writer = BagWriter(path, store)
    handle = writer.add_topic("/taiji2/grs1/voltages", msgtype)
    receive_ns = 1_700_000_000 * 10**9
    for k in range(1, 601):
        sec, nanosec = divmod(k * 100_000_000, 10**9)
        data = encode_messages(store, msgtype, {"header.stamp.sec": sec, "header.stamp.nanosec": nanosec,
                                                "header.frame_id": "tmrf1", "grs_id": 1}, 1)[0]
        receive_ns += 1_000_000 if k % 100 else 5_000_000_000  # 1 ms apart, a 5-s pause every 100
        writer.write(handle, receive_ns, data)
    writer.close()


def test_bag_info_shows_the_header_stamp_view_and_says_which(tmp_path):
    bag = tmp_path / "bag"
    _write_bursty_bag(bag)
    proc = _taiji2("bag", "info", str(bag))
    assert proc.returncode == 0, proc.stderr
    row = next(line for line in proc.stdout.splitlines() if "/taiji2/grs1/voltages" in line)
    assert "10.000 Hz" in row and "largest gap 0.100 s" in row and "(header stamps)" in row
    assert "Header stamps:     59.900 s" in proc.stdout
    info = json.loads(_taiji2("bag", "info", str(bag), "--json").stdout)
    topic = info["topics"][0]
    assert topic["stamp_rate_hz"] == pytest.approx(10.0) and topic["stamp_largest_gap_s"] == pytest.approx(0.1)
    assert topic["largest_gap_s"] == pytest.approx(5.0)  # the receive view is still there


# -- row 7: help ------------------------------------------------------------------------------------------

def test_run_help_and_package_listing():
    proc = _taiji2("run", "--help")
    assert proc.returncode == 0 and "positional arguments" in proc.stdout and "executable" in proc.stdout
    proc = _taiji2("run", "taiji2_sim_pkg", "--help")
    assert proc.returncode == 0 and "maneuver_commander" in proc.stdout and "spacecraft_sim" in proc.stdout
    proc = _taiji2("run", "taiji2_sim_pkg", "maneuver_commander", "--help", timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "maneuver_commander.yaml" in proc.stdout and "--ros-args" in proc.stdout
    assert "[INFO]" not in proc.stderr  # the node was not started
    proc = _taiji2("run")
    assert proc.returncode == 2 and "required" in proc.stderr


def test_every_verb_help_is_plain_text_and_every_option_explained():
    from taiji2_apps.cli.main import build_parser

    parser = build_parser()
    verbs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert len(verbs.choices) >= 10
    for name, sub in verbs.choices.items():
        text = sub.format_help()
        assert "``" not in text and ":mod:" not in text and ":func:" not in text, name
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):
                for inner_name, inner in action.choices.items():
                    for inner_action in inner._actions:
                        assert inner_action.help, f"taiji2 {name} {inner_name} {inner_action.option_strings}"
                continue
            assert action.help, f"taiji2 {name} {action.option_strings or action.dest}: no help"


# -- row 8: outputs go to one documented place -------------------------------------------------------------

def test_default_outputs_go_under_taiji2_out():
    from taiji2_apps.cli.main import build_parser

    parser = build_parser()
    assert parser.parse_args(["diagnose", "BAG"]).out == "taiji2_out/diagnosis"
    assert parser.parse_args(["plot"]).out == "taiji2_out/plots"
    assert "taiji2_out/design-LAYOUT" in " ".join(_taiji2("design", "--help").stdout.split())
    assert "taiji2_out/campaigns/" in " ".join(_taiji2("campaign", "--help").stdout.split())
    assert "taiji2_out/" in (REPO / ".gitignore").read_text(encoding="utf-8").splitlines()
