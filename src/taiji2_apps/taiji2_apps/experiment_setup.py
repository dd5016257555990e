"""What ``taiji2 experiment`` checks before it starts a node, and what it tells after the run.

* :func:`plan_experiment`: every argument checked with the message the node that would refuse it
  gives (spacecraft_sim: layout, config, overrides; maneuver_commander: the maneuver file and its
  thrust; the estimators: the method), so a bad argument costs no node start;
* :func:`experiment_verdict`: the Cramer-Rao bound of the flown maneuver and duration
  (:func:`taiji2_estimator_pkg.core.crlb.crlb`) and the verdict (:mod:`taiji2_estimator_pkg.verdict`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from taiji2_model.maneuver_choice import MANEUVER_CHOICES, choose_maneuver

__all__ = ["MANEUVER_CHOICES", "ExperimentPlan", "experiment_verdict", "plan_experiment"]

#: the simulator's duration_s range [s]
_MAX_DURATION_S = 1e7
_METHODS = ("gls", "paper")


@dataclass
class ExperimentPlan:
    """A checked experiment.

    Attributes
    ----------
    source : str
        ``--config`` file or ``--layout`` name (what the nodes get).
    config : SimConfig
        The simulator configuration with every override applied.
    duration_s : float
        Simulated duration [s].
    maneuver : object
        What maneuver_commander flies (any family of ``maneuver_families``).
    maneuver_kind : str
        ``design`` (the layout's shipped design), ``paper`` (the layout's preset) or ``file``.
    maneuver_file : str or None
        Absolute path of the maneuver file (None: the preset).
    maneuver_label : str
        What was flown, in words.
    """

    source: str
    config: Any
    duration_s: float
    maneuver: Any
    maneuver_kind: str
    maneuver_file: str | None
    maneuver_label: str

    @property
    def maneuver_covers_run(self) -> bool:
        """The maneuver lasts the whole run (zero torque after its end otherwise)."""
        return self.maneuver.start_s <= 0.0 and self.maneuver.start_s + self.maneuver.duration_s >= self.duration_s

    def provenance(self) -> dict[str, Any]:
        """What was flown, as results.json records it: kind, file and the maneuver's parameters."""
        from taiji2_model.maneuver_families import maneuver_spec

        return {"kind": self.maneuver_kind, "file": self.maneuver_file, **maneuver_spec(self.maneuver)}

    def maneuver_parameter(self) -> str:
        """The nodes' ``maneuver`` parameter for this maneuver: ``design``, ``paper`` or the file (the nodes
        resolve and name it as the verbs do)."""
        return self.maneuver_kind if self.maneuver_kind in ("design", "paper") else str(self.maneuver_file)

    def commander_parameters(self) -> list[str]:
        """``-p`` arguments of maneuver_commander for this maneuver."""
        if self.maneuver_kind != "paper":
            return ["-p", f"maneuver:={self.maneuver_parameter()}"]
        return ["-p", "maneuver:=paper", "-p", f"duration_s:={self.duration_s}"]


def plan_experiment(layout: str, config_file: str, maneuver: str | None, duration_s: float | None,
                    overrides: list[str], seed: int, method: str) -> ExperimentPlan:
    """Check the arguments of ``taiji2 experiment``; ValueError carries the node's own one-line message.

    ``maneuver``: None picks the default, the layout's shipped design where there is one (not with a
    ``config_file``), else its preset.
    """
    from taiji2_model.config import ConfigError, load_config
    from taiji2_model.maneuver import ManeuverError
    from taiji2_model.maneuver_families import check_thrust
    from taiji2_sim_pkg.nodes.spacecraft_sim import _overrides

    if method not in _METHODS:  # the estimators' message (nodes/common.py)
        raise ValueError(f"method: {method!r} is not one of {', '.join(_METHODS)}")
    if not -1 <= seed <= 2**62:
        raise ValueError(f"--seed {seed}: must be in [-1, 2**62] (-1 draws one)")
    if duration_s is not None and not (math.isfinite(duration_s) and 0.1 <= duration_s <= _MAX_DURATION_S):
        raise ValueError(f"--duration-s {duration_s:g}: must be at least one sample (0.1 s) and at most "
                         f"{_MAX_DURATION_S:g} s")
    # the commander flies the preset of --layout (its `preset` parameter) and checks thrust with its thrusters
    try:
        preset = load_config(layout)
    except ConfigError as exc:
        raise ValueError(str(exc)) from None
    source = config_file or layout
    chosen = choose_maneuver(layout, maneuver, duration_s, config_file=config_file, preset=preset)
    flown, kind, path, label, duration_s = chosen.maneuver, chosen.kind, chosen.file, chosen.label, chosen.duration_s
    thrusters = preset.thrusters
    try:
        check_thrust(flown, thrusters.min_thrust_n, thrusters.max_thrust_n, thrusters.lever_arm_m)
    except ManeuverError as exc:
        raise ValueError(str(exc)) from None
    entries = [f"maneuver.duration_s={duration_s}", *overrides]
    try:
        config = load_config(source, overrides=_overrides(entries))
    except ConfigError as exc:
        bad = next((o for o in overrides if o.split("=", 1)[0].strip().split(".")[0] in str(exc)), None)
        raise ValueError(f"--override {bad}: {exc}" if bad else str(exc)) from None
    return ExperimentPlan(source, config, float(duration_s), flown, kind, path, label)


#: longer runs of a periodic maneuver get the bound of a whole number of periods scaled to the duration
_FULL_BOUND_MAX_S = 4 * 3600.0


def _bound(problem: Any, plan: ExperimentPlan) -> Any:
    """The Cramer-Rao bound of the flown maneuver over the run.

    The data after the maneuver's end carry no excitation, so the bound is taken over the run up to
    that end: the whole-duration bound up to 4 h (about 0.5 s per simulated hour), beyond that the
    stationary fast path of ``taiji2 design`` (a window of whole periods scaled by W / T; within +2 %,
    conservative).
    """
    end_s = plan.maneuver.start_s + plan.maneuver.duration_s
    span_s = min(plan.duration_s, end_s) if end_s > 0 else plan.duration_s
    if span_s <= _FULL_BOUND_MAX_S:
        return problem.bound(plan.maneuver, span_s)
    period_s = getattr(plan.maneuver, "period_s", None)
    if period_s is None and hasattr(plan.maneuver, "step_s"):
        period_s = plan.maneuver.step_s * len(plan.maneuver.torque_n_m)
    if period_s is not None and plan.maneuver.start_s <= 0.0:
        return problem.bound(plan.maneuver, span_s, float(period_s), fast=True)
    return problem.bound(plan.maneuver, _FULL_BOUND_MAX_S).scaled(_FULL_BOUND_MAX_S / span_s, span_s)


def _level(level: Any) -> int:
    """DiagnosticStatus.level as an int (rclpy gives a one-byte ``bytes``)."""
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def experiment_verdict(plan: ExperimentPlan, table: Any, layout: str, diagnostics: dict[str, Any],
                       not_as_planned: str = "") -> Any:
    """The verdict of a finished run: its estimates against the requirements and the bound.

    ``diagnostics``: the latest ``/diagnostics`` status of every name (DiagnosticStatus messages).
    ``not_as_planned``: why the flown maneuver differs from the plan (activities refused onboard); the
    plan's bound then does not apply, and the run is judged on the 1-sigma alone, as ``taiji2 calibrate``
    judges a recording.
    """
    import json

    import numpy as np

    from taiji2_apps.design.evaluate import DesignProblem, requirement_ratios
    from taiji2_estimator_pkg.verdict import RangeCheck, judge

    problem = DesignProblem(plan.config.to_dict())
    bound = None if not_as_planned else requirement_ratios(_bound(problem, plan))
    design_peak = float(np.max(problem.usage(plan.maneuver, min(plan.duration_s, _FULL_BOUND_MAX_S)).range_fraction))
    warnings = [f"the flown maneuver is not the plan ({not_as_planned}): judged on the 1-sigma alone, without the "
                "plan's Cramer-Rao bound"] if not_as_planned else []
    range_check = None
    for name, status in sorted(diagnostics.items()):
        values = {kv.key: kv.value for kv in status.values}
        if name == "spacecraft_sim: GRS linear range":
            try:
                range_check = RangeCheck.from_values({k: json.loads(v) for k, v in values.items()}, design_peak,
                                                     bool(plan.config.grs.readout_saturation))
            except (KeyError, ValueError, TypeError):
                warnings.append(f"simulator: {status.message}")
        elif _level(status.level) > 0:
            warnings.append(f"{name}: {status.message}")
    option = f"--layout {layout}" if plan.source == layout else f"--config {plan.source}"
    name = layout if plan.source == layout else Path(plan.source).stem
    if plan.maneuver_kind == "design":
        remedy = "a longer --duration-s, or a new design: taiji2 design --minimize-duration (docs/maneuver_design.md)"
    else:
        remedy = (f"a designed maneuver: taiji2 design {option} --minimize-duration --out taiji2_out/design-{name}, "
                  f"then taiji2 experiment {option} --maneuver taiji2_out/design-{name}/maneuver.yaml")
        from taiji2_model.maneuver_families import builtin_maneuver_file

        if plan.source == layout and builtin_maneuver_file(layout):
            remedy += f"; or the shipped design, the default: taiji2 experiment --layout {layout}"
    range_remedy = (f"a maneuver inside the range with the noise: taiji2 design {option} --minimize-duration (its "
                    "default keeps the maneuver's peak + 3.29 sigma of the readout noise inside the range)")
    from taiji2_model.maneuver_families import builtin_maneuver_file

    if plan.source == layout and builtin_maneuver_file(layout) and plan.maneuver_kind != "design":
        range_remedy += f", or the shipped design, the default: taiji2 experiment --layout {layout}"
    return judge(table, bound, plan.duration_s, plan.maneuver_label, remedy=remedy,
                 maneuver_covers_run=plan.maneuver_covers_run, warnings=warnings, range_check=range_check,
                 range_remedy=range_remedy)
