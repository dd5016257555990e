"""A run's outcome as a verb's exit status: the report's when the graph ran to its end, else a failure."""

from __future__ import annotations

import sys
from collections.abc import Callable

from taiji2_apps.cli.exit_status import ExitStatus
from taiji2_apps.runner.graph import Graph, RunResult
from taiji2_apps.runner.supervise import run_graph

__all__ = ["run_to_status"]


def run_to_status(graph: Graph, report: Callable[[RunResult], int], cleanup: Callable[[], None],
                  verb: str = "taiji2 experiment") -> int:
    """Run ``graph`` (:func:`~taiji2_apps.runner.supervise.run_graph`) and return the verb's exit status.

    ``report(result)`` gives it when the run reached its end (0 or 3, the verdict's); a failure is one line
    ``error: <verb>: <failure>`` and :attr:`ExitStatus.FAILED`, and so is every node that did not stop cleanly
    (a recording left incomplete), after the report. ``cleanup()`` runs whatever happens (the verb's own node),
    before the stop problems are said.
    """
    try:
        result = run_graph(graph)
        if result.failure is not None:
            print(f"error: {verb}: {result.failure}", file=sys.stderr)
            status = int(ExitStatus.FAILED)
        else:
            status = report(result)
    finally:
        cleanup()
    for problem in result.stop_problems:  # the recording is incomplete
        print(f"error: {verb}: {problem}", file=sys.stderr)
        status = int(ExitStatus.FAILED)
    return status
