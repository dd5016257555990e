"""Simulate an experiment and save the paper-style figures (fit, estimates vs time, error vs CRLB) as PNG."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--layout", default="type1", help="built-in layout: type1 | type2 (default type1)")
    parser.add_argument("--duration-s", type=float, default=10800.0, help="experiment length [s] (default 3 h)")
    parser.add_argument("--seed", type=int, default=1, help="simulator seed (default 1)")
    parser.add_argument("--thruster-force-noise", choices=("on", "off"), default="on")
    parser.add_argument("--out", default="plots", help="output directory (default ./plots)")


def main(args: argparse.Namespace) -> int:
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    import numpy as np

    from taiji2_estimator_pkg import plots
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_sim_pkg.core.config import load_config
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    overrides = {"noise.thruster_force.enabled": args.thruster_force_noise == "on"}
    config = load_config(args.layout, overrides={"maneuver.duration_s": args.duration_s, **overrides})
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"simulating {args.duration_s:g} s of {args.layout} (seed {args.seed}) ...", file=sys.stderr)
    out = simulate_batch(config, args.seed, maneuver_torque_commands(config))
    instrument = InstrumentModel.from_layout(config)
    g_true = np.concatenate([s.angular_scale_factors for s in config.grs.sensors])
    d_true = np.concatenate([s.com_offset_m for s in config.grs.sensors])
    print("running the estimators sample by sample ...", file=sys.stderr)
    history = plots.running_estimates(out.t_s, out.st_quat_xyzw, out.voltages_v, instrument)
    if history["t_s"].size < 2:
        raise ValueError(f"--duration-s {args.duration_s:g}: too short for the estimates to be determined")
    plots.plot_angular_acceleration_fit(out_dir / "angular_acceleration_fit.png", out.t_s, out.st_quat_xyzw,
                                        out.voltages_v, instrument, history["g"][-1])
    plots.plot_estimates(out_dir, history, g_true, d_true)
    plots.plot_error_vs_crlb(out_dir / "error_vs_crlb.png", history, g_true, d_true, args.layout, overrides)
    for name in ("angular_acceleration_fit", "scale_factors_vs_time", "com_offsets_vs_time", "error_vs_crlb"):
        print(out_dir / f"{name}.png")
    return 0
