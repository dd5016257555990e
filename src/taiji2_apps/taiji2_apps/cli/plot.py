"""Simulate an experiment and save the paper-style figures (fit, estimates vs time, error vs CRLB) as PNG."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taiji2_model.maneuver_choice import MANEUVER_HELP, choose_maneuver


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--layout", default="type1", help="built-in layout: type1 | type2 (default type1)")
    parser.add_argument("--duration-s", type=float, default=None,
                        help="experiment length [s] (default: the maneuver's end, 3 h for the paper's preset)")
    parser.add_argument("--maneuver", default=None, metavar="design|paper|FILE", help=MANEUVER_HELP)
    parser.add_argument("--seed", type=int, default=1, help="simulator seed (default 1)")
    parser.add_argument("--thruster-force-noise", choices=("on", "off"), default="on",
                        help="simulate with the thruster force noise of the layout's budget (on, default) or "
                             "without it (off)")
    parser.add_argument("--out", default="taiji2_out/plots", help="output directory (default taiji2_out/plots)")


#: shortest experiment whose running estimates the figures can show [s] (type1 at 120 s: G not yet determined)
_MIN_DURATION_S = 200.0


def main(args: argparse.Namespace) -> int:
    import math

    chosen = choose_maneuver(args.layout, args.maneuver, args.duration_s)
    args.duration_s = chosen.duration_s
    if not (math.isfinite(args.duration_s) and args.duration_s >= _MIN_DURATION_S):
        raise ValueError(f"--duration-s {args.duration_s:g}: must be at least {_MIN_DURATION_S:g} s (shorter runs "
                         "do not determine the estimates the figures show)")
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    import time

    import numpy as np

    from taiji2_apps import plots
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_model.config import load_config
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    started = time.monotonic()
    last = [started]

    def say(message: str) -> None:
        print(f"[{time.monotonic() - started:6.1f} s] {message}", file=sys.stderr, flush=True)

    def progress(k: int, n: int) -> None:
        if time.monotonic() - last[0] >= 10.0:
            last[0] = time.monotonic()
            eta = (time.monotonic() - running) * (n - k) / max(k, 1)
            say(f"  estimators at {k / 10:.0f} of {n / 10:.0f} s of data ({100 * k / n:.0f} %, about {eta:.0f} s left)")

    overrides = {"noise.thruster_force.enabled": args.thruster_force_noise == "on"}
    config = load_config(args.layout, overrides={"maneuver.duration_s": args.duration_s, **overrides})
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    say(f"simulating {args.duration_s:g} s of {args.layout}, {chosen.label} (seed {args.seed}) ...")
    steps = round(args.duration_s * config.sample_rate_hz)
    out = simulate_batch(config, args.seed, maneuver_torque_commands(config, steps, maneuver=chosen.maneuver))
    instrument = InstrumentModel.from_layout(config)
    g_true = np.concatenate([s.angular_scale_factors for s in config.grs.sensors])
    d_true = np.concatenate([s.com_offset_m for s in config.grs.sensors])
    say("running the estimators sample by sample (as the nodes do; about 25 s per simulated hour on an idle "
        "2-core machine) ...")
    running = time.monotonic()
    history = plots.running_estimates(out.t_s, out.st_quat_xyzw, out.voltages_v, instrument, progress=progress)
    if history["t_s"].size < 2:
        raise ValueError(f"--duration-s {args.duration_s:g}: too short for the estimates to be determined")
    say("drawing the figures ...")
    plots.plot_angular_acceleration_fit(out_dir / "angular_acceleration_fit.png", out.t_s, out.st_quat_xyzw,
                                        out.voltages_v, instrument, history["g"][-1], flown=chosen.label)
    plots.plot_estimates(out_dir, history, g_true, d_true, flown=chosen.label)
    plots.plot_error_vs_crlb(out_dir / "error_vs_crlb.png", history, g_true, d_true, args.layout, overrides,
                             maneuver=chosen.maneuver, flown=chosen.label)
    for name in ("angular_acceleration_fit", "scale_factors_vs_time", "com_offsets_vs_time", "error_vs_crlb"):
        print(out_dir / f"{name}.png")
    say("done")
    return 0
