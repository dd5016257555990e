"""The calibration graph as separate processes, with a monitor node in the test process, for fault injection.

spacecraft_sim (accelerated, lock-step with the commander), maneuver_commander, the two estimators
(with checkpoint files) and a bag recorder of every topic run as `taiji2 run` / `taiji2 bag record`
subprocesses, as a user starts them. The monitor keeps the latest estimate of each topic and every
/diagnostics status seen, so a test can ask whether a fault was named there.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import Reader

from taiji2_apps.cli.experiment_link import estimate_stamps_ns
from taiji2_runtime.interfaces import typestore
from taiji2_runtime.ros import messages, rclpy

from support import PYTHON, python_subprocess_env

_NS = 1_000_000_000
#: the recorder last (stop() relies on it)
NODES = ("spacecraft_sim", "maneuver_commander", "scale_factor_estimator", "com_offset_estimator", "recorder")
ESTIMATORS = ("scale_factor_estimator", "com_offset_estimator")
RAW_TOPICS = ("/taiji2/star_tracker", "/taiji2/grs1/voltages", "/taiji2/grs2/voltages")
ESTIMATE_TOPICS = tuple(f"/taiji2/estimates/grs{g}/{k}" for g in (1, 2) for k in ("scale_factors", "com_offset"))
#: 600 s simulated: the c.m.-offset estimate is determined after a few minutes of the square wave
#: (docs/estimators.md), and the run takes ~20 s of wall time on an idle core
DURATION_S = 600.0
#: what each node logs once it is up (simulator: its run line; estimator: its method line; recorder: its bag)
_STARTED = {"spacecraft_sim": "layout type1, seed", "maneuver_commander": "the paper's type1 preset",
            "scale_factor_estimator": "method gls", "com_offset_estimator": "method gls", "recorder": "recording into"}
SEED = 4
#: a wait bounded by simulated progress (``spin_until(..., while_moving=True)``) ends after this much wall time
#: however the graph moves (the kill graph takes 45-75 s on 2 busy cores)
MOVING_WAIT_CAP_S = 900.0


def bag_stamps(bag: Path) -> dict[str, list[int]]:
    """Header stamps [ns] of the raw topics in ``bag`` (the files its metadata lists), per topic, in bag order."""
    store = typestore()
    out: dict[str, list[int]] = {t: [] for t in RAW_TOPICS}
    with Reader(bag) as reader:
        for connection, _, data in reader.messages():
            if connection.topic in out:
                h = store.deserialize_cdr(data, connection.msgtype).header
                out[connection.topic].append(h.stamp.sec * _NS + h.stamp.nanosec)
    return out


def last_stamps(bag: Path) -> dict[str, int]:
    """Header stamp [ns] of the last message of each raw topic in ``bag`` (topics with none left out)."""
    store = typestore()
    with Reader(bag) as reader:
        raw = [c for c in reader.connections if c.topic in RAW_TOPICS]
        last = {c.topic: (c.msgtype, data) for c, _, data in reader.messages(raw)}
    stamps = {}
    for topic, (msgtype, data) in last.items():
        h = store.deserialize_cdr(data, msgtype).header
        stamps[topic] = h.stamp.sec * _NS + h.stamp.nanosec
    return stamps


@dataclass
class Diagnostic:
    name: str
    level: int
    message: str
    values: dict[str, Any]


@dataclass
class Graph:
    """One graph run under ``root``; ``start()``, inject faults, ``wait_for_end()``, ``stop()``."""

    root: Path
    context: Any
    duration_s: float = DURATION_S
    recorder_extra: list[str] = field(default_factory=list)
    #: RLIMIT_FSIZE of the recorder [bytes]: every file it writes stops growing there (EFBIG, like ENOSPC)
    recorder_file_size_limit: int | None = None
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)
    bags: list[Path] = field(default_factory=list)
    diagnostics: list[Diagnostic] = field(default_factory=list)
    latest: dict[str, Any] = field(default_factory=dict)
    #: the simulator's latest /clock [s] (-1 before the first)
    sim_time_s: float = -1.0
    exit_codes: dict[str, list[int]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        self.node = rclpy.node.Node("fault_monitor", context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        t = messages.taiji2_msgs
        qos = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL)
        for topic in ESTIMATE_TOPICS:
            cls = t.ScaleFactorEstimate if topic.endswith("scale_factors") else t.ComOffsetEstimate
            self.node.create_subscription(cls, topic, lambda m, k=topic: self.latest.__setitem__(k, m), qos)
        self.node.create_subscription(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", self._on_diag, 100)
        self.node.create_subscription(messages.rosgraph_msgs.Clock, "/clock", self._on_clock, 10)

    # -- processes -------------------------------------------------------------------------------
    def argv(self, name: str) -> list[str]:
        est = ["--ros-args", "-p", "layout:=type1", "-p", f"checkpoint_file:={self.root / (name + '.ckpt')}"]
        if name in ESTIMATORS:
            return ["run", "taiji2_estimator_pkg", name, *est]
        if name == "maneuver_commander":
            return ["run", "taiji2_sim_pkg", name, "--ros-args", "-p", "preset:=type1", "-p", "use_sim_time:=true",
                    "-p", "lookahead_s:=2.0", "-p", "maneuver:=paper"]  # the square wave the fault-free run flies
        if name == "spacecraft_sim":
            # star tracker: scale-factor estimator + recorder; each GRS: both estimators + recorder
            return ["run", "taiji2_sim_pkg", name, "--ros-args", "-p", "layout:=type1", "-p", f"seed:={SEED}",
                    "-p", f"duration_s:={self.duration_s}", "-p", "wait_for_subscribers:=[2, 3, 3]",
                    "-p", "exit_when_done:=false", "-p", "publish_truth:=false",
                    "-p", "config_overrides:=" + json.dumps([f"maneuver.duration_s={self.duration_s}",
                                                             "grs.readout_saturation=false"])]
        bag = self.root / f"bag{len(self.bags)}"
        self.bags.append(bag)
        return ["bag", "record", "-a", "-o", str(bag), *self.recorder_extra]

    def spawn(self, name: str) -> None:
        log = (self.root / f"{name}.log").open("a")
        limit = self.recorder_file_size_limit if name == "recorder" else None
        preexec = None if limit is None else (lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
        self.procs[name] = subprocess.Popen([PYTHON, "-m", "taiji2_apps.cli.main", *self.argv(name)],
                                            stdout=log, stderr=subprocess.STDOUT, env=python_subprocess_env(),
                                            preexec_fn=preexec)

    def start(self) -> None:
        for name in NODES:
            self.spawn(name)

    def log(self, name: str) -> str:
        return (self.root / f"{name}.log").read_text(errors="replace")

    def dead(self) -> list[str]:
        """Nodes that exited (none should until ``stop()``)."""
        return [n for n, p in self.procs.items() if p.poll() is not None]

    def kill_and_restart(self, name: str) -> None:
        proc = self.procs[name]
        proc.send_signal(signal.SIGKILL)
        self.exit_codes.setdefault(name, []).append(proc.wait(timeout=10))
        self.spawn(name)

    def wait_until_restarted(self, name: str, timeout_s: float = 60.0) -> None:
        """Spin until the restarted ``name`` logged its start-up line a second time (it is up)."""
        self.spin_until(lambda: self.log(name).count(_STARTED[name]) >= 2, timeout_s, f"{name} to start again")

    def stall(self, name: str, seconds: float) -> None:
        """SIGSTOP ``name`` for ``seconds`` of wall time, spinning the monitor meanwhile, then SIGCONT."""
        os.kill(self.procs[name].pid, signal.SIGSTOP)
        try:
            self.spin_for(seconds)
        finally:
            os.kill(self.procs[name].pid, signal.SIGCONT)

    def stop(self) -> dict[str, int]:
        """SIGINT every node, the recorder last; their exit codes (a clean stop is 0).

        The recorder may trail the accelerated graph and writes its whole backlog on SIGINT (as
        `taiji2 experiment` stops it): it gets the CPU the others used and a bound of its own."""
        codes = {}
        for group, timeout_s in ((NODES[:-1], 20.0), (NODES[-1:], 120.0)):
            for name in group:
                if self.procs[name].poll() is None:
                    self.procs[name].send_signal(signal.SIGINT)
            for name in group:
                codes[name] = self._wait_exit(name, timeout_s)
        self.executor.shutdown()
        self.node.destroy_node()
        return codes

    def _wait_exit(self, name: str, timeout_s: float) -> int:
        """Exit code of node ``name`` after SIGINT; SIGKILL (-9) after ``timeout_s`` without progress.

        Progress of the recorder, which writes its whole backlog on SIGINT: its bags still growing
        (under load that backlog takes longer than any fixed bound; a recorder that hangs stops growing)."""
        proc = self.procs[name]
        start = time.monotonic()
        deadline, size = start + timeout_s, self._bag_bytes(name)
        while True:
            try:
                return proc.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                now, grown = time.monotonic(), self._bag_bytes(name)
                if grown != size and now - start < MOVING_WAIT_CAP_S:
                    deadline, size = now + timeout_s, grown
                if now > deadline:
                    proc.kill()
                    return -9

    def _bag_bytes(self, name: str) -> int:
        """Bytes in the recorder's bags (0 for the other nodes)."""
        if name != NODES[-1]:
            return 0
        total = 0
        for bag in self.bags:
            try:
                total += sum(f.stat().st_size for f in bag.iterdir())
            except OSError:  # a journal removed while listed: the bag moved, so it grew
                total -= 1
        return total

    # -- monitor ---------------------------------------------------------------------------------
    def _on_diag(self, msg: Any) -> None:
        for s in msg.status:
            values = {}
            for kv in s.values:
                try:
                    values[kv.key] = json.loads(kv.value)
                except ValueError:
                    values[kv.key] = kv.value
            self.diagnostics.append(Diagnostic(s.name, int.from_bytes(s.level, "little") if isinstance(
                s.level, bytes) else int(s.level), s.message, values))

    def _on_clock(self, msg: Any) -> None:
        self.sim_time_s = msg.clock.sec + msg.clock.nanosec / _NS

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def motion(self) -> tuple[float, ...]:
        """What moves while the graph makes simulated progress: the simulator's clock and every estimate's stamp."""
        return (self.sim_time_s, *(self.stamp_s(t) for t in ESTIMATE_TOPICS))

    def spin_until(self, predicate: Any, timeout_s: float, what: str, *, while_moving: bool = False) -> None:
        """Spin the monitor until ``predicate()``; a timeout, or a node that died meanwhile, fails the
        test with the tail of every node's log (a CI failure must say which node stopped and why).

        ``while_moving``: ``timeout_s`` counts from the graph's last simulated progress (:meth:`motion`
        changed), not from the call, so a loaded machine that runs the graph slower still passes and a
        graph that stopped still fails within ``timeout_s`` (:data:`MOVING_WAIT_CAP_S` in all)."""
        start = time.monotonic()
        deadline, motion = start + timeout_s, self.motion()
        while not predicate():
            dead = self.dead()
            assert not dead, f"{', '.join(dead)} died while waiting for {what}\n{self.log_tails()}"
            now = time.monotonic()
            if while_moving and self.motion() != motion and now - start < MOVING_WAIT_CAP_S:
                deadline, motion = now + timeout_s, self.motion()
            still = "without simulated progress " if while_moving else ""
            assert now < deadline, (f"timed out after {timeout_s} s {still}waiting for {what} "
                                    f"({now - start:.0f} s in all)\n{self.log_tails()}")
            self.executor.spin_once(timeout_sec=0.05)

    def log_tails(self, lines: int = 12) -> str:
        """The last ``lines`` lines of each node's log, and the latest estimate stamp per topic."""
        out = [f"estimate stamps [s]: {({t: round(self.stamp_s(t), 1) for t in ESTIMATE_TOPICS})}"]
        for name in NODES:
            path = self.root / f"{name}.log"
            tail = path.read_text(errors="replace").splitlines()[-lines:] if path.exists() else ["(no log)"]
            out.append(f"--- {name} (exit {self.procs[name].poll() if name in self.procs else None}):")
            out.extend(line[:300] for line in tail)
        return "\n".join(out)

    def stamp_s(self, topic: str) -> float:
        m = self.latest.get(topic)
        # an estimate is as far as all its inputs: d's data and the G it used (its scale_factors_stamp)
        return -1.0 if m is None else min(estimate_stamps_ns(m)) / _NS

    def progress_s(self) -> float:
        """Simulated time every estimate has reached [s] (-1 before the first of each)."""
        return min(self.stamp_s(t) for t in ESTIMATE_TOPICS)

    def wait_for_progress(self, t_s: float, timeout_s: float = 60.0) -> None:
        """Spin until every estimate reached ``t_s`` [s]; fails after ``timeout_s`` without simulated progress."""
        self.spin_until(lambda: self.progress_s() >= t_s, timeout_s, f"the estimates to reach t = {t_s} s",
                        while_moving=True)

    def wait_for_sim_time(self, t_s: float, timeout_s: float = 60.0) -> None:
        """Spin until the simulator's clock reached ``t_s`` [s] (the estimators may trail it); fails after
        ``timeout_s`` without simulated progress."""
        self.spin_until(lambda: self.sim_time_s >= t_s, timeout_s, f"the simulator to reach t = {t_s} s",
                        while_moving=True)

    def wait_for_end(self, timeout_s: float = 120.0) -> None:
        self.wait_for_progress(self.duration_s, timeout_s)

    def wait_for_bag(self, bag: Path, t_s: float, timeout_s: float = 60.0) -> dict[str, int]:
        """Spin until the live ``bag`` lists every raw topic up to ``t_s`` [s]; the last stamp [ns] of each then.

        The bag is read as any reader would while it is being recorded: a reading that races the
        writer's move of a file (a journal deleted once its segment closed) is simply repeated. Only
        the last message of each topic is decoded (the test process shares the CPU with the graph)."""
        last: dict[str, int] = {}

        def reached() -> bool:
            nonlocal last
            try:
                last = last_stamps(bag)
            except Exception:  # metadata replaced between reading it and opening a file it listed
                return False
            return len(last) == len(RAW_TOPICS) and min(last.values()) >= t_s * _NS

        # ``timeout_s`` counts from the bag's last progress (its topics' last stamps moved), as the
        # graph's waits do: a loaded machine records slower, a recorder that stopped still fails
        start = time.monotonic()
        deadline, seen = start + timeout_s, dict(last)
        while not reached():
            now = time.monotonic()
            if last != seen and now - start < MOVING_WAIT_CAP_S:
                deadline, seen = now + timeout_s, dict(last)
            assert now < deadline, (f"timed out after {timeout_s} s without progress of {bag} (at "
                                    f"{ {k: v / _NS for k, v in last.items()} }) waiting for it to reach {t_s} s")
            self.spin_for(0.5)
        return last

    def named(self, *words: str) -> list[Diagnostic]:
        """Non-OK /diagnostics statuses whose message contains every one of ``words``."""
        return [d for d in self.diagnostics if d.level > 0 and all(w in d.message for w in words)]

    def estimates(self) -> dict[str, tuple[np.ndarray, np.ndarray, int, int]]:
        """topic -> (value, 1-sigma, samples used, samples rejected) of the latest estimate."""
        out = {}
        for topic, m in self.latest.items():
            if topic.endswith("scale_factors"):
                value, cov = np.array(m.scale_factors), np.reshape(m.covariance, (3, 3))
            else:
                value, cov = np.array([m.offset.x, m.offset.y, m.offset.z]), np.reshape(m.covariance, (3, 3))
            out[topic] = (value, np.sqrt(np.diag(cov)), int(m.samples_used), int(m.samples_rejected))
        return out
