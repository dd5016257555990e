"""The nodes fly what every verb flies by default (taiji2_model.maneuver_choice): maneuver_commander,
command_planner and spacecraft_sim take the same ``maneuver`` parameter, with the same default."""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_model.maneuver_choice import choose_maneuver
from taiji2_model.maneuver_families import maneuver_spec


def _torques(maneuver, t_s: np.ndarray) -> np.ndarray:
    return np.array([maneuver.torque_at(t) for t in t_s])


# type2 long for CI time (25 s): the same code path as type1, with the other layout's shipped design
@pytest.mark.parametrize("layout", ["type1", pytest.param("type2", marks=pytest.mark.long)])
def test_the_commander_and_the_planner_fly_the_verbs_default_by_default(context, layout):
    from taiji2_ground_pkg.nodes.command_planner import CommandPlanner
    from taiji2_sim_pkg.nodes.maneuver_commander import ManeuverCommander

    chosen = choose_maneuver(layout, None, None)
    commander = ManeuverCommander(context=context, cli_args=["--ros-args", "-p", f"preset:={layout}"])
    planner = CommandPlanner(context=context,
                             cli_args=["--ros-args", "-p", f"preset:={layout}", "-p", "start_s:=0.0"])
    try:
        assert commander._choice.kind == chosen.kind == "design"
        assert maneuver_spec(commander._maneuver) == maneuver_spec(chosen.maneuver)
        t = np.arange(0.0, 2000.0, 0.7)
        np.testing.assert_array_equal(_torques(commander._maneuver, t), _torques(chosen.maneuver, t))
        # the planner's tables release the same torque changes over the same span
        assert planner.plan and planner.plan[-1]["last_release_s"] <= chosen.duration_s + 1.0
        assert planner.plan[-1]["last_release_s"] > chosen.duration_s - chosen.maneuver.period_s
    finally:
        commander.destroy_node()
        planner.destroy_node()


def test_paper_or_square_wave_keys_fly_the_preset(context):
    from taiji2_sim_pkg.nodes.maneuver_commander import ManeuverCommander

    paper = ManeuverCommander(context=context, cli_args=["--ros-args", "-p", "maneuver:=paper"])
    period = ManeuverCommander(context=context,
                               cli_args=["--ros-args", "-r", "__node:=commander_2", "-p", "period_s:=300.0"])
    try:
        assert paper._choice.kind == "paper" and paper._maneuver.period_s == 250.0
        # a square-wave key without a maneuver describes a square wave: the preset's, modified
        assert period._choice.kind == "paper" and period._maneuver.period_s == 300.0
    finally:
        paper.destroy_node()
        period.destroy_node()


def test_a_maneuver_that_cannot_be_flown_is_one_line_naming_it(context):
    from taiji2_sim_pkg.nodes.maneuver_commander import ManeuverCommander

    with pytest.raises(ValueError, match=r"no_such\.yaml"):
        ManeuverCommander(context=context, cli_args=["--ros-args", "-p", "maneuver:=no_such.yaml"])


@pytest.mark.parametrize("asked, overrides, end_s", [
    ("", [""], "design"), ("paper", [""], 10800.0), ("", ["maneuver.duration_s=600.0"], 600.0)])
def test_the_simulator_runs_to_the_end_of_the_same_maneuver(context, asked, overrides, end_s):
    from taiji2_sim_pkg.nodes.spacecraft_sim import SpacecraftSim

    if end_s == "design":
        end_s = choose_maneuver("type1", None, None).duration_s
    args = ["-p", f"maneuver:={asked}"] if asked else []
    node = SpacecraftSim(context=context,
                         cli_args=["--ros-args", *args, "-p", "seed:=1", "-p", f"config_overrides:={overrides}"])
    try:
        assert node._n_steps == round(end_s / 0.1)
    finally:
        node.destroy_node()
