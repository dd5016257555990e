"""The cost and the verdict of the diagnosis's relinearisation (stage 3b, ``stages/relinearize.py``) on 3-h records.

Two large effects alone on a 3-h Type-1 record (unclipped readout, standard simulator): a force leakage of 0.04 /m
per diagonal term from 5,400 s and a thruster torque gain of 0.02 about y from the start. Each is diagnosed twice in
one process, without the relinearisation (its threshold set out of reach: the baseline) and with it; the wall time
of each, its ratio, how far the selected model moved G and d, and the verdict. Issue 39: a 3-h diagnosis <= 60 s.

Usage::

    python benchmarks/bench_relinearize_cost.py [--seed 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one BLAS thread, as the blind benchmark's workers

import numpy as np

import taiji2_estimator_pkg.diagnosis.stages.relinearize as relinearize
from taiji2_estimator_pkg.diagnosis import DiagnosisOptions, diagnose, prepare_input
from taiji2_model.config import load_config
from taiji2_model.effect_catalog import make_effect
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

EFFECTS = {
    "force leakage 0.04 /m diagonal from 5400 s": {"name": "thruster_force_leakage",
                                                   "leakage_per_m": (np.eye(3) * 0.04).tolist(), "onset_s": 5400.0},
    "torque gain 0.02 y": {"name": "thruster_torque_gain", "gain": 0.02, "axis": "y"},
}
DURATION_S = 10800.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    config = load_config("type1", {"grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, round(DURATION_S * config.sample_rate_hz))
    threshold = relinearize.RELINEARIZE_SIGMA
    worst = 0.0
    for label, spec in EFFECTS.items():
        out = simulate_batch(config, args.seed, commands, effects=[make_effect(**spec)])
        inp = prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)
        walls = []
        for on in (False, True):
            relinearize.RELINEARIZE_SIGMA = threshold if on else float("inf")
            started = time.perf_counter()
            result = diagnose(inp, config, DiagnosisOptions())
            walls.append(time.perf_counter() - started)
            moved = result.calibration.get("relinearized", {}).get("moved_sigma")
            print(f"{label}: relinearisation {'on ' if on else 'off'} {walls[-1]:5.1f} s"
                  f"{f', G and d moved {moved:.1f} sigma' if moved else ''}; {result.verdict['summary'][:110]}",
                  flush=True)
        print(f"{label}: {walls[1] / walls[0]:.2f}x the time without", flush=True)
        worst = max(worst, walls[1])
    relinearize.RELINEARIZE_SIGMA = threshold
    print(f"longest 3-h diagnosis with the relinearisation: {worst:.1f} s (goal <= 60 s: "
          f"{'met' if worst <= 60.0 else 'NOT met'})")
    return 0 if worst <= 60.0 else 1


if __name__ == "__main__":
    sys.exit(main())
