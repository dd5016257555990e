"""Constrained search for the maneuver minimising the largest CRLB / requirement ratio.

Constraints: peak maneuver-induced linear acceleration of every TM axis plus k sigma of that
axis' readout noise (every noise source, per sample) <= margin x range (the paper's range
constraint: the maneuver combined with the background noise within the GRS range), thrust
per axis in [min, max] at the lever arm, peak attitude excursion <= a limit. A shape x of a family
is *projected* onto the constraints: its torque scale s is raised (or lowered) until the first
constraint binds (range and attitude are linear in s to O(omega^2), thrust exactly), and torque
levels below the smallest thrust are switched off. The bound only decreases with s, so the optimum
of each shape lies on that boundary. Over the shapes: scipy ``differential_evolution`` (seeded,
the paper's preset in the initial population) for ``generations`` generations after its initial
population, at most ``1 - _POLISH_SHARE`` of ``max_evaluations``, then a bounded Nelder-Mead
polish of the best shape with the rest of ``max_evaluations`` (the objective is a maximum of
ratios, not smooth where two ratios are equal: a simplex method, not a gradient one), all on the
fast bound; the returned design is then checked on the full simulation and full bound.

The search is bounded by evaluations, so a seed gives the same design however fast the machine
is. ``budget_s`` is only a wall-clock cap: checked before every evaluation, and when it is hit the
search stops where it is and the result says ``truncated`` (its design then depends on the
machine's speed).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution, minimize

from taiji2_apps.design.evaluate import DesignProblem, Usage
from taiji2_apps.design.families import Family, family

__all__ = ["GENERATIONS", "MAX_EVALUATIONS", "RANGE_SIGMAS", "Constraints", "DesignResult", "InfeasibleError",
           "check_feasible", "optimize", "project"]

_REFERENCE_N_M = 1e-6
_SHRINK = 0.995  # safety factor after the O(omega^2) non-linearity of the range check
_SKIPPED = 1e3  # objective of a candidate not evaluated (budget spent) or infeasible
_PROGRESS_EVERY_S = 15.0
_POLISH_SHARE = 0.3  # share of max_evaluations kept for the polish of the global search's best shape
# defaults: the search an idle 2-core machine made in the former 150-s wall-clock budget (type1 square,
# measured: 596 evaluations, 412 of them global = the initial 32 + 12 generations of 32, the rest polish)
MAX_EVALUATIONS = 600
GENERATIONS = 12  # differential-evolution generations after the initial population
_SIMPLEX_STEP = 0.05  # initial simplex of the polish: this fraction of each parameter's range


class _BudgetSpent(Exception):
    """The polish ran out of evaluations or hit the wall-clock cap (its best evaluation so far is kept)."""


RANGE_SIGMAS = 3.29
"""Default k of the range constraint: peak noise-free maneuver part + k sigma of the readout noise
within the range. 3.29 sigma is the two-sided 0.1 % point of a Gaussian: even a signal that sat at
its peak in every sample would leave at most 0.05 % of the samples of an axis beyond the range,
half the 0.1 % the verdict allows (``taiji2_estimator_pkg.verdict.RANGE_FRACTION_LIMIT``)."""


@dataclass(frozen=True)
class Constraints:
    """Design constraints: range margin (fraction of the GRS range), k sigma of the readout noise
    added to the maneuver's peak against it, and peak attitude [rad]."""

    range_margin: float = 1.0
    max_attitude_rad: float = 0.01
    range_sigmas: float = RANGE_SIGMAS

    def range_room(self, problem: DesignProblem) -> np.ndarray:
        """(2, 3) room left for the noise-free maneuver part per GRS axis, fraction of the range:
        ``margin - k sigma / range`` (<= 0: the noise alone fills the range)."""
        return self.range_margin - self.range_sigmas * np.asarray(problem.noise_fraction)

    def range_excess(self, problem: DesignProblem, usage: Usage) -> float:
        """Largest (maneuver peak + k sigma) / (margin x range) over the TM axes (> 1: violated)."""
        total = np.asarray(usage.range_fraction) + self.range_sigmas * np.asarray(problem.noise_fraction)
        return float(np.max(total / self.range_margin))


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
    generations: int = 0  # differential-evolution generations completed after the initial population
    max_evaluations: int = MAX_EVALUATIONS
    truncated: bool = False  # the wall-clock cap stopped the search before its evaluations were spent
    budget_s: float = float("inf")


def _limits(problem: DesignProblem, usage: Usage, constraints: Constraints) -> dict[str, float]:
    """Factor by which the torque may grow before each constraint binds."""
    room = constraints.range_room(problem)
    if np.any(room <= 0.0):
        raise InfeasibleError(f"GRS linear range: {constraints.range_sigmas:g} sigma of the readout noise alone is "
                              f"{float(np.max(constraints.range_sigmas * problem.noise_fraction)):.3g} of the range "
                              f"> margin {constraints.range_margin:g}")
    fraction = np.asarray(usage.range_fraction)
    with np.errstate(divide="ignore"):
        per_axis = np.where(fraction > 0.0, room / np.where(fraction > 0.0, fraction, 1.0), np.inf)
    peak_att = float(np.max(usage.attitude_rad))
    peak_thrust = float(np.max(usage.thrust_n))
    inf = float("inf")
    return {"GRS linear range": float(np.min(per_axis)),
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
    from taiji2_model.maneuver import SquareWaveManeuver

    torque = problem.min_thrust_n * problem.lever_arm_m
    failures: list[tuple[str, float, float]] = []
    for axis in range(3):
        amp = np.zeros(3)
        amp[axis] = torque
        m = SquareWaveManeuver(100.0, amp, 75.0, 0.0, duration_s)
        u = problem.usage(m, duration_s)
        over = {"GRS linear range": (constraints.range_excess(problem, u), 1.0),
                "attitude excursion": (float(np.max(u.attitude_rad)), constraints.max_attitude_rad)}
        name, (value, limit) = max(over.items(), key=lambda kv: kv[1][0] / kv[1][1])
        if value <= limit:
            return
        failures.append((name, value, limit))
    name, value, limit = min(failures, key=lambda f: f[1] / f[2])
    unit = (f"x (maneuver peak + {constraints.range_sigmas:g} sigma of the noise) / (margin x range)"
            if name == "GRS linear range" else "rad")
    raise InfeasibleError(
        f"infeasible: {name} is the binding constraint: even the smallest thrust "
        f"({problem.min_thrust_n:.3g} N) on the most favourable axis gives {value:.3g} {unit} > limit {limit:.3g}")


def optimize(problem: DesignProblem, family_name: str, duration_s: float, constraints: Constraints,
             seed: int = 1, budget_s: float = float("inf"), progress: Callable[[str], None] | None = None,
             max_evaluations: int = MAX_EVALUATIONS, generations: int = GENERATIONS) -> DesignResult:
    """Search one family (see module doc); progress lines go to ``progress`` (default stderr).

    Deterministic for a seed: ``max_evaluations`` evaluations of the fast bound at most (the
    paper's preset first), ``generations`` generations of the global search; ``budget_s`` is a
    wall-clock cap whose hit is reported (``truncated``), on ``progress`` too.
    """
    if max_evaluations < 1 or generations < 0:
        raise ValueError(f"max_evaluations must be >= 1 and generations >= 0, got {max_evaluations}, {generations}")
    say = progress or (lambda line: print(line, file=sys.stderr, flush=True))
    fam = family(family_name)
    paper = problem.config.maneuver
    x0 = np.clip(fam.paper_start(paper.period_s, paper.amplitude_n_m, paper.phase_s),
                 [b[0] for b in fam.bounds], [b[1] for b in fam.bounds])
    started = time.monotonic()
    global_cap = max(1, max_evaluations - int(np.ceil(_POLISH_SHARE * max_evaluations)))
    state = {"n": 0, "best": np.inf, "x": x0, "said": started, "cap": global_cap, "polish": False,
             "generations": 0, "truncated": False, "skipped": False}

    def objective(x: np.ndarray) -> float:
        stop = state["n"] >= state["cap"]
        if not stop and time.monotonic() - started >= budget_s:
            state["truncated"] = stop = True
        if stop:
            if state["polish"]:
                raise _BudgetSpent
            # scipy checks the callback once per generation: the rest of the generation is skipped
            state["skipped"] = True
            return _SKIPPED
        if time.monotonic() - state["said"] > _PROGRESS_EVERY_S:
            report_progress()
        state["n"] += 1
        try:
            maneuver, _, _ = project(problem, fam, x, duration_s, constraints)
            worst = float(np.max(problem.ratios(maneuver, duration_s, fam.period_s(x), fast=True)))
        except (InfeasibleError, np.linalg.LinAlgError, ValueError):
            worst = _SKIPPED
        if worst < state["best"]:
            state["best"], state["x"] = worst, np.array(x)
        return worst

    def report_progress() -> None:
        state["said"] = time.monotonic()
        say(f"  design {family_name}{' (polish)' if state['polish'] else ''}: {state['n']} evaluations, "
            f"best max CRLB/requirement {state['best']:.3f} ({state['said'] - started:.0f} s)")

    def generation_done(*_: Any, **__: Any) -> bool:
        state["generations"] += not state["skipped"]  # generations evaluated in full
        report_progress()
        return state["truncated"] or state["n"] >= state["cap"]

    say(f"design {family_name}: {len(fam.bounds)} parameters, seed {seed}, at most {max_evaluations} evaluations "
        f"({generations} generation{'s' if generations != 1 else ''} of the global search, then a polish); "
        f"wall-clock cap {budget_s:.0f} s")
    objective(x0)
    report_progress()
    if not state["truncated"] and state["n"] < state["cap"]:
        differential_evolution(objective, fam.bounds, x0=x0, seed=seed, popsize=max(2, 24 // len(fam.bounds)),
                               maxiter=generations, polish=False, init="sobol", tol=0.0,
                               callback=generation_done, mutation=(0.5, 1.0), recombination=0.7)
    state["cap"] = max_evaluations
    _polish(objective, fam, state)
    report_progress()
    if state["truncated"]:
        say(f"design {family_name}: search truncated: the wall-clock cap of {budget_s:.0f} s was hit after "
            f"{state['n']} of {max_evaluations} evaluations; this design depends on the machine's speed "
            f"(raise the cap or lower --max-evaluations for a reproducible search)")
    x = state["x"]
    maneuver, scale, binding = project(problem, fam, x, duration_s, constraints)
    ratios = problem.ratios(maneuver, duration_s, fam.period_s(x), fast=True)
    return DesignResult(family_name, x, maneuver, fam.period_s(x), scale, binding, ratios, state["n"],
                        time.monotonic() - started, state["generations"], max_evaluations, state["truncated"],
                        float(budget_s))


def _polish(objective: Callable[[np.ndarray], float], fam: Family, state: dict[str, Any]) -> None:
    """Bounded Nelder-Mead from the best shape until ``state["cap"]`` evaluations in all (or the
    wall-clock cap); ``state`` keeps the best."""
    if state["truncated"] or state["n"] >= state["cap"] or not np.isfinite(state["best"]):
        return
    lower, upper = np.array([b[0] for b in fam.bounds]), np.array([b[1] for b in fam.bounds])
    start = np.array(state["x"], dtype=np.float64)
    # simplex: the best shape and one step along each parameter, inwards where a bound is near
    steps = _SIMPLEX_STEP * (upper - lower)
    simplex = np.tile(start, (start.size + 1, 1))
    for i in range(start.size):
        simplex[i + 1, i] += steps[i] if start[i] + steps[i] <= upper[i] else -steps[i]
    state["polish"] = True
    try:
        minimize(objective, start, method="Nelder-Mead", bounds=list(fam.bounds),
                 options={"initial_simplex": simplex, "xatol": 1e-6, "fatol": 1e-6, "maxfev": 100_000})
    except _BudgetSpent:
        pass
