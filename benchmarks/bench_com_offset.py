"""c.m. offsets d against the full Cramer-Rao bound, on our data, on independently simulated data, and
with the noise budget wrong by 2x: the joint estimator's honesty and efficiency (issue 28).

Four studies, each a campaign on the Dask engine (resumable: give ``--out`` and rerun to extend):

1. ``own``: the standard simulator, ``--seeds-own`` seeds per layout (Type-1, Type-2), 3 h.
   Goal: error std / reported sigma in [0.9, 1.1] for every G and d, mean error / sigma within
   +-0.2, d error std within 1.1x the full bound.
2. ``reference``: the reference-fidelity simulator (its own discretisation, timing conventions and
   noise streams), ``--seeds-foreign`` seeds per layout. Goal: d error std / sigma in [0.9, 1.1],
   error std within 1.1x the full bound.
3. ``force2x``: reference-fidelity data with the thruster force noise at 2x PSD, the estimators
   given the nominal budget (``model_overrides``), ``--seeds-foreign`` seeds of Type-1. Goal: d
   error std / sigma in [0.85, 1.15]; the band NIS flags the mismatch.
4. ``bound``: reported sigma of d / full bound for one 3-h record per layout (goal <= 1.03), and
   the same for maneuver files from ``taiji2 design`` (``--design type1=DIR/maneuver.yaml``).

The relative standard error of a std over n seeds is 1/sqrt(2(n-1)): 5 % at 200 seeds, 10 % at 50.
Bracketed ranges are bootstrap 95 % intervals.

    python benchmarks/bench_com_offset.py [--studies own,reference,force2x,bound] [--seeds-own 200]
                                          [--seeds-foreign 50] [--workers 2] [--out DIR]
                                          [--design type1=design-type1/maneuver.yaml ...]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from taiji2_apps.campaign.engine import run_campaign
from taiji2_apps.campaign.spec import load_spec
from taiji2_apps.campaign.store import read_rows
from taiji2_apps.campaign.summary import summarize_table

NOMINAL_FORCE_ASD = 1.0e-7
STUDIES = ("own", "reference", "force2x", "bound")


def _specs(args: argparse.Namespace) -> dict[str, dict]:
    base = {"durations_s": [10800.0], "methods": ["gls"], "chunk_size": 10}
    return {
        "own": {**base, "name": "com_offset_own", "layouts": ["type1", "type2"],
                "seeds": {"start": 20000, "count": args.seeds_own}},
        "reference": {**base, "name": "com_offset_reference", "layouts": ["type1", "type2"],
                      "fidelities": ["reference"], "seeds": {"start": 30000, "count": args.seeds_foreign}},
        "force2x": {**base, "name": "com_offset_force2x", "layouts": ["type1"], "fidelities": ["reference"],
                    "overrides": {"noise.thruster_force.asd_n_rthz": NOMINAL_FORCE_ASD * np.sqrt(2.0)},
                    "model_overrides": {"noise.thruster_force.asd_n_rthz": NOMINAL_FORCE_ASD},
                    "seeds": {"start": 40000, "count": args.seeds_foreign}},
    }


def _report(name: str, out: Path) -> None:
    table = read_rows(out)
    rows = table.to_pydict()
    print(f"\n=== {name}: {out} ===")
    for s in summarize_table(table):
        if s.method != "gls" or s.parameter.startswith("diff."):
            continue
        sel = [i for i, (g, p) in enumerate(zip(rows["group"], rows["parameter"], strict=True))
               if g == s.group and p == s.parameter and rows["status"][i] == "ok"]
        nis_band = np.nanmean([rows["nis_band"][i] for i in sel]) if s.parameter.count(".d_") else float("nan")
        adjusted = np.mean([bool(rows["noise_adjusted"][i]) for i in sel]) if s.parameter.count(".d_") else 0.0
        # the summary's units: % of truth for G, um for d
        print(f"{s.group[:34]:34s} {s.parameter:13s} n={s.n:3d}  err std {s.error_std:8.3f} {s.unit:2s} "
              f"sigma {s.mean_sigma:8.3f}  std/sigma {s.std_over_sigma:5.2f} "
              f"[{s.std_over_sigma_lo:4.2f},{s.std_over_sigma_hi:4.2f}]  mean/sigma {s.mean_error / s.mean_sigma:+5.2f}"
              f"  std/bound {s.std_over_crlb:5.2f} [{s.std_over_crlb_lo:4.2f},{s.std_over_crlb_hi:4.2f}]"
              + (f"  band NIS {nis_band:4.2f} adjusted {adjusted:4.0%}" if np.isfinite(nis_band) else ""))


def _bound_study(designs: list[str]) -> None:
    from taiji2_estimator_pkg.core.crlb import crlb
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.pipeline import calibrate
    from taiji2_model.config import NOISE_SOURCE_NAMES, load_config
    from taiji2_model.maneuver_families import load_maneuver_file
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    print("\n=== bound: reported sigma of d / full bound, one 3-h record (goal <= 1.03) ===")
    cases = [(layout, None) for layout in ("type1", "type2")]
    for item in designs:
        layout, _, path = item.partition("=")
        cases.append((layout, path))
    for layout, path in cases:
        maneuver = load_maneuver_file(path) if path else None
        duration_s = maneuver.duration_s if maneuver else 10800.0
        # the readout unclipped: the paper's preset leaves the GRS range in ~15 % of its samples, and this study
        # is of the reported sigma against the bound, not of saturation
        config = load_config(layout, overrides={"maneuver.duration_s": duration_s, "grs.readout_saturation": False})
        n = round(((maneuver.start_s if maneuver else 0.0) + duration_s) / config.dt_s)
        commands = maneuver_torque_commands(config, n, maneuver=maneuver) if maneuver else \
            maneuver_torque_commands(config)
        out = simulate_batch(config, 1, commands)
        result = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, InstrumentModel.from_layout(config))
        quiet = load_config(layout, overrides={"maneuver.duration_s": duration_s,
                                               **{f"noise.{k}.enabled": False for k in NOISE_SOURCE_NAMES}})
        clean = simulate_batch(quiet, 0, commands)
        sensors = {s.grs_id: s for s in config.grs.sensors}
        bound = crlb(InstrumentModel.from_layout(config), clean.t_s, clean.truth.omega_dot_rad_s2,
                     clean.truth.omega_rad_s, (1, 2), {g: sensors[g].angular_scale_factors for g in (1, 2)},
                     {g: sensors[g].com_offset_m for g in (1, 2)})
        ratio = result.com_offsets.sigma / bound.com_offset_sigma
        print(f"{layout} {path or '(paper preset)'}: sigma/full bound "
              + " ".join(f"{r:.3f}" for r in ratio)
              + f"; full bound {np.round(bound.com_offset_sigma[:3] * 1e6, 1)} um"
              + f", two-stage {np.round(bound.com_offset_sigma_two_stage[:3] * 1e6, 1)} um (GRS1)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", default=",".join(STUDIES))
    parser.add_argument("--seeds-own", type=int, default=200)
    parser.add_argument("--seeds-foreign", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="", help="parent directory of the campaigns (default: temporary)")
    parser.add_argument("--design", action="append", default=[], help="LAYOUT=maneuver.yaml from taiji2 design")
    args = parser.parse_args()
    studies = [s for s in args.studies.split(",") if s]
    unknown = sorted(set(studies) - set(STUDIES))
    if unknown:
        parser.error(f"--studies: unknown {unknown} (known: {', '.join(STUDIES)})")
    specs = _specs(args)
    with tempfile.TemporaryDirectory() as tmp:
        parent = Path(args.out or tmp)
        for name in studies:
            if name == "bound":
                _bound_study(args.design)
                continue
            out = parent / specs[name]["name"]
            run_campaign(load_spec(specs[name]), out, workers=args.workers)
            _report(name, out)


if __name__ == "__main__":
    main()
