"""What a run is: the node processes of a graph, when the run is done, what progress it makes; and its outcome.

Only the standard library: the verbs import this at module level (a verb's rule, taiji2_apps.cli.main).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

#: a node process's command line starts with this: ``taiji2 <verb> ...`` run by this interpreter
TAIJI2 = (sys.executable, "-m", "taiji2_apps.cli.main")


@dataclass(frozen=True)
class NodeProcess:
    """One process of the graph: its command line, its environment, and how it is allowed to end.

    ``ends``: it ends by itself (status 0) once its part is done (the simulator after ``duration_s``); the run
    waits for it at its end (:attr:`Graph.end_grace_s`), and while it runs the run counts as progressing. Every
    other node runs until the runner stops it: its exit before the run is done, whatever the status, is a
    failure. ``stop_last``: its output is a product of the run (the recorder's bag): it is stopped after the
    others, with its own bound (it may have a backlog to write), and it must then exit with status 0.
    """

    name: str
    argv: tuple[str, ...]
    env: Mapping[str, str] = field(default_factory=dict)
    ends: bool = False
    stop_last: bool = False

    @classmethod
    def taiji2(cls, name: str, argv: Sequence[str], *, ends: bool = False, stop_last: bool = False) -> NodeProcess:
        """``taiji2 ARGV...`` (a node: ``run PKG EXECUTABLE --ros-args ...``; the recorder: ``bag record ...``),
        unbuffered so that its log is complete up to the moment it fails."""
        return cls(name, (*TAIJI2, *argv), {"PYTHONUNBUFFERED": "1"}, ends=ends, stop_last=stop_last)


@dataclass(frozen=True)
class Progress:
    """How far the run is: its results rest on ``simulated_s`` of ``total_s`` simulated seconds.

    ``detail`` is added to the progress line. The run progresses while its :class:`Progress` changes (all
    fields: ``marker`` carries what moves without moving ``simulated_s``, e.g. every estimate's stamp)."""

    simulated_s: float
    total_s: float
    detail: str = ""
    marker: Hashable = None

    def summary(self) -> str:
        """``42.0 % of 3600 s simulated[; detail]``."""
        done = 100.0 * max(0.0, min(self.simulated_s / self.total_s, 1.0)) if self.total_s > 0 else 0.0
        return f"{done:5.1f} % of {self.total_s:g} s simulated" + (f"; {self.detail}" if self.detail else "")

    def line(self, wall_s: float) -> str:
        """The progress line (stderr): one format for every run."""
        return f"  {self.summary()} ({wall_s:.0f} s wall)"


def _default_stall(stall_s: float, progress: Progress) -> str:
    return (f"the run has not progressed for {stall_s:g} s of wall time since its self-ending nodes ended; "
            f"{progress.summary().strip()}")


@dataclass
class Graph:
    """A run of node processes (:func:`taiji2_apps.runner.run_graph`).

    * ``nodes``: started in this order, each with its log ``log_dir/NAME.log`` (stdout and stderr);
    * ``done()``: the run's end condition, asked after each ``wait``;
    * ``progress()``: printed every ``progress_period_s`` and compared for stall detection;
    * ``wait(seconds)``: wait up to that long and handle what arrived (the verb's monitor spins its DDS node
      here); the runner checks the nodes, the end, stall and timeout after each;
    * ``timeout_s``: wall-clock limit of the run (the user's ``--timeout-s``);
    * ``stall_s``: once every ``ends`` node has ended, wall time without any change of ``progress()`` before the
      run is declared stuck (while such a node runs, the run progresses: a simulator held at start-up until its
      readers have matched, or slowed by a busy machine, is not stuck). ``stall_message(stall_s, progress)``
      says what was short of the end;
    * ``end_grace_s``: once done, wall time to wait for the ``ends`` nodes to exit (the simulator publishes its
      final diagnostics just before);
    * ``stop_waits_s``: wall time a node has to exit after SIGINT, then after SIGTERM, then after SIGKILL;
      a ``stop_last`` node's first wait is what is left of ``timeout_s`` (at least ``min_last_stop_s``);
    * ``prefix``: what the runner's own stderr lines start with (``experiment``).
    """

    nodes: Sequence[NodeProcess]
    log_dir: Path
    done: Callable[[], bool]
    progress: Callable[[], Progress]
    wait: Callable[[float], None] = time.sleep
    timeout_s: float = 1800.0
    stall_s: float = 60.0
    stall_message: Callable[[float, Progress], str] = _default_stall
    end_grace_s: float = 60.0
    poll_s: float = 0.1
    progress_period_s: float = 5.0
    stop_waits_s: tuple[float, float, float] = (10.0, 5.0, 5.0)
    min_last_stop_s: float = 60.0
    prefix: str = "experiment"


@dataclass(frozen=True)
class RunResult:
    """The outcome of :func:`~taiji2_apps.runner.run_graph`.

    ``failure``: why the run failed (a first line naming the cause, then perhaps the tail of a node's log);
    None: it was done. ``wall_s``: wall time from the start to the end (done or failed), before the stop.
    ``exit_statuses``: every started node's exit status (negative: the signal that ended it). ``forced``: the
    nodes that did not exit on SIGINT and the signal that ended them. ``stop_problems``: what went wrong
    stopping a ``stop_last`` node (its product is incomplete).
    """

    failure: str | None
    wall_s: float
    exit_statuses: Mapping[str, int]
    forced: Mapping[str, str]
    stop_problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return self.failure is None and not self.stop_problems
