"""Constrained search for the maneuver minimising the largest CRLB / requirement ratio.

Constraints: peak maneuver-induced linear acceleration of every TM axis <= margin x range, thrust
per axis in [min, max] at the lever arm, peak attitude excursion <= a limit. A shape x of a family
is *projected* onto the constraints: its torque scale s is raised (or lowered) until the first
constraint binds (range and attitude are linear in s to O(omega^2), thrust exactly), and torque
levels below the smallest thrust are switched off. The bound only decreases with s, so the optimum
of each shape lies on that boundary. Over the shapes: scipy ``differential_evolution`` (seeded,
the paper's preset in the initial population) for the first ``_GLOBAL_SHARE`` of the wall-clock
budget, then a bounded Nelder-Mead polish of the best shape for the rest (the objective is a
maximum of ratios, not smooth where two ratios are equal: a simplex method, not a gradient one),
all on the fast bound; the returned design is then checked on the full simulation and full bound.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution, minimize

from .evaluate import DesignProblem, Usage
from .families import Family, family

__all__ = ["Constraints", "DesignResult", "InfeasibleError", "check_feasible", "optimize", "project"]

_REFERENCE_N_M = 1e-6
_SHRINK = 0.995  # safety factor after the O(omega^2) non-linearity of the range check
_SKIPPED = 1e3  # objective of a candidate not evaluated (budget spent) or infeasible
_PROGRESS_EVERY_S = 15.0
_GLOBAL_SHARE = 0.7  # share of the budget for the global search; the rest polishes its best shape
_SIMPLEX_STEP = 0.05  # initial simplex of the polish: this fraction of each parameter's range


class _BudgetSpent(Exception):
    """The polish ran out of budget (its best evaluation so far is kept)."""


@dataclass(frozen=True)
class Constraints:
    """Design constraints: range margin (fraction of the GRS range) and peak attitude [rad]."""

    range_margin: float = 0.9
    max_attitude_rad: float = 0.01


class InfeasibleError(ValueError):
    """No maneuver satisfies the constraints; the message names the binding one (one line)."""


@dataclass
class DesignResult:
    """Outcome of a search."""

    family: str
    x: np.ndarray
    maneuver: Any
    period_s: float
    scale_n_m: float
    binding: str
    fast_ratios: np.ndarray
    evaluations: int
    wall_s: float


def _limits(problem: DesignProblem, usage: Usage, constraints: Constraints) -> dict[str, float]:
    """Factor by which the torque may grow before each constraint binds."""
    peak_range = float(np.max(usage.range_fraction))
    peak_att = float(np.max(usage.attitude_rad))
    peak_thrust = float(np.max(usage.thrust_n))
    inf = float("inf")
    return {"GRS linear range": constraints.range_margin / peak_range if peak_range > 0 else inf,
            "attitude excursion": constraints.max_attitude_rad / peak_att if peak_att > 0 else inf,
            "maximum thrust": problem.max_thrust_n / peak_thrust if peak_thrust > 0 else inf}


def project(problem: DesignProblem, fam: Family, x: np.ndarray, duration_s: float,
            constraints: Constraints) -> tuple[Any, float, str]:
    """Scale shape x to the binding constraint; returns (maneuver, scale [N m], binding constraint)."""
    reference = fam.maneuver(x, _REFERENCE_N_M, duration_s)
    limits = _limits(problem, problem.usage(reference, duration_s), constraints)
    binding = min(limits, key=limits.__getitem__)
    if not np.isfinite(limits[binding]):
        raise InfeasibleError("zero maneuver")
    scale = _REFERENCE_N_M * limits[binding] * _SHRINK
    maneuver = fam.maneuver(x, scale, duration_s, problem.min_thrust_n * problem.lever_arm_m)
    return maneuver, scale, binding


def check_feasible(problem: DesignProblem, duration_s: float, constraints: Constraints) -> None:
    """Raise InfeasibleError (naming the binding constraint) if even the gentlest maneuver violates it.

    The gentlest maneuver on an axis is the smallest thrust, as a square wave of the shortest
    period of the search (100 s) phased for zero mean rate; if on every axis it already leaves the
    range margin or the attitude limit, no maneuver of any family can satisfy both.
    """
    from taiji2_sim_pkg.core.maneuver import SquareWaveManeuver

    torque = problem.min_thrust_n * problem.lever_arm_m
    failures: list[tuple[str, float, float]] = []
    for axis in range(3):
        amp = np.zeros(3)
        amp[axis] = torque
        m = SquareWaveManeuver(100.0, amp, 75.0, 0.0, duration_s)
        u = problem.usage(m, duration_s)
        over = {"GRS linear range": (float(np.max(u.range_fraction)), constraints.range_margin),
                "attitude excursion": (float(np.max(u.attitude_rad)), constraints.max_attitude_rad)}
        name, (value, limit) = max(over.items(), key=lambda kv: kv[1][0] / kv[1][1])
        if value <= limit:
            return
        failures.append((name, value, limit))
    name, value, limit = min(failures, key=lambda f: f[1] / f[2])
    unit = "of the range" if name == "GRS linear range" else "rad"
    raise InfeasibleError(
        f"infeasible: {name} is the binding constraint: even the smallest thrust "
        f"({problem.min_thrust_n:.3g} N) on the most favourable axis gives {value:.3g} {unit} > limit {limit:.3g}")


def optimize(problem: DesignProblem, family_name: str, duration_s: float, constraints: Constraints,
             seed: int = 1, budget_s: float = 150.0, progress: Callable[[str], None] | None = None) -> DesignResult:
    """Search one family (see module doc); progress lines go to ``progress`` (default stderr)."""
    say = progress or (lambda line: print(line, file=sys.stderr, flush=True))
    fam = family(family_name)
    paper = problem.config.maneuver
    x0 = np.clip(fam.paper_start(paper.period_s, paper.amplitude_n_m, paper.phase_s),
                 [b[0] for b in fam.bounds], [b[1] for b in fam.bounds])
    started = time.monotonic()
    state = {"n": 0, "best": np.inf, "x": x0, "said": started, "phase_end": started + _GLOBAL_SHARE * budget_s,
             "polish": False}

    def objective(x: np.ndarray) -> float:
        now = time.monotonic()
        if now > state["phase_end"]:
            if state["polish"]:
                raise _BudgetSpent
            # scipy checks the callback once per generation (up to 2 x popsize x dim evaluations of
            # ~1 s): past the budget the rest of the generation is skipped, not evaluated
            return _SKIPPED
        if now - state["said"] > _PROGRESS_EVERY_S:
            callback()
        state["n"] += 1
        try:
            maneuver, _, _ = project(problem, fam, x, duration_s, constraints)
            worst = float(np.max(problem.ratios(maneuver, duration_s, fam.period_s(x), fast=True)))
        except (InfeasibleError, np.linalg.LinAlgError, ValueError):
            worst = _SKIPPED
        if worst < state["best"]:
            state["best"], state["x"] = worst, np.array(x)
        return worst

    def callback(*_: Any, **__: Any) -> bool:
        state["said"] = time.monotonic()
        elapsed = state["said"] - started
        say(f"  design {family_name}{' (polish)' if state['polish'] else ''}: {state['n']} evaluations, "
            f"best max CRLB/requirement {state['best']:.3f} ({elapsed:.0f} s)")
        return state["said"] > state["phase_end"]

    say(f"design {family_name}: {len(fam.bounds)} parameters, budget {budget_s:.0f} s, seed {seed}")
    objective(x0)
    callback()
    differential_evolution(objective, fam.bounds, x0=x0, seed=seed, popsize=max(2, 24 // len(fam.bounds)),
                           maxiter=10_000, polish=False, init="sobol", tol=0.0, callback=callback,
                           mutation=(0.5, 1.0), recombination=0.7)
    _polish(objective, fam, state, started + budget_s)
    x = state["x"]
    maneuver, scale, binding = project(problem, fam, x, duration_s, constraints)
    ratios = problem.ratios(maneuver, duration_s, fam.period_s(x), fast=True)
    return DesignResult(family_name, x, maneuver, fam.period_s(x), scale, binding, ratios, state["n"],
                        time.monotonic() - started)


def _polish(objective: Callable[[np.ndarray], float], fam: Family, state: dict[str, Any], end: float) -> None:
    """Bounded Nelder-Mead from the best shape until ``end`` (monotonic s); ``state`` keeps the best."""
    if time.monotonic() >= end or not np.isfinite(state["best"]):
        return
    lower, upper = np.array([b[0] for b in fam.bounds]), np.array([b[1] for b in fam.bounds])
    start = np.array(state["x"], dtype=np.float64)
    # simplex: the best shape and one step along each parameter, inwards where a bound is near
    steps = _SIMPLEX_STEP * (upper - lower)
    simplex = np.tile(start, (start.size + 1, 1))
    for i in range(start.size):
        simplex[i + 1, i] += steps[i] if start[i] + steps[i] <= upper[i] else -steps[i]
    state["polish"], state["phase_end"] = True, end
    try:
        minimize(objective, start, method="Nelder-Mead", bounds=list(fam.bounds),
                 options={"initial_simplex": simplex, "xatol": 1e-6, "fatol": 1e-6, "maxfev": 100_000})
    except _BudgetSpent:
        pass
