"""Maneuver design: fast bound vs crlb.py, constraints of a returned design, infeasible verdicts, maneuver files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from taiji2_apps.cli.main import main as taiji2
from taiji2_apps.design.evaluate import PARAMETER_NAMES, DesignProblem
from taiji2_apps.design.families import family
from taiji2_apps.design.optimize import Constraints, project
from taiji2_model.maneuver_families import (
    MultisineManeuver,
    PiecewiseManeuver,
    load_maneuver_file,
    save_maneuver_file,
)
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands

from support import cpu_bound_processes


@pytest.fixture(scope="module")
def problem() -> DesignProblem:
    return DesignProblem("type1")


@pytest.mark.parametrize("which", ["paper", "multisine"])
def test_fast_bound_equals_crlb_py_up_to_the_end_effect(problem, which):
    # The fast bound is crlb.py on a window of whole periods (>= 1000 s) scaled by W / T; what it
    # neglects is the end effect (diffuse initial state, bias/trend nuisances), which only makes the
    # window bound larger, by O(period / W): measured 1-2 % at W = 1000 s for the paper's preset.
    # Bound: never below the full bound by more than rounding, at most 3 % above.
    duration_s = 4000.0
    if which == "paper":
        maneuver, period_s = problem.paper_maneuver(duration_s), 250.0
    else:
        maneuver = MultisineManeuver([1 / 400, 3 / 400], [[3e-6, 2e-5, 1e-5], [1e-6, 0, 3e-6]],
                                     [[0, 1, 2], [0.5, 0, 1]], 0.0, duration_s)
        period_s = 400.0
    full = problem.bound(maneuver, duration_s)
    fast = problem.bound(maneuver, duration_s, period_s, fast=True)
    for a, b in ((fast.scale_factor_sigma, full.scale_factor_sigma), (fast.com_offset_sigma, full.com_offset_sigma)):
        ratio = a / b
        assert np.all(ratio > 1 - 1e-6) and np.all(ratio < 1.03), ratio


@pytest.mark.parametrize("name", ["square", "multisine", "piecewise"])
def test_projected_shapes_respect_every_constraint(problem, name):
    fam = family(name)
    rng = np.random.default_rng(3)
    lo, hi = np.array(fam.bounds).T
    constraints = Constraints(range_margin=0.8, max_attitude_rad=2e-3)
    for _ in range(2):
        x = lo + (hi - lo) * rng.random(lo.size)
        maneuver, _, binding = project(problem, fam, x, 2000.0, constraints)
        usage = problem.usage(maneuver, 2000.0)
        # projection is linear in the torque scale; the O(omega^2) range term is covered by 0.5 % shrink;
        # the range holds the maneuver's peak + 3.29 sigma of the readout noise on every TM axis
        assert constraints.range_excess(problem, usage) <= 1.0
        assert np.all(usage.range_fraction + 3.29 * problem.noise_fraction <= constraints.range_margin)
        assert np.max(usage.attitude_rad) <= constraints.max_attitude_rad
        levels = np.abs(maneuver_torque_commands(problem.quiet, 20000, maneuver=maneuver))
        nonzero = levels[levels > 0] / problem.lever_arm_m
        assert np.all(nonzero <= problem.max_thrust_n * (1 + 1e-12))
        if name != "multisine":  # a sine passes through zero; its peak is checked
            assert np.all(nonzero >= problem.min_thrust_n * (1 - 1e-12))
        assert binding in ("GRS linear range", "attitude excursion", "maximum thrust")


@pytest.mark.parametrize(("flag", "value", "name"), [("--range-margin", "1e-6", "GRS linear range"),
                                                     ("--max-attitude-rad", "1e-9", "attitude excursion")])
def test_infeasible_constraints_give_one_line_naming_the_constraint(tmp_path, capsys, flag, value, name):
    status = taiji2(["design", "--layout", "type1", "--duration-s", "1000", flag, value, "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert status == 2
    assert len(err.splitlines()) == 1 and "infeasible" in err and name in err, err
    assert not (tmp_path / "maneuver.yaml").exists()


@pytest.mark.parametrize("maneuver", [
    MultisineManeuver([0.004, 0.012], [[1e-6, 2e-6, 3e-6], [0.0, 1e-6, 0.0]], [[0, 1, 2], [3, 4, 5]], 5.0, 900.0),
    PiecewiseManeuver(31.3, [[1e-6, 0, -2e-6], [-1e-6, 5e-6, 0], [0, -5e-6, 2e-6]], 0.0, 900.0),
])
def test_maneuver_file_round_trips_through_the_commander_and_the_sim_core(tmp_path, context, maneuver):
    from taiji2_model.config import load_config
    from taiji2_sim_pkg.nodes.maneuver_commander import ManeuverCommander

    path = tmp_path / "m.yaml"
    save_maneuver_file(path, maneuver, "test")
    node = ManeuverCommander(context=context, cli_args=["--ros-args", "-p", f"maneuver:={path}"])
    try:
        config = load_config("type1")
        n = 10_000
        t = np.arange(n) * config.dt_s
        core = maneuver_torque_commands(config, n, maneuver=load_maneuver_file(path))
        np.testing.assert_array_equal(core, maneuver.torque_series(t))  # file keeps full precision
        np.testing.assert_array_equal(np.array([node._maneuver.torque_at(ti) for ti in t]), core)
        assert np.any(core != 0.0) and np.all(core[t >= maneuver.end_s] == 0.0)
    finally:
        node.destroy_node()


def test_bad_maneuver_file_is_one_line_naming_the_key(tmp_path):
    from taiji2_model.config import ConfigError

    path = tmp_path / "bad.yaml"
    path.write_text("family: multisine\nmultisine: {frequencies_hz: [0.01], amplitude_n_m: [[1, 2]]}\n")
    with pytest.raises(ConfigError, match="phase_rad"):
        load_maneuver_file(path)


@pytest.mark.slow
def test_design_cli_writes_the_files_and_beats_or_matches_the_paper(tmp_path):
    out = tmp_path / "d"
    status = taiji2(["design", "--layout", "type1", "--family", "square", "--duration-s", "500",
                     "--max-evaluations", "10", "--no-plots", "--out", str(out)])
    assert status == 0
    report = json.loads((out / "report.json").read_text())
    assert report["search"]["evaluations"] == 10 and not report["search"]["truncated"]
    assert "Search: complete" in (out / "report.md").read_text()
    for key in ("design", "paper"):
        assert list(report[key]["crlb_over_requirement"]) == list(PARAMETER_NAMES)
    # the paper's preset, scaled into the constraints, is in the initial population: the design can only be
    # better than that (full bounds, up to the fast bound's <= 3 % end effect in the search). The preset as
    # the paper flies it leaves the range with the noise (peak 0.86 + 3.29 sigma > 1): no comparison there.
    problem = DesignProblem("type1")
    fam, preset = family("square"), problem.config.maneuver
    lo, hi = np.array(fam.bounds).T
    x0 = np.clip(fam.paper_start(preset.period_s, preset.amplitude_n_m, preset.phase_s), lo, hi)
    inside, _, _ = project(problem, fam, x0, 500.0, Constraints())
    assert report["design"]["max_crlb_over_requirement"] <= 1.03 * float(np.max(problem.ratios(inside, 500.0)))
    paper_usage = np.asarray(report["paper"]["usage"]["range_fraction"])
    assert np.max(paper_usage + 3.29 * problem.noise_fraction) > 1.0
    usage = report["design"]["usage"]
    sigma = np.asarray(report["constraints"]["noise_sigma_fraction_of_range"])
    assert report["constraints"]["range_sigmas"] == 3.29 and report["constraints"]["range_margin"] == 1.0
    assert np.all(np.asarray(usage["range_fraction"]) + 3.29 * sigma <= 1.0)
    assert np.max(usage["attitude_peak_rad"]) <= 0.01
    assert np.max(usage["thrust_peak_n"]) <= 1e-4
    assert load_maneuver_file(out / "maneuver.yaml").duration_s == 500.0
    assert (out / "report.md").read_text().count("| grs") == 12


def test_a_spent_budget_evaluates_no_more_candidates(problem):
    """The wall-clock cap is checked before every evaluation, not only once per generation (a
    generation of the square family is 32 candidates of a bound each): with no time nothing is
    evaluated, the search returns its start, the paper's preset, and says it was truncated."""
    from taiji2_apps.design.optimize import optimize

    lines: list[str] = []
    result = optimize(problem, "square", 1000.0, Constraints(), seed=1, budget_s=0.0, progress=lines.append)
    assert result.evaluations == 0 and result.truncated
    np.testing.assert_array_equal(result.x, _paper_start(problem))
    assert any("0 evaluations" in line for line in lines)
    assert "truncated" in lines[-1]


def _paper_start(problem: DesignProblem) -> np.ndarray:
    paper = problem.config.maneuver
    fam = family("square")
    return np.clip(fam.paper_start(paper.period_s, paper.amplitude_n_m, paper.phase_s),
                   [b[0] for b in fam.bounds], [b[1] for b in fam.bounds])


def test_same_seed_gives_the_same_design_however_slow_the_clock(problem, monkeypatch):
    """The search is bounded by evaluations, not by wall time: the same seed gives the bit-identical
    design with the real clock and with a clock that runs 30 s per reading (a machine hundreds of
    times slower), as long as the wall-clock cap is not hit; when it is, the result says truncated."""
    import types

    import taiji2_apps.design.optimize as optimize_module

    search = {"seed": 5, "max_evaluations": 14, "generations": 1, "progress": lambda line: None}
    idle = optimize_module.optimize(problem, "square", 1000.0, Constraints(), **search)
    clock = {"t": 0.0, "reads": 0}

    def slow_clock() -> float:
        clock["t"] += 30.0
        clock["reads"] += 1
        return clock["t"]

    monkeypatch.setattr(optimize_module, "time", types.SimpleNamespace(monotonic=slow_clock))
    busy = optimize_module.optimize(problem, "square", 1000.0, Constraints(), budget_s=1e7, **search)
    assert clock["reads"] > 2 * busy.evaluations  # the search read the slow clock
    assert busy.wall_s > 14 * 30.0
    assert not idle.truncated and not busy.truncated
    assert idle.evaluations == busy.evaluations == 14
    np.testing.assert_array_equal(busy.x, idle.x)  # bit-equal
    np.testing.assert_array_equal(busy.fast_ratios, idle.fast_ratios)
    assert not np.array_equal(idle.x, _paper_start(problem))  # the search moved: the check is not vacuous
    # a cap that the slow clock hits mid-search: stopped there, and said so
    lines: list[str] = []
    cut = optimize_module.optimize(problem, "square", 1000.0, Constraints(), budget_s=200.0,
                                   **{**search, "progress": lines.append})
    assert cut.truncated and 0 < cut.evaluations < 14
    assert "truncated" in lines[-1] and "of 14 evaluations" in lines[-1]


def test_same_seed_gives_the_same_design_beside_cpu_bound_processes(problem):
    """The same, on a really busy machine: two CPU-bound processes beside the second search (one
    BLAS thread, as `taiji2 design` runs it)."""
    from threadpoolctl import threadpool_limits

    from taiji2_apps.design.optimize import optimize

    search = {"seed": 6, "max_evaluations": 14, "generations": 1, "progress": lambda line: None}
    with threadpool_limits(limits=1, user_api="blas"):
        idle = optimize(problem, "square", 1000.0, Constraints(), **search)
        with cpu_bound_processes(2):
            busy = optimize(problem, "square", 1000.0, Constraints(), **search)
    assert not idle.truncated and not busy.truncated and idle.evaluations == busy.evaluations == 14
    np.testing.assert_array_equal(busy.x, idle.x)


def test_cli_search_defaults_are_the_optimizers():
    import argparse

    from taiji2_apps.cli import design as design_cli
    from taiji2_apps.design.optimize import GENERATIONS, MAX_EVALUATIONS, RANGE_SIGMAS

    parser = argparse.ArgumentParser()
    design_cli.add_arguments(parser)
    args = parser.parse_args([])
    assert (args.max_evaluations, args.generations) == (MAX_EVALUATIONS, GENERATIONS)
    # the range constraint by default: noise-free maneuver peak + 3.29 sigma of the readout noise within the range
    assert (args.range_margin, args.range_sigmas) == (Constraints().range_margin, RANGE_SIGMAS) == (1.0, 3.29)


@pytest.mark.parametrize(("flag", "value"), [("--max-evaluations", "0"), ("--generations", "-1"),
                                             ("--budget-s", "nan"), ("--range-sigmas", "-1")])
def test_bad_search_size_is_one_line(tmp_path, capsys, flag, value):
    status = taiji2(["design", "--layout", "type1", flag, value, "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1 and flag in err, err


@pytest.mark.parametrize("value", ["0", "nan", "-5"])
def test_bad_time_limit_is_one_line(tmp_path, capsys, value):
    status = taiji2(["design", "--layout", "type1", "--time-limit-s", value, "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1 and "--time-limit-s" in err, err
