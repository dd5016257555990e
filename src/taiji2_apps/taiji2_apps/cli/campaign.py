"""Run a Monte Carlo campaign on Dask (`taiji2 campaign SPEC.yaml`), or summarize one (`taiji2 campaign summarize DIR`).

A spec is a grid (or list) of cases over layouts, maneuvers, durations, config overrides (noise
switches, ...), catalog effects, estimator methods and seeds (docs/campaigns.md). Each case runs
the batch simulator, the offline estimators, the CRLB and optionally the diagnosis, and yields one
row per method and parameter in Parquet chunks under --out. A rerun with the same --out skips the
cases already recorded; Ctrl-C keeps every finished case. By default the cases run on an embedded
Dask LocalCluster (one worker process per core); --scheduler runs them on an existing cluster.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", help="campaign spec YAML, or the word 'summarize'")
    parser.add_argument("directory", nargs="?", default="", help="with 'summarize': the campaign directory")
    parser.add_argument("--out", default="", help="campaign directory (default: taiji2_out/campaigns/<spec name>)")
    parser.add_argument("--scheduler", default="", help="existing Dask scheduler, e.g. tcp://host:8786")
    parser.add_argument("--workers", type=int, default=0, help="worker processes of the embedded cluster "
                                                               "(default: one per core)")
    parser.add_argument("--no-summary", action="store_true", help="skip the summary after the run")


def main(args: argparse.Namespace) -> int:
    if args.target == "summarize":
        if not args.directory:
            raise ValueError("campaign summarize: give the campaign directory")
        return summarize(Path(args.directory))
    if args.directory:
        raise ValueError(f"campaign: unexpected argument {args.directory!r} (did you mean --out?)")
    if args.workers < 0:
        raise ValueError(f"--workers: expected a positive count, got {args.workers}")
    from taiji2_apps.campaign.engine import run_campaign
    from taiji2_apps.campaign.spec import load_spec

    spec = load_spec(args.target)
    out = Path(args.out or Path("taiji2_out") / "campaigns" / spec["name"])
    try:
        run = run_campaign(spec, out, scheduler=args.scheduler or None, workers=args.workers or None)
    except KeyboardInterrupt:
        print(f"[campaign] interrupted: finished cases are in {out}; rerun the same command to resume",
              file=sys.stderr)
        return 130
    if run.completed:
        overhead = run.wall_s * max(run.workers, 1) / run.compute_s - 1 if run.compute_s else float("nan")
        print(f"[campaign] {run.completed} cases ({run.failed} failed) in {run.wall_s:.1f} s on {run.workers} "
              f"workers; case compute {run.compute_s:.1f} s; engine overhead {overhead:+.1%}", file=sys.stderr)
    return 0 if args.no_summary else summarize(out)


def summarize(directory: Path) -> int:
    from taiji2_apps.campaign.plots import plot_campaign
    from taiji2_apps.campaign.store import read_rows
    from taiji2_apps.campaign.summary import format_summary, requirement_summaries, save_summary, summarize_table

    table = read_rows(directory)
    summaries = summarize_table(table)
    requirements = requirement_summaries(table)
    print(format_summary(summaries, requirements))
    failed = sum(1 for s in table.column("status").to_pylist() if s != "ok")
    if failed:
        print(f"\n{failed} failed case(s): see the error_message column", file=sys.stderr)
    paths = save_summary(summaries, directory, requirements) + plot_campaign(table, summaries, directory)
    print(f"\n[campaign] wrote {', '.join(str(p) for p in paths)}", file=sys.stderr)
    return 0
