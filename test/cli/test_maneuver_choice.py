"""One default maneuver for every verb that simulates: experiment, simulate and plot fly and name the same."""

from __future__ import annotations

import json
import subprocess

import pytest

from taiji2_apps.experiment_setup import plan_experiment
from taiji2_model.maneuver_choice import choose_maneuver
from taiji2_model.maneuver_families import builtin_maneuver_file, maneuver_spec

from support import PYTHON, python_subprocess_env


@pytest.mark.parametrize("layout", ["type1", "type2"])
def test_the_default_is_the_shipped_design_where_there_is_one_and_experiment_flies_it(layout):
    chosen = choose_maneuver(layout, None, None)
    shipped = builtin_maneuver_file(layout)
    assert chosen.kind == ("design" if shipped else "paper") and chosen.file == shipped
    plan = plan_experiment(layout, "", None, None, [], 1, "gls")
    assert (plan.maneuver_kind, plan.maneuver_file, plan.maneuver_label) == (chosen.kind, chosen.file, chosen.label)
    assert plan.duration_s == chosen.duration_s and maneuver_spec(plan.maneuver) == maneuver_spec(chosen.maneuver)


def test_a_config_file_flies_its_own_preset_by_default(tmp_path):
    from taiji2_model.config import load_config

    config = load_config("type1", overrides={"maneuver.period_s": 300.0})
    chosen = choose_maneuver("type1", None, 600.0, config_file="my.yaml", preset=config)
    assert chosen.kind == "paper" and chosen.maneuver.period_s == 300.0 and chosen.duration_s == 600.0


def test_a_bad_choice_is_one_line():
    with pytest.raises(ValueError, match=r"no_such\.yaml"):
        choose_maneuver("type1", "no_such.yaml", None)


def test_simulate_flies_and_records_the_default_maneuver(tmp_path):
    import yaml

    out = tmp_path / "bag"
    proc = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "simulate", "--duration-s", "600", "--out", str(out)],
                          env=python_subprocess_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    chosen = choose_maneuver("type1", None, 600.0)
    assert json.loads(proc.stdout)["maneuver"] == chosen.label
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]  # any ROS 2 tool's view
    provenance = json.loads(meta["custom_data"]["taiji2.provenance"])
    assert provenance["maneuver"]["label"] == chosen.label and provenance["maneuver"]["kind"] == chosen.kind
    # calibrate of that bag names the same maneuver, in its table and its verdict
    calibrated = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "calibrate", str(out), "--json"],
                                env=python_subprocess_env(), capture_output=True, text=True, timeout=300)
    assert calibrated.returncode in (0, 3), calibrated.stderr  # 600 s: some requirements not met (3)
    result = json.loads(calibrated.stdout)
    assert result["maneuver"] == chosen.label and chosen.label in json.dumps(result["verdict"])
