"""Calibrate the GRS scale factors and c.m. offsets from a recorded experiment bag (no pub/sub).

Works on any ROS 2 bag that follows the raw-data contract (/taiji2/star_tracker,
/taiji2/grs1/voltages, /taiji2/grs2/voltages; no truth, no provenance needed): runs the same
estimator cores as the nodes, in bulk, and prints the result table, or with --json one JSON
object with, per GRS, "scale_factors", "scale_factors_cov", "com_offset" (CRF, m),
"com_offset_cov", plus "com_offset_difference" (d1 - d2) and its covariance, and the counts of
samples used and rejected (per topic and reason, each sample once) and of the grid samples missing
per topic ("missing": no message at that time; not rejected). BAG may also be a CCSDS packet file
or directory (docs/interfaces.md), recognised by content; its defects are counted per topic.

The streams are assigned to epochs by the one rule of ``taiji2_estimator_pkg.epochs`` (the GRS
instants are the epochs; the star tracker keeps its own constant offset, which the estimator
models). Exit status: 0 calibrated, 2 bad input, 4 result cannot be determined (a raw stream without
a usable sample, or data that do not determine every parameter): one line
``error: taiji2 calibrate: <stream>: <reason>``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from taiji2_apps.cli.exit_status import ExitStatus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="ROS 2 bag directory (MCAP or sqlite3), or a CCSDS packet file or directory")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--layout", default="type1", help="built-in nominal model: type1 | type2 (default type1)")
    source.add_argument("--config", default="", help="nominal model YAML (simulator config format)")
    parser.add_argument("--method", default="gls", choices=("gls", "paper"), help="estimator method (default gls)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    parser.add_argument("--time-correlation", metavar="FILE", default="",
                        help="packets: onboard -> contract time YAML (default: the packet directory's "
                             "time_correlation.yaml, else identity)")


def main(args: argparse.Namespace) -> int:
    """Run the calibration; returns the exit status: 0 every requirement met, 3 not (the verdict says which and
    how long a run of this maneuver would meet them), 4 undetermined (one error line)."""
    from taiji2_estimator_pkg.epochs import UndeterminedError

    try:
        return _main(args)
    except UndeterminedError as exc:
        print(f"error: taiji2 calibrate: {exc}", file=sys.stderr)
        return ExitStatus.UNDETERMINED


def _main(args: argparse.Namespace) -> int:
    from taiji2_estimator_pkg.epochs import UndeterminedError

    started = time.perf_counter()
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    from taiji2_estimator_pkg.calibration import align_streams, calibrate
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.report import format_table
    from taiji2_ground_pkg.raw_data import load_raw_data
    from taiji2_ground_pkg.raw_packets import time_correlation_from
    from taiji2_runtime.bag.provenance import flown_maneuver

    raw = load_raw_data(args.bag, correlation=time_correlation_from(args.time_correlation))
    instrument = InstrumentModel.from_layout(args.config or args.layout)
    grs = {gid: (raw.grs(gid).stamp_ns, raw.grs(gid).voltages_v) for gid in (1, 2)}
    record = align_streams(raw.star_tracker.stamp_ns, raw.star_tracker.quat_xyzw, grs, instrument.sample_rate_hz)
    corrections = None
    if args.config:  # an extended layout (taiji2 diagnose --write-config): remove the known effects first
        from taiji2_model.config import load_config

        layout = load_config(args.config)
        if layout.effects:
            from taiji2_estimator_pkg.diagnosis.correction import correct_raw

            record.quat_xyzw, record.voltages_v, corrections = correct_raw(record.t_s, record.quat_xyzw,
                                                                           record.voltages_v, layout)
    for topic, report in raw.report.items():
        # the loader's stamp flags are left to the epoch rule: it counts the duplicates it refuses, and uses
        # (sorted) the samples a bag holds out of stamp order
        flagged = {r: n for r, n in report.flagged.items() if r not in ("duplicate_stamp", "out_of_order_stamp")}
        for reason, n in {**report.dropped, **flagged}.items():
            record.count(topic, reason, n)
    table = calibrate(record, instrument, args.method)
    if not table.extra["determined"]:
        raise UndeterminedError("star_tracker, grs1, grs2", "the data do not determine every parameter "
                                f"(scale-factor updates {table.extra['samples']['scale_factor_updates']}, "
                                f"c.m.-offset updates {table.extra['samples']['com_offset_updates']})")
    elapsed = time.perf_counter() - started
    duration_s = float(record.t_s[-1] - record.t_s[0]) if record.t_s.size > 1 else 0.0
    table.extra.update({"bag": str(args.bag), "nominal_model": args.config or args.layout,
                        "duration_s": duration_s, "wall_time_s": elapsed})
    if corrections is not None:
        table.extra["known_effects"] = corrections
    flown = flown_maneuver(raw.custom_data)
    table.extra["maneuver"] = flown
    verdict = _verdict(table, duration_s, flown)
    status = ExitStatus.OK if verdict.all_met else ExitStatus.NOT_MET
    if args.json:
        print(json.dumps({**table.to_dict(), "verdict": verdict.to_dict()}))
        return status
    for line in raw.report_lines():
        print(line)
    if raw.packets is not None:
        print("\n".join(raw.packets.lines()))
    print(format_table(table))
    if corrections is not None:
        print("known effects of the layout: " + "; ".join(f"{k.replace('_', ' ')}: {', '.join(v)}"
                                                        for k, v in corrections.items() if v))
    print(f"star tracker read {1e3 * table.extra['star_tracker_offset_s']:.1f} ms after the GRS instants "
          "(modelled); median stamp phases: " + ", ".join(f"{s} {1e3 * v:.1f} ms"
                                                       for s, v in table.extra["stream_phase_s"].items()))
    rejected = table.extra["rejected"]
    if rejected:
        print("rejected: " + "; ".join(f"{s}: " + ", ".join(f"{r} {n}" for r, n in v.items())
                                       for s, v in rejected.items()))
    if table.extra["missing"]:
        print("missing (grid samples without a message): "
              + ", ".join(f"{s} {n}" for s, n in table.extra["missing"].items()))
    ratio = duration_s / max(elapsed, 1e-9)
    print(f"{duration_s:.0f} s of data calibrated in {elapsed:.2f} s ({ratio:,.0f}x real time)\n")
    print("\n".join(verdict.lines()))
    return status


def _verdict(table: object, duration_s: float, flown: str | None) -> object:
    """The verdict of a recording, by the experiment's rules (:func:`taiji2_estimator_pkg.verdict.judge`) on
    the 1-sigma alone: no truth and no bound of the flown maneuver here, so a requirement whose 1-sigma is
    beyond it is named with the run length that would meet it (1-sigma falls as 1/sqrt(T))."""
    from taiji2_estimator_pkg.verdict import judge

    remedy = ("a longer run of this maneuver, or a designed one: taiji2 design --minimize-duration "
              "(docs/maneuver_design.md)")
    return judge(table, None, duration_s, flown or "the maneuver in the data", remedy=remedy)
