"""Run a calibration experiment through the whole node graph and print the estimates against truth.

Starts spacecraft_sim (accelerated simulated time), maneuver_commander, scale_factor_estimator and
com_offset_estimator as separate processes on the current runtime (the embedded Cyclone DDS runtime
without ROS 2), optionally a bag recorder, waits for the simulated experiment to end and for the
estimators to take its last sample, then prints the final estimates with their 1-sigma
uncertainties against the simulator's truth and the Taiji-2 requirements.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

_NS = 1_000_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--layout", default="type1", help="built-in layout: type1 | type2 (default type1)")
    parser.add_argument("--config", default="", help="simulator config YAML instead of --layout")
    parser.add_argument("--duration-s", type=float, default=None,
                        help="experiment length [s] (default: the --maneuver file's duration, else 3 h)")
    parser.add_argument("--maneuver", default="",
                        help="maneuver file (e.g. maneuver.yaml of taiji2 design) flown by maneuver_commander "
                             "instead of the layout's square wave")
    parser.add_argument("--seed", type=int, default=1, help="simulator seed (default 1)")
    parser.add_argument("--method", default="gls", help="estimator method: gls (default) | paper")
    parser.add_argument("--override", action="append", default=[],
                        help="simulator config override 'dotted.key=value' (repeatable)")
    parser.add_argument("--record", default="", help="also record the raw topics to this bag directory")
    parser.add_argument("--out", default="", help="directory for node logs and results.json (default: a temp dir)")
    parser.add_argument("--json", action="store_true", help="print the results as one JSON object")
    parser.add_argument("--timeout-s", type=float, default=1800.0, help="wall-clock limit [s]")
    from taiji2_estimator_pkg.cli.experiment_link import add_link_arguments

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
            self.diagnostics[status.name] = status

    def stamp_ns(self, topic: str) -> int:
        msg = self.latest.get(topic)
        return -1 if msg is None else msg.header.stamp.sec * _NS + msg.header.stamp.nanosec


def _spawn(argv: list[str], log: Path) -> subprocess.Popen:
    handle = log.open("w")
    return subprocess.Popen([sys.executable, "-m", "taiji2_runtime.cli.main", *argv], stdout=handle,
                            stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONUNBUFFERED="1"))


#: wall time a node has to stop after SIGINT before it is killed [s]
_STOP_TIMEOUT_S = 10.0


def _interrupt(procs: dict[str, subprocess.Popen], timeout_s: float) -> list[str]:
    """SIGINT ``procs``, wait up to ``timeout_s`` for them all; returns the names that had to be killed."""
    for proc in procs.values():
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    deadline, killed = time.monotonic() + timeout_s, []
    for name, proc in procs.items():
        try:
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            killed.append(name)
    return killed


def _stop(procs: dict[str, subprocess.Popen], recorder_timeout_s: float) -> str | None:
    """SIGINT every node, the recorder last; returns why the recording is incomplete (None: it is not).

    At the accelerated rate the recorder can trail the graph by a large share of the run: every raw
    sample is already in its subscriptions (reliable, acknowledged to the simulator), and on SIGINT it
    writes them all before it closes the bag. So it is stopped after the others, given the CPU they
    used, and waited for with its own bound; killing it on the nodes' 10 s would lose that backlog."""
    _interrupt({n: p for n, p in procs.items() if n != "recorder"}, _STOP_TIMEOUT_S)
    recorder = procs.get("recorder")
    if recorder is None:
        return None
    if recorder.poll() is None:
        print("experiment: waiting for the recorder to write what it has received", file=sys.stderr)
    if _interrupt({"recorder": recorder}, recorder_timeout_s):
        return f"the recorder did not finish writing within {recorder_timeout_s:g} s and was killed"
    if recorder.returncode != 0:
        return f"the recorder exited with status {recorder.returncode}"
    return None


def main(args: argparse.Namespace) -> int:
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    if getattr(args, "link", ""):
        from taiji2_estimator_pkg.cli.experiment_link import run_link_experiment

        return run_link_experiment(args)  # onboard and ground joined by a space link (docs/link.md)
    import tempfile

    from taiji2_estimator_pkg.report import EstimateTable, format_table
    from taiji2_runtime.ros import rclpy

    out = Path(args.out or tempfile.mkdtemp(prefix="taiji2-experiment-"))
    out.mkdir(parents=True, exist_ok=True)
    commander_maneuver: list[str] = []
    if args.maneuver:
        from taiji2_sim_pkg.core.config import ConfigError
        from taiji2_sim_pkg.core.maneuver_families import load_maneuver_file

        try:
            flown = load_maneuver_file(args.maneuver)
        except ConfigError as exc:
            print(f"error: taiji2 experiment: {exc}", file=sys.stderr)
            return 2
        if args.duration_s is None:
            args.duration_s = float(flown.start_s + flown.duration_s)
        commander_maneuver = ["-p", f"maneuver_file:={Path(args.maneuver).resolve()}"]
    if args.duration_s is None:
        args.duration_s = 10800.0
    n_steps = round(args.duration_s * 10)
    overrides = [f"maneuver.duration_s={args.duration_s}", *args.override]
    source = ["-p", f"config_file:={args.config}"] if args.config else ["-p", f"layout:={args.layout}"]
    # who reads what: star tracker <- scale-factor estimator (+ com estimator for the paper method);
    # each GRS <- both estimators; plus the recorder on every topic
    extra = 1 if args.record else 0
    subscribers = [1 + (args.method == "paper") + extra, 2 + extra, 2 + extra]
    est_args = ["--ros-args", "-p", f"layout:={args.config or args.layout}", "-p", f"method:={args.method}"]
    commands = {
        "scale_factor_estimator": ["run", "taiji2_estimator_pkg", "scale_factor_estimator", *est_args],
        "com_offset_estimator": ["run", "taiji2_estimator_pkg", "com_offset_estimator", *est_args],
        "maneuver_commander": ["run", "taiji2_sim_pkg", "maneuver_commander", "--ros-args", "-p",
                               f"preset:={args.layout}", "-p", "use_sim_time:=true", "-p", "lookahead_s:=2.0",
                               *commander_maneuver],
        "spacecraft_sim": ["run", "taiji2_sim_pkg", "spacecraft_sim", "--ros-args", *source, "-p",
                           f"seed:={args.seed}", "-p", f"duration_s:={args.duration_s}",
                           "-p", f"wait_for_subscribers:={subscribers}",
                           "-p", "config_overrides:=" + json.dumps(overrides)],
    }
    if args.record:
        commands["recorder"] = ["bag", "record", "-a", "-o", args.record]
    rclpy.init(args=["taiji2-experiment"])
    node = rclpy.create_node("taiji2_experiment")
    monitor = _Monitor(node)
    procs: dict[str, subprocess.Popen] = {}
    started = time.monotonic()
    status = 0
    try:
        for name, argv in commands.items():
            procs[name] = _spawn(argv, out / f"{name}.log")
        print(f"experiment: {args.layout if not args.config else args.config}, {args.duration_s:g} s simulated, "
              f"seed {args.seed}, method {args.method}; node logs in {out}", file=sys.stderr)
        last_progress = 0.0
        final_ns = n_steps * 100_000_000
        topics = [f"/taiji2/estimates/grs{g}/{k}" for g in (1, 2) for k in ("scale_factors", "com_offset")]
        topics.append("/taiji2/estimates/com_offset_difference")
        while True:
            rclpy.spin_once(node, timeout_sec=0.1)
            # the simulator exits (0) when done; every other node runs until stopped
            failed = [n for n, p in procs.items()
                      if p.poll() is not None and (p.returncode != 0 or n != "spacecraft_sim")]
            if failed:
                raise RuntimeError(f"node {failed[0]} exited with status {procs[failed[0]].returncode}; "
                                   f"see {out / (failed[0] + '.log')}")
            if all(monitor.stamp_ns(t) >= final_ns for t in topics):
                break
            if time.monotonic() - started > args.timeout_s:
                raise TimeoutError(f"experiment did not finish within {args.timeout_s:g} s wall time")
            if time.monotonic() - last_progress > 5.0:
                last_progress = time.monotonic()
                done = max(0, min(monitor.stamp_ns(t) for t in topics)) / final_ns
                print(f"  {100 * done:5.1f} % of {args.duration_s:g} s simulated "
                      f"({time.monotonic() - started:.0f} s wall)", file=sys.stderr)
        elapsed = time.monotonic() - started
        table = EstimateTable.from_messages(monitor.latest, layout=args.layout)
        results = table.to_dict()
        if args.maneuver:
            from taiji2_sim_pkg.core.maneuver_families import maneuver_spec

            results["maneuver"] = {"file": str(Path(args.maneuver).resolve()), **maneuver_spec(flown)}
        (out / "results.json").write_text(json.dumps(results, indent=2))
        if args.json:
            print(json.dumps(results))
        else:
            print(format_table(table))
            print(f"\n{args.duration_s:g} s simulated in {elapsed:.1f} s wall "
                  f"({args.duration_s / elapsed:.0f}x real time); results in {out / 'results.json'}")
    except (RuntimeError, TimeoutError) as exc:
        print(f"error: taiji2 experiment: {exc}", file=sys.stderr)
        status = 1
    finally:
        incomplete = _stop(procs, max(60.0, args.timeout_s - (time.monotonic() - started)))
        node.destroy_node()
        rclpy.try_shutdown()
    if incomplete is not None:
        print(f"error: taiji2 experiment: {incomplete}; see {out / 'recorder.log'}", file=sys.stderr)
        status = 1
    return status
