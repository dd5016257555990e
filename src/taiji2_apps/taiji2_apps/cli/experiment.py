"""Run a calibration experiment through the whole node graph and say which requirements it meets.

Starts spacecraft_sim (accelerated simulated time), maneuver_commander, scale_factor_estimator and
com_offset_estimator as separate processes (the runner, taiji2_apps.runner) on the current runtime (the
embedded Cyclone DDS runtime without ROS 2), optionally a bag recorder, waits for the simulated
experiment to end and for the estimators to take its last sample, then prints the final estimates with
their 1-sigma uncertainties against the simulator's truth and ends with the verdict: which requirements
(G 0.3 %, d 100 um, 1 sigma) are met, which cannot be met with this maneuver and duration (their
Cramer-Rao bound, and what to do), and what the simulator warned about.

The default maneuver is the layout's shipped design (taiji2 design; --maneuver paper flies the
paper's preset). Every argument is checked before a node starts. The graph runs on a private DDS
domain unless ROS_DOMAIN_ID is set; without --out, the node logs go to a temporary directory that
is removed at the end (kept on failure or with --keep).

Exit status: 0 every requirement met, 3 the run completed but not every requirement is met,
1 the run failed, 2 bad arguments (one line, before any node starts).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from taiji2_apps.cli.exit_status import ExitStatus
from taiji2_apps.runner import Graph, NodeProcess, Progress, run_to_status

_NS = 1_000_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--layout", default="type1", help="built-in layout: type1 | type2 (default type1)")
    parser.add_argument("--config", default="", help="simulator config YAML instead of --layout")
    parser.add_argument("--duration-s", type=float, default=None,
                        help="experiment length [s] (default: the maneuver file's duration, 3 h for the shipped "
                             "designs and the paper's preset)")
    parser.add_argument("--maneuver", default=None, metavar="design|paper|FILE",
                        help="what maneuver_commander flies: design (default where the layout has one: its shipped "
                             "taiji2 design, config/maneuvers/LAYOUT.yaml), paper (the layout's square-wave preset, "
                             "the paper's maneuver), or a maneuver file (maneuver.yaml of taiji2 design)")
    parser.add_argument("--seed", type=int, default=1, help="simulator seed (default 1)")
    parser.add_argument("--method", default="gls", help="estimator method: gls (default) | paper")
    parser.add_argument("--override", action="append", default=[],
                        help="simulator config override 'dotted.key=value' (repeatable)")
    parser.add_argument("--record", default="", help="also record the raw topics to this bag directory")
    parser.add_argument("--out", default="", help="directory for node logs and results.json (default: a temporary "
                                                  "directory, removed at the end unless --keep or the run fails)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary directory of node logs")
    parser.add_argument("--json", action="store_true", help="print the results (and the verdict) as one JSON object")
    parser.add_argument("--timeout-s", type=float, default=1800.0, help="wall-clock limit [s] (default 1800)")
    from taiji2_apps.cli.experiment_link import add_link_arguments

    add_link_arguments(parser)  # --link MODEL, --link-seed, --link-fault (docs/link.md)


class _Monitor:
    """Keeps the latest estimate and truth of every GRS, and the diagnostics."""

    def __init__(self, node: Any) -> None:
        from taiji2_runtime.ros import messages, rclpy

        t = messages.taiji2_msgs
        qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
        self.latest: dict[str, Any] = {}
        for grs in (1, 2):
            for kind, cls in (("scale_factors", t.ScaleFactorEstimate), ("com_offset", t.ComOffsetEstimate)):
                for source in ("estimates", "sim"):
                    self._watch(node, cls, f"/taiji2/{source}/grs{grs}/{kind}", qos)
        self._watch(node, t.ComOffsetEstimate, "/taiji2/estimates/com_offset_difference", qos)
        self.diagnostics: dict[str, Any] = {}
        node.create_subscription(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", self._on_diag, 100)

    def _watch(self, node: Any, cls: type, topic: str, qos: Any) -> None:
        node.create_subscription(cls, topic, lambda m: self.latest.__setitem__(topic, m), qos)

    def _on_diag(self, msg: Any) -> None:
        for status in msg.status:
            # an estimator is "starved" once the run's data have ended: keep what it said before
            if not status.message.startswith("starved"):
                self.diagnostics[status.name] = status

    def through_ns(self, topic: str) -> int:
        """Time through which the latest estimate on ``topic`` rests on all its inputs [ns]: the earlier of its data
        and scale factors stamps (:func:`~taiji2_apps.cli.experiment_link.estimate_stamps_ns`); -1: none."""
        from taiji2_apps.cli.experiment_link import estimate_stamps_ns

        msg = self.latest.get(topic)
        return -1 if msg is None else min(estimate_stamps_ns(msg))


#: after the simulator has finished, wall time without any estimate moving before the run is declared stuck [s];
#: also the bound on the wait for the simulator to exit (and publish its final diagnostics) once the estimates
#: have ended (it exits within seconds; a busy machine may take longer than the 15 s this was before)
_STALL_S = 60.0


def _private_domain() -> Any:
    """A private DDS domain for this graph unless the user chose one with ROS_DOMAIN_ID (None then)."""
    if os.environ.get("ROS_DOMAIN_ID", "").strip():
        return None
    from taiji2_runtime.domain import reserve_private_domain

    reservation = reserve_private_domain()
    os.environ["ROS_DOMAIN_ID"] = str(reservation.domain_id)  # this process and every node it starts
    return reservation


def main(args: argparse.Namespace) -> int:
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    import shutil
    import tempfile

    from taiji2_apps.experiment_setup import plan_experiment

    try:  # every argument, with the message of the node that would refuse it, before any node starts
        plan = plan_experiment(args.layout, args.config, args.maneuver, args.duration_s, args.override, args.seed,
                               args.method)
        if not args.timeout_s > 0:
            raise ValueError(f"--timeout-s {args.timeout_s:g}: must be > 0")
        if args.record and Path(args.record).exists():
            raise ValueError(f"--record {args.record}: already exists; choose another output or remove it")
        link_only = [o for o, v in (("--link-fault", args.link_fault), ("--key-file", args.key_file),
                                     ("--uplink-attack", args.uplink_attack), ("--ground", args.ground)) if v]
        if link_only and not args.link:
            raise ValueError(f"{', '.join(link_only)}: only with --link (the direct run has no uplink)")
    except ValueError as exc:
        print(f"error: taiji2 experiment: {' '.join(str(exc).split())}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    args.duration_s, args.maneuver = plan.duration_s, plan.maneuver_parameter()
    try:
        reservation = _private_domain()
    except RuntimeError as exc:
        print(f"error: taiji2 experiment: {exc}", file=sys.stderr)
        return ExitStatus.FAILED
    temporary = not args.out
    if temporary:
        args.out = tempfile.mkdtemp(prefix="taiji2-experiment-")
    status = 1
    try:
        if getattr(args, "link", ""):
            from taiji2_apps.cli.experiment_link import run_link_experiment

            status = run_link_experiment(args, plan, temporary)  # onboard and ground joined by a space link
        else:
            status = _run(args, plan, None if reservation is None else reservation.domain_id, temporary)
    finally:
        if reservation is not None:
            reservation.release()
        if temporary and status in (0, 3) and not args.keep:
            shutil.rmtree(args.out, ignore_errors=True)
        elif temporary:
            print(f"experiment: node logs kept in {args.out}", file=sys.stderr)
    return status


def _run(args: argparse.Namespace, plan: Any, domain: int | None, temporary: bool) -> int:
    """The direct graph (one network) through :func:`~taiji2_apps.runner.run_graph`; returns the exit status."""
    from taiji2_runtime.ros import rclpy

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n_steps = round(args.duration_s * 10)
    overrides = [f"maneuver.duration_s={args.duration_s}", *args.override]
    source = ["-p", f"config_file:={args.config}"] if args.config else ["-p", f"layout:={args.layout}"]
    # who reads what: star tracker <- scale-factor estimator (+ com estimator for the paper method);
    # each GRS <- both estimators; plus the recorder on every topic
    extra = 1 if args.record else 0
    subscribers = [1 + (args.method == "paper") + extra, 2 + extra, 2 + extra]
    est_args = ["--ros-args", "-p", f"layout:={args.config or args.layout}", "-p", f"method:={args.method}"]
    nodes = [
        NodeProcess.taiji2("scale_factor_estimator",
                           ["run", "taiji2_estimator_pkg", "scale_factor_estimator", *est_args]),
        NodeProcess.taiji2("com_offset_estimator", ["run", "taiji2_estimator_pkg", "com_offset_estimator", *est_args]),
        NodeProcess.taiji2("maneuver_commander", ["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p",
                                                  f"preset:={args.layout}", "-p", "use_sim_time:=true", "-p",
                                                  "lookahead_s:=2.0", *plan.commander_parameters()]),
        # the simulator exits (0) when done; every other node runs until stopped
        NodeProcess.taiji2("spacecraft_sim", ["run", "taiji2_sim_pkg", "spacecraft_sim", "--ros-args", *source, "-p",
                                              f"seed:={args.seed}", "-p", f"duration_s:={args.duration_s}",
                                              "-p", f"maneuver:={args.maneuver}",  # named in its provenance
                                              "-p", f"wait_for_subscribers:={subscribers}",
                                              "-p", "config_overrides:=" + json.dumps(overrides)], ends=True),
    ]
    if args.record:
        nodes.append(NodeProcess.taiji2("recorder", ["bag", "record", "-a", "-o", args.record], stop_last=True))
    rclpy.init(args=["taiji2-experiment"])
    node = rclpy.create_node("taiji2_experiment")
    monitor = _Monitor(node)
    final_ns = n_steps * 100_000_000
    topics = [f"/taiji2/estimates/grs{g}/{k}" for g in (1, 2) for k in ("scale_factors", "com_offset")]
    topics.append("/taiji2/estimates/com_offset_difference")

    def progress() -> Progress:
        stamps = tuple(monitor.through_ns(t) for t in topics)
        return Progress(max(0, min(stamps)) / _NS, args.duration_s, marker=stamps)

    def stalled(stall_s: float, now: Progress) -> str:
        behind = ", ".join(f"{t} ({'none' if s < 0 else f'{s / _NS:g} s'})"
                           for t, s in zip(topics, now.marker, strict=True) if s < final_ns)
        return (f"the simulator finished {args.duration_s:g} s, but no estimate has moved for {stall_s:g} s; "
                f"short of the end: {behind} (see the estimator logs in {out})")

    graph = Graph(nodes, out, done=lambda: all(monitor.through_ns(t) >= final_ns for t in topics),
                  progress=progress, wait=lambda s: rclpy.spin_once(node, timeout_sec=s), timeout_s=args.timeout_s,
                  stall_s=_STALL_S, stall_message=stalled, end_grace_s=_STALL_S)
    where = (f"DDS domain {domain} (private; set ROS_DOMAIN_ID to choose one)" if domain is not None
             else f"DDS domain {os.environ['ROS_DOMAIN_ID']}")
    print(f"experiment: {args.config or args.layout}, {plan.maneuver_label}, {args.duration_s:g} s simulated, "
          f"seed {args.seed}, method {args.method}; {where}; node logs in {out}", file=sys.stderr)

    def cleanup() -> None:
        node.destroy_node()
        rclpy.try_shutdown()

    return run_to_status(graph, lambda result: _report(args, plan, monitor, out, temporary, result.wall_s), cleanup)


def _report(args: argparse.Namespace, plan: Any, monitor: _Monitor, out: Path, temporary: bool,
            elapsed: float) -> int:
    """Print the final estimates and the verdict, write results.json; returns 0 (every requirement met) or 3."""
    from taiji2_apps.experiment_setup import experiment_verdict
    from taiji2_estimator_pkg.report import EstimateTable, format_table

    table = EstimateTable.from_messages(monitor.latest, layout=args.layout)
    verdict = experiment_verdict(plan, table, args.layout, monitor.diagnostics)
    results = table.to_dict()
    results["maneuver"] = plan.provenance()
    results["verdict"] = verdict.to_dict()
    (out / "results.json").write_text(json.dumps(results, indent=2))
    if args.json:
        print(json.dumps(results))
    else:
        print(format_table(table))
        kept = (f"results in {out / 'results.json'}" if not temporary or args.keep
                else "--out DIR keeps the node logs and results.json")
        print(f"\n{args.duration_s:g} s simulated in {elapsed:.1f} s wall "
              f"({args.duration_s / elapsed:.0f}x real time); {kept}\n")
        print("\n".join(verdict.lines()))
    return verdict_status(verdict)


def verdict_status(verdict: Any) -> ExitStatus:
    """OK when every requirement (the 12 parameters and the GRS linear range) is met, else NOT_MET (3)."""
    return ExitStatus.OK if verdict.all_met else ExitStatus.NOT_MET
