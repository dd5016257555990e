"""Diagnose the sim-to-real gap of a recorded experiment: where it lies, which effect causes it, how far it shrinks.

Reads a bag that follows the raw-data contract (docs/interfaces.md: topics, types, stamps and
timing conventions; star tracker, both GRS, maneuver commands; nothing else is used), calibrates
the nominal model (``--layout`` or ``--config``) on it, compares the data with the calibrated
model channel by channel, band by band and segment by segment, tests every effect of the catalog
(timing and actuation included) as an extension of the model, checks each on held-out data, names
only the effects that stand on their own, and writes report.md, report.json and PNG plots into
--out. Also accepts an ``.npz`` file with the arrays ``t_s``, ``st_quat_xyzw``, ``voltages_v``
(n, 2, 6) and ``torque_cmd_n_m`` (n, 3) on one grid, or a CCSDS packet file or directory
(docs/interfaces.md, recognised by content). Method: docs/diagnosis.md.

The streams are assigned to epochs by the one rule of ``taiji2_estimator_pkg.epochs`` (the same as
``taiji2 calibrate`` and the estimator nodes); gaps of up to 5 s are bridged, longer ones end a segment
(docs/diagnosis.md, inputs).

Exit status: 0 diagnosed, 3 insufficient data, 2 bad input (one-line error), 4 result cannot be
determined (a raw stream without a usable sample: one line ``error: taiji2 diagnose: <stream>: <reason>``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from taiji2_apps.cli.exit_status import ExitStatus

_INSUFFICIENT = 3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``taiji2 diagnose``."""
    parser.add_argument("bag", help="recorded experiment: bag directory, .mcap/.db3 file, .npz arrays, or a CCSDS "
                                    "packet file or directory")
    parser.add_argument("--layout", default="type1",
                        help="nominal model: built-in layout type1 | type2 (default type1)")
    parser.add_argument("--config", default="",
                        help="nominal model: simulator config YAML (instead of --layout); its timing section "
                             "states the data's timing conventions (docs/interfaces.md)")
    parser.add_argument("--out", default="taiji2_out/diagnosis",
                        help="output directory for report.md, report.json, plots (default taiji2_out/diagnosis)")
    parser.add_argument("--json", action="store_true", help="print report.json to stdout")
    parser.add_argument("--write-config", metavar="FILE", default="",
                        help="write the nominal layout extended with the named effects (timing section, effects "
                             "with onsets) to FILE: `taiji2 diagnose BAG --config FILE` then models them")
    parser.add_argument("--candidates", default="", help="comma-separated effect families to consider (default all)")
    parser.add_argument("--exclude", default="", help="comma-separated effect families to leave out")
    parser.add_argument("--f-max-hz", type=float, default=None, help="highest frequency of the fits [Hz] (0.2)")
    parser.add_argument("--orbit-period-s", type=float, default=None,
                        help="orbit period assumed by the gravity-gradient candidate [s] (86164.1)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument("--time-correlation", metavar="FILE", default="",
                        help="packets: onboard -> contract time YAML (default: the packet directory's "
                             "time_correlation.yaml, else identity)")


def _load_npz(path: Path, sample_rate_hz: float) -> Any:
    import numpy as np

    from taiji2_estimator_pkg.diagnosis import prepare_input

    try:
        data = np.load(path)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable .npz file ({exc})") from None
    missing = [key for key in ("t_s", "st_quat_xyzw", "voltages_v", "torque_cmd_n_m") if key not in data]
    if missing:
        raise ValueError(f"{path}: missing arrays {', '.join(missing)}")
    rate = float(data["sample_rate_hz"]) if "sample_rate_hz" in data else sample_rate_hz
    return prepare_input(data["t_s"], data["st_quat_xyzw"], data["voltages_v"], data["torque_cmd_n_m"], rate)


def _load_bag(path: Path | str, sample_rate_hz: float, correlation: Any = None) -> tuple[Any, Any]:
    """The diagnosis input of a bag, packets or a Yamcs archive, and the raw experiment it came from."""
    from taiji2_estimator_pkg.diagnosis import align_streams
    from taiji2_ground_pkg.raw_data import load_raw_data

    raw = load_raw_data(path, correlation=correlation)
    st, grs1, grs2, commands = raw.star_tracker, raw.grs1, raw.grs2, raw.commands
    if st is None or grs1 is None or grs2 is None or commands is None:
        raise ValueError(f"{path}: a raw topic is missing")
    inp = align_streams(st.t_s, st.quat_xyzw, grs1.t_s, grs1.voltages_v, grs2.t_s, grs2.voltages_v, commands.t_s,
                        commands.torque_n_m, sample_rate_hz)
    for report in raw.report.values():  # structural drops of the bag loader count as rejections too
        for reason, count in getattr(report, "dropped", {}).items():
            if count:
                inp.rejected[f"bag_{reason}"] = inp.rejected.get(f"bag_{reason}", 0) + int(count)
    return inp, raw


def _calibration_choice(raw: Any, config: Any, result: Any) -> dict[str, Any]:
    """``taiji2 calibrate``'s result on the same data beside the diagnosis's torque-channel calibration and its
    corrected calibration."""
    from taiji2_estimator_pkg.calibration import align_streams, calibrate
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.diagnosis.calibration_choice import calibration_choice

    grs = {gid: (raw.grs(gid).stamp_ns, raw.grs(gid).voltages_v) for gid in (1, 2)}
    record = align_streams(raw.star_tracker.stamp_ns, raw.star_tracker.quat_xyzw, grs, config.sample_rate_hz)
    return calibration_choice(calibrate(record, InstrumentModel.from_layout(config)), result.calibration,
                              result.corrected, result.verdict, result.blind_spots)


def _share(value: float | None) -> str:
    """A shrink (docs/diagnosis.md section 6) as a percentage."""
    return "-" if value is None else f"{100 * value:.0f} %"


def main(args: argparse.Namespace) -> int:
    """Run the diagnosis; returns the exit status."""
    from taiji2_estimator_pkg.epochs import UndeterminedError

    try:
        return _main(args)
    except UndeterminedError as exc:
        print(f"error: taiji2 diagnose: {exc}", file=sys.stderr)
        return ExitStatus.UNDETERMINED


def _main(args: argparse.Namespace) -> int:
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    import numpy as np

    from taiji2_estimator_pkg.diagnosis import FAMILIES, DiagnosisOptions, diagnose, write_report
    from taiji2_model.config import load_config

    started = time.perf_counter()

    def progress(message: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - started:6.1f} s] {message}", file=sys.stderr, flush=True)

    config = load_config(args.config if args.config else args.layout)
    chosen = [f.strip() for f in args.candidates.split(",") if f.strip()] or list(FAMILIES)
    excluded = {f.strip() for f in args.exclude.split(",") if f.strip()}
    unknown = [f for f in [*chosen, *excluded] if f not in FAMILIES]
    if unknown:
        raise ValueError(f"unknown effect family {unknown[0]!r}; known: {', '.join(FAMILIES)}")
    overrides: dict[str, Any] = {"candidates": tuple(f for f in chosen if f not in excluded)}
    if args.f_max_hz is not None:
        overrides["f_max_hz"] = args.f_max_hz
    if args.orbit_period_s is not None:
        overrides["orbit_period_s"] = args.orbit_period_s
    options = DiagnosisOptions(**overrides)
    from taiji2_ground_pkg.mcs.yamcs_api import is_yamcs_url

    # a Yamcs archive (yamcs://...) is an address, not a path (a Path would fold its "//")
    path: Any = args.bag if is_yamcs_url(args.bag) else Path(args.bag)
    if isinstance(path, Path) and not path.exists():
        raise ValueError(f"{path}: no such bag (the path does not exist)")
    progress(f"reading {path}")
    raw = None
    if isinstance(path, Path) and path.suffix == ".npz":
        inp = _load_npz(path, config.sample_rate_hz)
    else:
        from taiji2_ground_pkg.raw_packets import time_correlation_from

        inp, raw = _load_bag(path, config.sample_rate_hz, time_correlation_from(args.time_correlation))
    rejected = sum(inp.rejected.values())
    progress(f"{inp.n} samples on the grid ({inp.duration_s:.0f} s), {rejected} rejected {inp.rejected or ''}"
             + (f", bridged (gaps <= 5 s) {inp.bridged}" if inp.bridged else ""))
    result = diagnose(inp, config, options, progress)
    choice = None
    if raw is not None and result.status == "ok":  # the raw streams' own calibration, for the report's choice
        progress("the star-tracker calibration (taiji2 calibrate) of the same data, for the report's choice")
        choice = _calibration_choice(raw, config, result)
    files = write_report(result, args.out, plots=not args.no_plots, choice=choice)
    progress(f"wrote {', '.join(str(p) for p in files.values())}")
    if args.write_config:
        import yaml

        layout = result.extended_layout if result.extended_layout is not None else config.to_dict()
        Path(args.write_config).write_text(yaml.safe_dump(layout, sort_keys=False), encoding="utf-8")
        progress(f"wrote the extended layout {args.write_config}"
                 + ("" if result.extended_layout is not None else " (nothing named: the nominal layout)"))
    if args.json:
        print(json.dumps(json.loads(files["report.json"].read_text(encoding="utf-8")), indent=1))
    else:
        verdict = result.verdict
        print(f"verdict: {verdict['summary']}")
        if choice is not None:
            print(f"  calibration to use: taiji2 calibrate's (the star tracker; the torque channel trusts the nominal "
                  f"inertia); they differ by up to {choice['max_difference_sigma']:.1f} combined sigma (report.md)")
        for effect in result.effects:
            if effect.accepted:
                onset = effect.parameters.get("onset_s")
                print(f"  {effect.key}: {effect.magnitude:.4g} +- {effect.sigma:.2g} {effect.unit}"
                      + (f", from {onset['value']:.0f} +- {onset['sigma']:.0f} s"
                         if onset and onset["modelled"] else "")
                      + "; shrink "
                      f"{_share(effect.shrink)} (the part of the gap at its locations that it closes; held-out "
                      f"data: {_share(effect.shrink_heldout)})"
                      + (f"; aliases {', '.join(effect.aliases)}" if effect.aliases else ""))
        corrected = result.corrected
        if corrected:
            shift = max(float(np.max(np.abs(corrected["g_shift_sigma"]))),
                        float(np.max(np.abs(corrected["d_shift_sigma"]))))
            print(f"  corrected calibration (named effects modelled): G and d move by up to {shift:.1f} sigma "
                  "(report.md, report.json corrected_calibration)")
        print(f"report: {files['report.md']}")
    return _INSUFFICIENT if result.status != "ok" else 0
