"""The diagnosis of records with link losses, with and without the angular loss in its noise model.

Type-1, unclipped readout, the deep_space loss pattern at twice its burst rate with the 10 Hz command rows
lost too (every stream: 1 % at random plus Gilbert-Elliott bursts of mean 10 packets shared by the four
APIDs), played back out of order. Each record is diagnosed twice: as shipped, and with
``DiagnosisInput.angular_loss`` forced to zero (the noise model before the angular loss was in it:
:mod:`taiji2_estimator_pkg.diagnosis.angular_gaps`). Printed per seed: the mean gap weight, the command
changes in doubt, the verdict, the accepted effects, the star-tracker low-frequency noise's delta chi2 and
the largest location's significance against the threshold.

    python benchmarks/bench_angular_gaps.py [--duration-s 10800] [--seeds 11,12,13]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from taiji2_estimator_pkg.diagnosis import align_streams, diagnose
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

_STREAMS = ("star_tracker", "grs1", "grs2", "command")


def lossy_record(config, commands: np.ndarray, seed: int) -> DiagnosisInput:
    """The record of simulator seed ``50 + seed`` as received through the loss pattern of ``seed``."""
    n = commands.shape[0]
    rng = np.random.default_rng(seed)
    keep = {name: rng.random(n) > 0.01 for name in _STREAMS}
    for start in np.flatnonzero(rng.random(4 * n) < 0.002):  # packet index of a burst's start, 4 APIDs
        stop = start + rng.geometric(0.1)
        for k in keep.values():
            k[start // 4: stop // 4 + 1] = False
    for k in keep.values():  # the record's ends received
        k[:10] = True
        k[-1] = True
    out = simulate_batch(config, 50 + seed, commands)
    t = out.t_s
    order = {name: rng.permutation(np.flatnonzero(k)) for name, k in keep.items()}
    return align_streams(t[order["star_tracker"]], out.st_quat_xyzw[order["star_tracker"]],
                         t[order["grs1"]], out.voltages_v[order["grs1"], 0],
                         t[order["grs2"]], out.voltages_v[order["grs2"], 1],
                         t[order["command"]] - config.dt_s, commands[order["command"]], config.sample_rate_hz)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--seeds", default="11,12,13", help="loss-pattern seeds (the simulator's is 50 + seed)")
    args = parser.parse_args()
    config = load_config("type1", {"grs.readout_saturation": False})
    commands = maneuver_torque_commands(config, round(args.duration_s * config.sample_rate_hz))
    shipped = DiagnosisInput.angular_loss
    without = property(lambda self: (0.0, np.zeros((3, 3))))
    print(f"duration {args.duration_s:.0f} s")
    for seed in (int(s) for s in args.seeds.split(",")):
        inp = lossy_record(config, commands, seed)
        weight, _ = inp.angular_loss
        doubts = 0 if inp.command_doubt is None else inp.command_doubt.shape[0]
        for label, loss in (("with", shipped), ("without", without)):
            DiagnosisInput.angular_loss = loss
            try:
                started = time.perf_counter()
                result = diagnose(inp, config)
            finally:
                DiagnosisInput.angular_loss = shipped
            noise = [e.delta_chi2 for e in result.effects if e.name == "star_tracker_lowfreq_noise"]
            top = result.locations[0].significance if result.locations else 0.0
            print(f"seed {seed} {label:7s} weight {weight:.4f} doubts {doubts}: {result.verdict['summary'][:100]!r}; "
                  f"accepted {[e.key for e in result.effects if e.accepted]}; star-tracker noise delta chi2 "
                  f"{noise[0] if noise else 0.0:.1f}; largest location {top:.2f} / {result.location_threshold:.2f} "
                  f"({time.perf_counter() - started:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
