"""Reproduce the paper's two result tables, then a Monte Carlo against the Cramer-Rao bound.

Part 1 (node graph): Type-1 and Type-2, 3-h experiments through the real graph (spacecraft_sim,
maneuver_commander, scale_factor_estimator, com_offset_estimator as separate processes on the
embedded runtime), thruster force noise on, for the paper's method and the default method; the
paper's published values (its Tables "scale factors" and "c.m. offsets") beside ours, +-1 sigma.

Part 2 (cores directly, parallel processes): for each layout, thruster force noise on and off,
>= 20 seeds: per parameter the mean error, error std, mean reported sigma, the CRLB, and the
ratios error std / mean sigma (honesty, goal [0.8, 1.25]) and error std / CRLB (goal <= 1.2).

    python benchmarks/bench_reproduction.py [--seeds 30] [--duration-s 10800] [--skip-graph] [--processes 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

os.environ.setdefault("TAIJI2_RUNTIME", "cyclonedds")

# The paper's published estimates (value, 1-sigma): scale factors x1e-8 rad s^-2 V^-1, offsets in um.
PAPER = {
    "type1": {"G": {1: [(5.523, 0.004), (5.516, 0.010), (7.367, 0.005)],
                    2: [(5.523, 0.004), (5.516, 0.010), (7.366, 0.005)]},
              "d": {1: [(121.0, 70.3), (179991.6, 31.2), (172.3, 68.8)],
                    2: [(126.6, 67.4), (-180008.0, 29.9), (166.7, 70.5)]}},
    "type2": {"G": {1: [(5.523, 0.002), (5.525, 0.005), (7.363, 0.002)],
                    2: [(5.523, 0.002), (5.525, 0.005), (7.363, 0.002)]},
              "d": {1: [(216397.7, 21.9), (125106.7, 53.1), (175.4, 68.2)],
                    2: [(216397.7, 21.4), (-125093.2, 53.1), (175.5, 68.2)]}},
}
G_NAMES = ("G_Pphi", "G_Ptheta", "G_Ppsi")
AXES = ("x", "y", "z")


def run_graph(layout: str, method: str, duration_s: float, seed: int) -> dict:
    cmd = [sys.executable, "-m", "taiji2_runtime.cli.main", "experiment", "--layout", layout, "--method", method,
           "--duration-s", str(duration_s), "--seed", str(seed), "--json"]
    started = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=6 * 3600)
    if proc.returncode != 0:
        raise SystemExit(f"experiment {layout} {method} failed:\n{proc.stderr[-2000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["wall_s"] = time.perf_counter() - started
    return result


def print_graph_tables(layout: str, runs: dict[str, dict], duration_s: float) -> None:
    print(f"\n=== {layout}: paper's table beside ours (node graph, {duration_s / 3600:g} h, "
          "thruster force noise on) ===")
    print("Scale factors [1e-8 rad s^-2 V^-1]: paper (published) | ours paper method | ours default (gls) | truth")
    for g in (1, 2):
        for k, name in enumerate(G_NAMES):
            row = f"  GRS{g} {name:9}"
            v, s = PAPER[layout]["G"][g][k]
            row += f" {v:7.3f}+-{s:.3f} |"
            for method in ("paper", "gls"):
                r = runs[method][f"grs{g}"]
                row += f" {r['scale_factors'][k] * 1e8:8.4f}+-{np.sqrt(r['scale_factors_cov'][k][k]) * 1e8:.4f} |"
            row += f" {runs['gls'][f'grs{g}']['scale_factors_truth'][k] * 1e8:.3f}"
            print(row)
    print("c.m. offsets [um]: paper (published) | ours paper method | ours default (gls) | truth")
    for g in (1, 2):
        for k, axis in enumerate(AXES):
            v, s = PAPER[layout]["d"][g][k]
            row = f"  GRS{g} {axis:9} {v:10.1f}+-{s:5.1f} |"
            for method in ("paper", "gls"):
                r = runs[method][f"grs{g}"]
                row += f" {r['com_offset'][k] * 1e6:10.1f}+-{np.sqrt(r['com_offset_cov'][k][k]) * 1e6:6.1f} |"
            row += f" {runs['gls'][f'grs{g}']['com_offset_truth'][k] * 1e6:.1f}"
            print(row)
    for method in ("paper", "gls"):
        print(f"  ({method}: {duration_s:g} s simulated in {runs[method]['wall_s']:.0f} s wall)")


def monte_carlo_one(args: tuple[str, bool, int, float]) -> dict:
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.pipeline import calibrate
    from taiji2_sim_pkg.core.config import load_config
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    layout, force_on, seed, duration_s = args
    overrides = {"maneuver.duration_s": duration_s, "noise.thruster_force.enabled": force_on}
    config = load_config(layout, overrides=overrides)
    instrument = InstrumentModel.from_layout(config)
    out = simulate_batch(config, seed, maneuver_torque_commands(config))
    g_true = np.concatenate([s.angular_scale_factors for s in config.grs.sensors])
    d_true = np.concatenate([s.com_offset_m for s in config.grs.sensors])
    row = {}
    for method in ("gls", "paper"):
        r = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, instrument, method=method)
        diff, diff_cov = r.com_offsets.difference()
        row[method] = {
            "g_err": ((r.scale_factors.values - g_true) / g_true).tolist(),
            "g_sig": (r.scale_factors.sigma / g_true).tolist(),
            "d_err": (r.com_offsets.values - d_true).tolist(), "d_sig": r.com_offsets.sigma.tolist(),
            "dd_err": (np.asarray(diff) - (d_true[:3] - d_true[3:])).tolist(),
            "dd_sig": np.sqrt(np.diag(diff_cov)).tolist()}
    return row


def print_monte_carlo(layout: str, force_on: bool, rows: list[dict], bound: object) -> None:
    n = len(rows)
    print(f"\n=== Monte Carlo {layout}, thruster force noise {'on' if force_on else 'off'}, {n} seeds ===")
    crlb = {"g": np.asarray(bound.scale_factor_relative_sigma), "d": np.asarray(bound.com_offset_sigma),
            "dd": np.asarray(bound.difference_sigma())}
    names = [f"GRS{g} {p}" for g in (1, 2) for p in G_NAMES]
    dnames = [f"GRS{g} d{a}" for g in (1, 2) for a in AXES]
    ddnames = [f"d1-d2 {a}" for a in AXES]
    for key, labels, scale, unit in (("g", names, 100.0, "%"), ("d", dnames, 1e6, "um"), ("dd", ddnames, 1e6, "um")):
        print(f"  {'[' + unit + ']':14} {'mean err':>10} {'err std':>10} {'mean sig':>10} {'CRLB':>10} "
              f"{'std/sig':>8} {'std/CRLB':>8} | paper: {'err std':>9} {'mean sig':>9} {'std/sig':>8}")
        err = np.array([r["gls"][f"{key}_err"] for r in rows]) * scale
        sig = np.array([r["gls"][f"{key}_sig"] for r in rows]) * scale
        perr = np.array([r["paper"][f"{key}_err"] for r in rows]) * scale
        psig = np.array([r["paper"][f"{key}_sig"] for r in rows]) * scale
        for j, label in enumerate(labels):
            std = err[:, j].std(ddof=1)
            print(f"  {label:14} {err[:, j].mean():10.4g} {std:10.4g} {sig[:, j].mean():10.4g} "
                  f"{crlb[key][j] * scale:10.4g} {std / sig[:, j].mean():8.2f} {std / (crlb[key][j] * scale):8.2f} | "
                  f"{perr[:, j].std(ddof=1):16.4g} {psig[:, j].mean():9.3g} "
                  f"{perr[:, j].std(ddof=1) / psig[:, j].mean():8.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--skip-graph", action="store_true")
    parser.add_argument("--processes", type=int, default=2)
    args = parser.parse_args()
    from taiji2_estimator_pkg.core.crlb import crlb_for_layout

    for layout in ("type1", "type2"):
        if not args.skip_graph:
            runs = {method: run_graph(layout, method, args.duration_s, seed=1) for method in ("paper", "gls")}
            print_graph_tables(layout, runs, args.duration_s)
        for force_on in (True, False):
            jobs = [(layout, force_on, 1000 + s, args.duration_s) for s in range(args.seeds)]
            with ProcessPoolExecutor(max_workers=args.processes) as pool:
                rows = list(pool.map(monte_carlo_one, jobs))
            bound = crlb_for_layout(layout, args.duration_s,
                                    overrides={"noise.thruster_force.enabled": force_on})
            print_monte_carlo(layout, force_on, rows, bound)
        sys.stdout.flush()


if __name__ == "__main__":
    main()
