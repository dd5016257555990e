"""Run a graph: start its nodes, supervise them until the run is done, print progress, stop them all."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from typing import Any

from taiji2_apps.runner.graph import Graph, Progress, RunResult
from taiji2_apps.runner.processes import Running, Stopped, failure_message, start, stop

#: after the run is done, the waits that take what the nodes published last (final diagnostics) [s]
_DRAIN_WAITS_S = (0.05,) * 5


class _Interrupts:
    """While the run lasts, SIGINT and SIGTERM raise KeyboardInterrupt in the main thread (so that the nodes are
    stopped in order, the recorder last); the handlers before (the DDS runtime's, which shut its context down)
    are restored after the stop. Within :meth:`held` (a node being started and recorded) the interrupt waits
    until the node is on the list of those to stop. Elsewhere than in the main thread, nothing changes."""

    def __init__(self) -> None:
        self._hold = False
        self._pending: int | None = None

    def _interrupt(self, signum: int, _frame: Any) -> None:
        if self._hold:
            self._pending = signum
            return
        raise KeyboardInterrupt(signal.Signals(signum).name)

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        before = {s: signal.signal(s, self._interrupt) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for signum, handler in before.items():
                signal.signal(signum, signal.SIG_DFL if handler is None else handler)

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        self._hold = True
        try:
            yield
        finally:
            self._hold = False
        if self._pending is not None:
            raise KeyboardInterrupt(signal.Signals(self._pending).name)


def run_graph(graph: Graph) -> RunResult:
    """Start ``graph.nodes``, supervise them until ``graph.done()`` (and the ``ends`` nodes have ended), then
    stop them all; returns the outcome. The nodes are stopped whatever happens (a failure, a timeout, an
    exception of the verb's hooks, Ctrl-C or SIGTERM, which are re-raised as KeyboardInterrupt after the stop):
    none outlives the call."""
    graph.log_dir.mkdir(parents=True, exist_ok=True)
    nodes: list[Running] = []
    started = time.monotonic()
    failure: str | None = None
    wall_s = 0.0
    stopped = Stopped()
    interrupts = _Interrupts()
    with interrupts.installed():
        try:
            for spec in graph.nodes:
                with interrupts.held():
                    nodes.append(start(spec, graph.log_dir))
            failure, wall_s = _supervise(graph, nodes, started)
        finally:
            wall_s = wall_s or time.monotonic() - started
            last_wait_s = max(graph.min_last_stop_s, graph.timeout_s - (time.monotonic() - started))
            stopped = stop(nodes, graph.stop_waits_s, last_wait_s, graph.prefix)
    return RunResult(failure, wall_s, {n.name: n.returncode for n in nodes if n.returncode is not None},
                     stopped.forced, tuple(stopped.problems))


def _ended_badly(nodes: Sequence[Running]) -> str | None:
    """The failure of the first node that has ended while the run needed it: with a non-zero status, or (a node
    that runs until stopped) at all."""
    for node in nodes:
        if node.ended() and (node.returncode != 0 or not node.spec.ends):
            return failure_message(node.name, node.returncode or 0, node.log, early=node.returncode == 0)
    return None


def _supervise(graph: Graph, nodes: Sequence[Running], started: float) -> tuple[str | None, float]:
    """Wait until the run is done; returns why it failed (None: done) and the wall time to the end or the failure
    (not counting the wait for the self-ending nodes after the end)."""
    ends = [n for n in nodes if n.spec.ends]
    last_line = -float("inf")
    seen: Progress | None = None
    moved = time.monotonic()
    while True:
        graph.wait(graph.poll_s)
        failure = _ended_badly(nodes)
        if failure is not None:
            return failure, time.monotonic() - started
        if graph.done():
            break
        now = time.monotonic()
        progress = graph.progress()
        # a self-ending node that still runs (the simulator, maybe held at start-up until its readers have
        # matched, or slowed by a busy machine) is progress itself; after it, the results must move
        if progress != seen or any(not n.ended() for n in ends):
            seen, moved = progress, now
        elif now - moved > graph.stall_s:
            return graph.stall_message(graph.stall_s, progress), now - started
        if now - started > graph.timeout_s:
            return (f"{graph.prefix} did not finish within {graph.timeout_s:g} s wall time; "
                    f"{progress.summary().strip()}", now - started)
        if now - last_line > graph.progress_period_s:
            last_line = now
            print(progress.line(now - started), file=sys.stderr)
    wall_s = time.monotonic() - started
    # done: the self-ending nodes publish their last words (the simulator's diagnostics of the whole run) as they
    # exit; wait for them, bounded
    deadline = time.monotonic() + graph.end_grace_s
    while any(not n.ended() for n in ends) and time.monotonic() < deadline:
        graph.wait(graph.poll_s)
    failure = _ended_badly(ends)
    if failure is not None:
        return failure, wall_s
    for seconds in _DRAIN_WAITS_S:
        graph.wait(seconds)
    return None, wall_s
