"""The experiment runner: one way to run a graph of node processes, for ``taiji2 experiment`` with and without
``--link``.

* :mod:`.graph`: the typed description of a run (:class:`NodeProcess`, :class:`Graph`, :class:`Progress`) and
  its outcome (:class:`RunResult`);
* :mod:`.processes`: start a node with its log, the one message format of a node's failure, stop them all
  (SIGINT, SIGTERM, SIGKILL with bounded waits, the recorder last);
* :mod:`.supervise`: :func:`run_graph`: start, supervise (exit statuses, the end, stall, timeout), print
  progress, stop;
* :mod:`.outcome`: :func:`run_to_status`: the run's outcome as the verb's exit status.

Only the standard library (a verb imports this at module level).
"""

from taiji2_apps.runner.graph import TAIJI2, Graph, NodeProcess, Progress, RunResult
from taiji2_apps.runner.outcome import run_to_status
from taiji2_apps.runner.processes import error_line, failure_message
from taiji2_apps.runner.supervise import run_graph

__all__ = ["TAIJI2", "Graph", "NodeProcess", "Progress", "RunResult", "error_line", "failure_message", "run_graph",
           "run_to_status"]
