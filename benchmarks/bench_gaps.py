"""Accuracy of the scale factors G on records with lost epochs, against the same seeds without gaps.

A telemetry stream with dropped packets loses the star tracker and both GRS at the same epochs. For
each seed, one simulated Type-1 experiment is calibrated three times (`taiji2_estimator_pkg.calibration`,
the bulk path of `taiji2 calibrate`): complete; with a fraction of the epochs lost at random; with
the epochs around every torque switch lost (where holding the last GRS input is least right).
Printed per case: the mean and spread over seeds of z = (G - truth) / sigma (unbiased and honest:
mean 0 within ~1/sqrt(seeds) of the complete case, spread ~1) and the mean relative sigma.

    python benchmarks/bench_gaps.py [--duration-s 1200] [--seeds 20] [--lost 0.05] [--switch-width 5]
"""

from __future__ import annotations

import argparse

import numpy as np

from taiji2_estimator_pkg.calibration import align_streams, calibrate
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch


def z_scores(out, keep: np.ndarray, instrument: InstrumentModel) -> tuple[np.ndarray, np.ndarray]:
    """(6,) (G - truth) / sigma of both GRS and (6,) sigma / truth of the record's kept epochs."""
    stamps = np.rint(out.t_s * 1e9).astype(np.int64)[keep]
    record = align_streams(stamps, out.st_quat_xyzw[keep],
                           {g: (stamps, out.voltages_v[keep, g - 1]) for g in (1, 2)}, instrument.sample_rate_hz)
    table = calibrate(record, instrument).to_dict()
    truth = out.truth.grs_angular_scale_factors[-1]
    g = np.concatenate([table[f"grs{i}"]["scale_factors"] for i in (1, 2)])
    sigma = np.concatenate([np.sqrt(np.diag(table[f"grs{i}"]["scale_factors_cov"])) for i in (1, 2)])
    return (g - truth.reshape(-1)) / sigma, sigma / truth.reshape(-1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=1200.0)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--lost", type=float, default=0.05, help="fraction of epochs lost at random")
    parser.add_argument("--switch-width", type=int, default=5, help="epochs lost around each torque switch")
    args = parser.parse_args()
    config = load_config("type1", overrides={"maneuver.duration_s": args.duration_s})
    n = round(args.duration_s * config.sample_rate_hz)
    commands = maneuver_torque_commands(config, n)
    instrument = InstrumentModel.from_layout("type1")
    switches = np.flatnonzero(np.any(np.diff(commands, axis=0) != 0, axis=1)) + 1
    at_switches = np.ones(n, dtype=bool)
    for s in switches:
        at_switches[max(0, s - args.switch_width // 2):s + args.switch_width - args.switch_width // 2] = False
    cases: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {"complete": [], "lost at random": [],
                                                             "lost at every switch": []}
    for seed in range(args.seeds):
        out = simulate_batch(config, 100 + seed, commands)
        random_keep = np.random.default_rng(seed).random(n) >= args.lost
        for name, keep in (("complete", np.ones(n, dtype=bool)), ("lost at random", random_keep),
                           ("lost at every switch", at_switches)):
            cases[name].append(z_scores(out, keep, instrument))
    print(f"Type-1, {args.duration_s:g} s, {args.seeds} seeds; G of GRS1 and GRS2 (Pphi, Ptheta, Ppsi)")
    for name, results in cases.items():
        z = np.array([r[0] for r in results])
        sigma = np.array([r[1] for r in results])
        lost = {"complete": 0, "lost at random": f"{args.lost:.0%}",
                "lost at every switch": f"{np.count_nonzero(~at_switches)} epochs"}[name]
        print(f"  {name:22s} (lost {lost}): mean z {np.array2string(z.mean(0), precision=2)}, "
              f"spread {np.array2string(z.std(0), precision=2)}, sigma/G [%] "
              f"{np.array2string(100 * sigma.mean(0), precision=3)}")
    print(f"  (mean z resolution: +-{1 / np.sqrt(args.seeds):.2f} per parameter)")


if __name__ == "__main__":
    main()
