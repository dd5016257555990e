"""Design the calibration maneuver: minimise the largest CRLB / requirement inside range, thrust, attitude.

Writes into --out: ``maneuver.yaml`` (maneuver_commander ``maneuver``; ``taiji2 experiment
--maneuver``), ``report.json`` (objects ``design`` and ``paper``, each with
``crlb_over_requirement`` per parameter), ``report.md`` and PNGs. Progress on stderr.

Exit status: 0 designed, 2 bad input or infeasible constraints (one line naming the binding constraint).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from taiji2_apps.cli.exit_status import ExitStatus

if TYPE_CHECKING:
    import numpy as np

_MAX_DURATION_S = 30 * 86400.0
# the search's size (design.optimize.MAX_EVALUATIONS / GENERATIONS; a test keeps them equal) and its wall caps
MAX_EVALUATIONS = 600
GENERATIONS = 12
RANGE_SIGMAS = 3.29  # design.optimize.RANGE_SIGMAS (a test keeps them equal)
BUDGET_S = 900.0
TIME_LIMIT_S = 1200.0
_FULL_BOUND_MAX_S = 4 * 3600.0  # longer records are verified with the (conservative) fast bound


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``taiji2 design``."""
    parser.add_argument("--layout", default="type1", help="built-in layout type1 | type2 (default type1)")
    parser.add_argument("--config", default="", help="simulator config YAML instead of --layout")
    parser.add_argument("--duration-s", type=float, default=10800.0,
                        help="maneuver duration [s] (default 10800; with --minimize-duration: the reference)")
    parser.add_argument("--minimize-duration", action="store_true",
                        help="shortest duration with every requirement met at 1 sigma")
    parser.add_argument("--family", default="square", choices=("square", "multisine", "piecewise"),
                        help="maneuver family (default square)")
    parser.add_argument("--out", default="",
                        help="output directory (default taiji2_out/design-LAYOUT, LAYOUT the --layout or the "
                             "--config file's name)")
    parser.add_argument("--range-margin", type=float, default=1.0,
                        help="allowed (peak noise-free maneuver-induced linear acceleration + k sigma of the "
                             "readout noise, every source) / GRS range, per TM axis (default 1.0)")
    parser.add_argument("--range-sigmas", type=float, default=RANGE_SIGMAS,
                        help=f"k of --range-margin (default {RANGE_SIGMAS:g}: at most 0.05 %% of the samples of an "
                             f"axis beyond the range with every noise on, half of what the verdict allows; 0: the "
                             f"noise-free maneuver part alone)")
    parser.add_argument("--max-attitude-rad", type=float, default=0.01,
                        help="allowed peak attitude excursion per axis [rad] (default 0.01: the small-angle "
                             "error theta^2/2 stays 60x below the 0.3 %% G requirement)")
    parser.add_argument("--seed", type=int, default=1, help="optimiser seed (default 1)")
    parser.add_argument("--max-evaluations", type=int, default=MAX_EVALUATIONS,
                        help=f"evaluations of the bound in the search, global search and polish together (default "
                             f"{MAX_EVALUATIONS}); the search is bounded by evaluations, so a seed gives the same "
                             f"design on an idle and on a busy machine")
    parser.add_argument("--generations", type=int, default=GENERATIONS,
                        help=f"differential-evolution generations after the initial population (default "
                             f"{GENERATIONS}); the global search also stops at 70 %% of --max-evaluations, the "
                             f"polish gets the rest")
    parser.add_argument("--budget-s", type=float, default=BUDGET_S,
                        help=f"wall-clock cap of the search [s] (default {BUDGET_S:g}); when hit, the search stops "
                             f"and is reported as truncated (stderr, report.md, report.json)")
    parser.add_argument("--time-limit-s", type=float, default=TIME_LIMIT_S,
                        help=f"wall-clock limit of the whole command [s] (default {TIME_LIMIT_S:g}): the search's "
                             f"cap is min(--budget-s, what is left after the measured cost of the final checks)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNGs")


def _fail(message: str) -> int:
    print(f"error: taiji2 design: {message}", file=sys.stderr)
    return ExitStatus.BAD_INPUT


def _say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _fit(problem: Any, fam: Any, x: np.ndarray, duration_s: float, constraints: Any) -> tuple[Any, Any, str]:
    import numpy as np

    """Project x at this duration and check the full simulation; shrink until every limit holds."""
    from taiji2_apps.design.optimize import project

    maneuver, scale, binding = project(problem, fam, x, duration_s, constraints)
    for _ in range(5):
        usage = problem.usage(maneuver, duration_s)
        excess = max(_range_scale_excess(problem, usage, constraints),
                     float(np.max(usage.attitude_rad)) / constraints.max_attitude_rad,
                     float(np.max(usage.thrust_n)) / problem.max_thrust_n)
        if excess <= 1.0:
            return maneuver, usage, binding
        scale /= excess * 1.001
        maneuver = fam.maneuver(x, scale, duration_s, problem.min_thrust_n * problem.lever_arm_m)
    raise RuntimeError("design does not settle inside the constraints")


def _range_scale_excess(problem: Any, usage: Any, constraints: Any) -> float:
    """Factor by which the torque must shrink for the range constraint (<= 1: inside)."""
    import numpy as np

    return float(np.max(np.asarray(usage.range_fraction) / constraints.range_room(problem)))


def main(args: argparse.Namespace) -> int:
    """Run ``taiji2 design``."""
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    import numpy as np

    from taiji2_apps.design.evaluate import PARAMETER_NAMES, DesignProblem
    from taiji2_apps.design.families import family
    from taiji2_apps.design.optimize import Constraints, InfeasibleError, check_feasible, optimize
    from taiji2_apps.design.report import summary, write_report
    from taiji2_model.config import ConfigError
    from taiji2_model.maneuver_families import save_maneuver_file

    if not (np.isfinite(args.duration_s) and args.duration_s >= 100.0):
        return _fail(f"--duration-s: must be >= 100 s, got {args.duration_s!r}")
    if not (0.0 < args.range_margin <= 1.0):
        return _fail(f"--range-margin: must be in (0, 1], got {args.range_margin!r}")
    if not (np.isfinite(args.range_sigmas) and args.range_sigmas >= 0.0):
        return _fail(f"--range-sigmas: must be >= 0, got {args.range_sigmas!r}")
    if not (np.isfinite(args.max_attitude_rad) and args.max_attitude_rad > 0.0):
        return _fail(f"--max-attitude-rad: must be > 0, got {args.max_attitude_rad!r}")
    if not args.time_limit_s > 0.0:  # inf: no limit
        return _fail(f"--time-limit-s: must be > 0, got {args.time_limit_s!r}")
    if not args.budget_s >= 0.0:  # inf: no cap
        return _fail(f"--budget-s: must be >= 0, got {args.budget_s!r}")
    if args.max_evaluations < 1:
        return _fail(f"--max-evaluations: must be >= 1, got {args.max_evaluations!r}")
    if args.generations < 0:
        return _fail(f"--generations: must be >= 0, got {args.generations!r}")
    started = time.monotonic()
    try:
        problem = DesignProblem(args.config or args.layout)
    except (ConfigError, OSError) as exc:
        return _fail(str(exc).splitlines()[0])
    layout = args.config or args.layout
    constraints = Constraints(args.range_margin, args.max_attitude_rad, args.range_sigmas)
    reference_s = float(args.duration_s)
    try:
        check_feasible(problem, reference_s, constraints)
    except InfeasibleError as exc:
        return _fail(str(exc))
    from taiji2_apps.design.evaluate import requirement_ratios

    _say("design: the paper's preset with the full bound")
    full_started = time.monotonic()
    paper = problem.paper_maneuver(reference_s)
    paper_bound = problem.bound(paper, reference_s)
    paper_ratios = requirement_ratios(paper_bound)
    paper_usage = problem.usage(paper, reference_s)
    full_check_s = time.monotonic() - full_started
    # after the search: the design's full check at the reference (one full_check_s) and, with
    # --minimize-duration, typically two checks at T* <= 4 h (each <= 4/3 full_check_s); plots ~10 s
    after_search_s = full_check_s * (1.0 + (2.0 * _FULL_BOUND_MAX_S / reference_s if args.minimize_duration else 0.0))
    budget_s = min(args.budget_s, args.time_limit_s - (time.monotonic() - started) - after_search_s - 10.0)
    if budget_s < args.budget_s:
        _say(f"design: search wall-clock cap {max(budget_s, 0.0):.0f} s (--time-limit-s {args.time_limit_s:g} s; "
             f"one full check takes {full_check_s:.0f} s on this machine now)")
    result = optimize(problem, args.family, reference_s, constraints, args.seed, max(budget_s, 0.0), _say,
                      max_evaluations=args.max_evaluations, generations=args.generations)
    fam = family(args.family)
    _say("design: checking the design with the full bound")
    try:
        maneuver, usage, binding = _fit(problem, fam, result.x, reference_s, constraints)
    except (InfeasibleError, RuntimeError) as exc:
        return _fail(f"infeasible: {exc}")
    bound = problem.bound(maneuver, reference_s)
    ratios = requirement_ratios(bound)
    at_reference = {"paper_max": float(np.max(paper_ratios)),
                    "paper_binding": PARAMETER_NAMES[int(np.argmax(paper_ratios))],
                    "design_max": float(np.max(ratios)), "design_binding": PARAMETER_NAMES[int(np.argmax(ratios))],
                    "reduction": float(1.0 - np.max(ratios) / np.max(paper_ratios)),
                    # (peak + k sigma) / (margin x range) of the paper's preset: > 1, it leaves the range
                    "paper_range_excess": constraints.range_excess(problem, paper_usage)}
    final_s, final_maneuver, final_usage, final_bound, final_ratios = reference_s, maneuver, usage, bound, ratios
    verified = True
    if args.minimize_duration:
        target = reference_s * float(np.max(ratios)) ** 2
        for _ in range(4):
            # whole seconds: how a planner schedules a maneuver (the bound changes by < 1e-4 per s)
            target = float(np.ceil(target))
            if target > _MAX_DURATION_S:
                return _fail(f"infeasible: duration: every requirement needs {target / 86400:.1f} d "
                             f"> {_MAX_DURATION_S / 86400:.0f} d")
            try:
                final_maneuver, final_usage, binding = _fit(problem, fam, result.x, target, constraints)
            except (InfeasibleError, RuntimeError) as exc:
                return _fail(f"infeasible: {exc}")
            verified = target <= _FULL_BOUND_MAX_S
            final_bound = problem.bound(final_maneuver, target, result.period_s, fast=not verified)
            final_ratios = requirement_ratios(final_bound)
            _say(f"design: at {target:.0f} s the largest CRLB/requirement is {np.max(final_ratios):.3f}")
            final_s = float(target)
            if np.max(final_ratios) <= 1.0:
                break
            target *= float(np.max(final_ratios)) ** 2 * 1.01
    out = Path(args.out or f"taiji2_out/design-{Path(args.config).stem if args.config else args.layout}")
    out.mkdir(parents=True, exist_ok=True)
    maneuver_path = out / "maneuver.yaml"
    save_maneuver_file(maneuver_path, final_maneuver,
                       f"taiji2 design: layout {layout}, family {args.family}, {final_s:.0f} s, seed {args.seed}\n"
                       f"max CRLB/requirement {np.max(final_ratios):.3f}; maneuver_commander maneuver")
    report: dict[str, Any] = {
        "layout": layout, "family": args.family, "seed": args.seed, "reference_duration_s": reference_s,
        "minimize_duration": bool(args.minimize_duration), "shortest_duration_s": (
            final_s if args.minimize_duration else reference_s * float(np.max(ratios)) ** 2),
        "shortest_verified": bool(args.minimize_duration and verified),
        "binding_constraint": binding, "evaluations": result.evaluations,
        "search": {"evaluations": result.evaluations, "max_evaluations": result.max_evaluations,
                   "generations": result.generations, "max_generations": args.generations,
                   "wall_cap_s": result.budget_s if np.isfinite(result.budget_s) else None,
                   "wall_s": result.wall_s, "truncated": result.truncated,
                   "x": [float(v) for v in result.x]},
        "constraints": {"range_margin": constraints.range_margin, "range_m_s2": problem.range_m_s2,
                        "range_sigmas": constraints.range_sigmas,
                        "noise_sigma_fraction_of_range": np.asarray(problem.noise_fraction).tolist(),
                        "max_attitude_rad": constraints.max_attitude_rad, "min_thrust_n": problem.min_thrust_n,
                        "max_thrust_n": problem.max_thrust_n, "lever_arm_m": problem.lever_arm_m},
        "design": summary(problem, final_maneuver, final_s, final_usage, final_bound, final_ratios),
        "design_at_reference": summary(problem, maneuver, reference_s, usage, bound, ratios),
        "paper": summary(problem, paper, reference_s, paper_usage, paper_bound, paper_ratios),
        "at_reference": at_reference, "maneuver_file": str(maneuver_path),
    }
    report["wall_s"] = time.monotonic() - started
    write_report(out, report, plots=not args.no_plots)
    print(f"design {layout} {args.family}: max CRLB/requirement at {reference_s:.0f} s: design "
          f"{at_reference['design_max']:.3f} ({at_reference['design_binding']}) vs paper "
          f"{at_reference['paper_max']:.3f} ({at_reference['paper_binding']}), reduction "
          f"{at_reference['reduction']:.1%}"
          + (f" (the paper's preset leaves the range constraint: peak + {constraints.range_sigmas:g} sigma = "
             f"{at_reference['paper_range_excess']:.2f} x margin x range)" if at_reference['paper_range_excess'] > 1.0
             else "")
          + f"; every requirement met at {report['shortest_duration_s'] / 3600:.2f} h "
          f"(paper {report['paper']['shortest_duration_all_met_s'] / 3600:.2f} h); binding constraint {binding}; "
          f"{maneuver_path}, {out / 'report.md'} ({report['wall_s']:.0f} s)")
    if result.truncated:
        _say(f"warning: taiji2 design: search truncated by the wall-clock cap ({result.budget_s:.0f} s) after "
             f"{result.evaluations} of {result.max_evaluations} evaluations: another run with the same seed may "
             f"give another design")
    return 0
