"""The star tracker sampled at its own instants: G and d against the same seed at phase 0 (the epoch rule).

One Type-1 experiment is simulated with the star tracker reading the attitude ``tau`` after each GRS
instant (the simulator's star-tracker timing, ``timing.star_tracker_stamp_offset_s = -tau``) and stamped
at its reading instants, and calibrated by the bulk path of ``taiji2 calibrate``
(:func:`taiji2_estimator_pkg.calibration.align_streams`, :func:`~taiji2_estimator_pkg.calibration.calibrate`).
Printed per case: the offset the rule measured and modelled, the median stamp phase against the GRS's, the
refused samples, the largest |G - G_0| / sigma_0 and |d - d_0| / sigma_0 over both GRS and axes, and the range
of sigma / sigma_0; cases: tau = 20, 40, 50, 70 ms; 2 ms rms jitter on every stamp (at 40 and 0 ms); 40 ms with the
offset left out of the model (``offsets_s["star_tracker"] = 0``). The same noise draws at every tau.

``--diagnose``: also ``taiji2 diagnose``'s path (:func:`taiji2_estimator_pkg.diagnosis.align_streams`, the
diagnosis's nominal calibration, which takes the measured phase into its model) on the same stamped streams,
against its own phase-0 result (the offset left out is a bulk-path case only).

    python benchmarks/bench_stream_phase.py [--duration-s 2400] [--seed 11] [--diagnose]
"""

from __future__ import annotations

import argparse

import numpy as np

from taiji2_estimator_pkg.calibration import align_streams, calibrate
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

T0_NS = 1_700_000_000 * 10**9


def run(duration_s: float, seed: int, tau_s: float, jitter_s: float = 0.0, model: bool = True,
        diagnose: bool = False):
    """(record, table dict, the diagnosis's nominal calibration or None) of one case."""
    config = load_config("type1", overrides={"maneuver.duration_s": duration_s,
                                              "timing.star_tracker_stamp_offset_s": -tau_s})
    n = round(duration_s * config.sample_rate_hz)
    out = simulate_batch(config, seed, maneuver_torque_commands(config, n))
    rng = np.random.default_rng(5)
    grs_ns = T0_NS + np.rint(out.t_s * 1e9).astype(np.int64)

    def jitter() -> np.ndarray:
        return np.rint(rng.normal(0.0, jitter_s * 1e9, n)).astype(np.int64)

    st_ns, grs1_ns, grs2_ns = grs_ns + round(tau_s * 1e9) + jitter(), grs_ns + jitter(), grs_ns + jitter()
    record = align_streams(st_ns, out.st_quat_xyzw, {1: (grs1_ns, out.voltages_v[:, 0]),
                                                     2: (grs2_ns, out.voltages_v[:, 1])}, config.sample_rate_hz)
    if not model:
        record.offsets_s["star_tracker"] = 0.0
    table = calibrate(record, InstrumentModel.from_layout("type1")).to_dict()
    nominal = None
    if diagnose and model:
        from taiji2_estimator_pkg.diagnosis import align_streams as diagnosis_streams
        from taiji2_estimator_pkg.diagnosis import diagnose as run_diagnosis

        seconds = (lambda ns: (ns - T0_NS) * 1e-9)  # noqa: E731
        # one command per step, stamped at its step's start (the commander publishes each change)
        inp = diagnosis_streams(seconds(st_ns), out.st_quat_xyzw, seconds(grs1_ns), out.voltages_v[:, 0],
                                seconds(grs2_ns), out.voltages_v[:, 1], out.t_s - 1.0 / config.sample_rate_hz,
                                maneuver_torque_commands(config, n), config.sample_rate_hz)
        nominal = run_diagnosis(inp, load_config("type1")).calibration
    return record, table, nominal


def _vectors(table: dict) -> tuple[np.ndarray, ...]:
    g = np.concatenate([table[f"grs{i}"]["scale_factors"] for i in (1, 2)])
    d = np.concatenate([table[f"grs{i}"]["com_offset"] for i in (1, 2)])
    sg = np.concatenate([np.sqrt(np.diag(table[f"grs{i}"]["scale_factors_cov"])) for i in (1, 2)])
    sd = np.concatenate([np.sqrt(np.diag(table[f"grs{i}"]["com_offset_cov"])) for i in (1, 2)])
    return g, d, sg, sd


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration-s", type=float, default=2400.0)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--diagnose", action="store_true", help="also the diagnosis's path (~20 s per case)")
    args = parser.parse_args()
    _, table0, diagnosis0 = run(args.duration_s, args.seed, 0.0, diagnose=args.diagnose)
    g0, d0, sg0, sd0 = _vectors(table0)
    for tau, jitter, model in ((0.020, 0.0, True), (0.040, 0.0, True), (0.050, 0.0, True), (0.070, 0.0, True),
                               (0.040, 0.002, True), (0.0, 0.002, True), (0.040, 0.0, False)):
        record, table, diagnosis = run(args.duration_s, args.seed, tau, jitter, model, args.diagnose)
        g, d, sg, sd = _vectors(table)
        phase = record.phase_s["star_tracker"] - 0.5 * (record.phase_s["grs1"] + record.phase_s["grs2"])
        print(f"tau {tau * 1e3:3.0f} ms, jitter {jitter * 1e3:.0f} ms, offset {'modelled' if model else 'left out'}: "
              f"offset {record.star_tracker_offset_s * 1e3:7.2f} ms, "
              f"median phase against the GRS {phase * 1e3:7.2f} ms, "
              f"refused {record.rejected or 'none'}; "
              f"max |dG|/sigma {np.max(np.abs(g - g0) / sg0):.3f}, max |dd|/sigma {np.max(np.abs(d - d0) / sd0):.3f}, "
              f"sigma_G ratio {np.min(sg / sg0):.4f}-{np.max(sg / sg0):.4f}, "
              f"sigma_d ratio {np.min(sd / sd0):.4f}-{np.max(sd / sd0):.4f}", flush=True)
        if diagnosis is not None:
            print("    diagnose: " + _compare(diagnosis, diagnosis0), flush=True)


def _compare(case: dict, zero: dict) -> str:
    """The diagnosis's nominal calibration against its phase-0 one, in phase-0 sigmas."""
    g, g0 = np.asarray(case["g_angular"]), np.asarray(zero["g_angular"])
    sg, sg0 = np.asarray(case["g_angular_sigma_relative"]), np.asarray(zero["g_angular_sigma_relative"])
    d, d0 = np.asarray(case["com_offset_m"]), np.asarray(zero["com_offset_m"])
    sd, sd0 = np.asarray(case["com_offset_sigma_m"]), np.asarray(zero["com_offset_sigma_m"])
    return (f"max |dG|/sigma {np.max(np.abs(g / g0 - 1.0) / sg0):.3f}, "
            f"max |dd|/sigma {np.max(np.abs(d - d0) / sd0):.3f}, "
            f"sigma_G ratio {np.min(sg / sg0):.4f}-{np.max(sg / sg0):.4f}, "
            f"sigma_d ratio {np.min(sd / sd0):.4f}-{np.max(sd / sd0):.4f}")


if __name__ == "__main__":
    main()
