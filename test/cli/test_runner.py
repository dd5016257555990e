"""The experiment runner (taiji2_apps.runner) with tiny fake node processes (``python -c``; no DDS): a clean run,
a failing node, a node that ends early with status 0, a stalled run, and a stop on Ctrl-C, SIGTERM or an
exception that leaves no process behind. Every wait is on the processes' own output (their logs), never a
sleep."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import psutil
import pytest

from taiji2_apps.runner import Graph, NodeProcess, Progress, run_graph

#: a node that runs until stopped: on SIGINT it notes its name in ORDER (when given) and exits 0
UNTIL_STOPPED = """
import os, signal, sys
def stop(*_):
    if len(sys.argv) > 1:
        with open(sys.argv[1], "a") as f:
            f.write(sys.argv[2] + "\\n")
    sys.exit(0)
signal.signal(signal.SIGINT, stop)
print("ready", flush=True)
while True:
    signal.pause()
"""
#: a node that ends by itself: five samples, then exit 0
SIMULATOR = """
for k in range(1, 6):
    print(f"t={k}", flush=True)
"""


def _node(name: str, code: str, *args: str, **kw: bool) -> NodeProcess:
    return NodeProcess(name, (sys.executable, "-c", code, *args), **kw)


def _log(tmp_path: Path, name: str) -> str:
    try:
        return (tmp_path / f"{name}.log").read_text()
    except FileNotFoundError:
        return ""


def _simulated_s(tmp_path: Path) -> float:
    lines = [line for line in _log(tmp_path, "sim").splitlines() if line.startswith("t=")]
    return float(lines[-1][2:]) if lines else 0.0


@pytest.fixture(autouse=True)
def _children_before_the_test() -> None:
    """The pytest worker's own children (e.g. multiprocessing's resource tracker, started by an earlier test in
    the same worker) are not the run's: only a process that appeared during the test counts as left behind."""
    global _CHILDREN_BEFORE
    _CHILDREN_BEFORE = {c.pid for c in psutil.Process().children(recursive=True)}


_CHILDREN_BEFORE: set[int] = set()


def _no_children_left() -> None:
    children = [c for c in psutil.Process().children(recursive=True) if c.pid not in _CHILDREN_BEFORE]
    assert children == [], [(c.pid, c.cmdline()) for c in children]


def test_a_clean_run_stops_every_node_the_recorder_last_and_prints_progress(tmp_path, capsys):
    order = tmp_path / "order.txt"
    nodes = [_node("worker", UNTIL_STOPPED, str(order), "worker"), _node("sim", SIMULATOR, ends=True),
             _node("recorder", UNTIL_STOPPED, str(order), "recorder", stop_last=True)]
    polled = []  # the run is done only after it has been polled once (a busy machine may finish the fake simulator
    # before the first poll, and a run done at its first poll prints no progress line)
    graph = Graph(nodes, tmp_path, done=lambda: bool(polled) and _simulated_s(tmp_path) >= 5
                  and "ready" in _log(tmp_path, "worker") and "ready" in _log(tmp_path, "recorder"),
                  progress=lambda: polled.append(1) or Progress(_simulated_s(tmp_path), 5.0, "fake"), timeout_s=120.0,
                  poll_s=0.01, progress_period_s=0.0)
    result = run_graph(graph)
    assert result.ok and result.failure is None and result.stop_problems == ()
    assert dict(result.exit_statuses) == {"worker": 0, "sim": 0, "recorder": 0} and dict(result.forced) == {}
    assert order.read_text().split() == ["worker", "recorder"]  # the recorder is stopped after the others
    err = capsys.readouterr().err
    assert "experiment: waiting for the recorder to write what it has received" in err
    progress = [line for line in err.splitlines() if " % of 5 s simulated; fake (" in line]
    assert progress and all(line.startswith("  ") and line.endswith(" s wall)") for line in progress), err
    _no_children_left()


def test_a_failing_node_is_named_with_its_status_and_the_tail_of_its_log(tmp_path):
    failing = ("import sys\nfor k in range(12):\n    print(f'[INFO] step {k}')\n"
               "print(\"error: worker: layout 'x': no such file or built-in layout\", file=sys.stderr)\nsys.exit(2)")
    nodes = [_node("other", UNTIL_STOPPED), _node("worker", failing)]
    result = run_graph(Graph(nodes, tmp_path, done=lambda: False, progress=lambda: Progress(0.0, 5.0),
                             timeout_s=120.0, poll_s=0.01))
    log = tmp_path / "worker.log"
    first, *tail = result.failure.splitlines()
    assert first == (f"node worker exited with status 2: error: worker: layout 'x': no such file or built-in layout "
                     f"(log: {log})")
    assert tail[0] == "  last lines of its log:" and tail[-1].strip().startswith("error: worker: layout 'x'")
    assert [t.strip() for t in tail[1:-1]] == [f"[INFO] step {k}" for k in range(5, 12)]  # the last 8 lines
    assert result.exit_statuses["worker"] == 2 and not result.ok
    _no_children_left()


def test_a_node_that_ends_normally_while_the_run_needs_it_is_reported_at_once(tmp_path):
    nodes = [_node("telemetry_packetizer", "print('[INFO] [1.0] [telemetry_packetizer]: bye')"),
             _node("sim", "import signal\nprint('ready', flush=True)\nsignal.pause()", ends=True)]
    result = run_graph(Graph(nodes, tmp_path, done=lambda: False, progress=lambda: Progress(0.0, 5.0),
                             timeout_s=600.0, stall_s=600.0, poll_s=0.01))
    log = tmp_path / "telemetry_packetizer.log"
    assert result.failure == ("node telemetry_packetizer exited with status 0 before the run was done (it runs until "
                              f"the run stops it): [INFO] [1.0] [telemetry_packetizer]: bye (log: {log})")
    assert result.wall_s < 600.0  # not the timeout
    _no_children_left()


def test_a_run_whose_results_stop_moving_after_the_simulator_ended_is_stuck(tmp_path):
    nodes = [_node("estimator", UNTIL_STOPPED), _node("sim", SIMULATOR, ends=True)]

    def progress() -> Progress:  # once the estimator is up (its SIGINT handler set), only the simulator moves
        return Progress(_simulated_s(tmp_path), 10.0, marker="ready" in _log(tmp_path, "estimator"))

    result = run_graph(Graph(nodes, tmp_path, done=lambda: False, progress=progress, timeout_s=600.0,
                             stall_s=0.2, poll_s=0.01,
                             stall_message=lambda s, p: f"nothing moved for {s:g} s at {p.summary().strip()}"))
    assert result.failure == "nothing moved for 0.2 s at 50.0 % of 10 s simulated"
    assert result.exit_statuses == {"estimator": 0, "sim": 0}
    _no_children_left()


#: ignores SIGINT (ends on SIGTERM)
STUBBORN = "import signal\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nprint('ready', flush=True)\nsignal.pause()"
#: ignores SIGINT and SIGTERM (only SIGKILL ends it)
DEAF = ("import signal\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "print('ready', flush=True)\nwhile True:\n    signal.pause()")
#: starts a grandchild that ignores SIGINT (in the node's process group), prints its pid, runs until SIGINT
PARENT = ("import signal, subprocess, sys\nsignal.signal(signal.SIGINT, lambda *_: sys.exit(0))\n"
          "child = subprocess.Popen([sys.executable, '-c', " + repr(STUBBORN) + "], stdout=subprocess.PIPE)\n"
          "child.stdout.readline()\nprint('grandchild', child.pid, flush=True)\nprint('ready', flush=True)\n"
          "signal.pause()")


@pytest.mark.parametrize("how", ["exception", "SIGINT", "SIGTERM"])
def test_an_interrupt_stops_every_node_and_what_they_started(tmp_path, how):
    names = ("worker", "stubborn", "deaf", "parent")
    nodes = [_node("worker", UNTIL_STOPPED), _node("stubborn", STUBBORN), _node("deaf", DEAF),
             _node("parent", PARENT), _node("recorder", UNTIL_STOPPED, stop_last=True)]

    def wait(seconds: float) -> None:
        time.sleep(seconds)  # the runner's poll period
        if all("ready" in _log(tmp_path, n) for n in (*names, "recorder")):
            if how == "exception":
                raise KeyboardInterrupt
            os.kill(os.getpid(), getattr(signal, how))  # as Ctrl-C, or `kill`, reach the experiment

    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with pytest.raises(KeyboardInterrupt):
        run_graph(Graph(nodes, tmp_path, done=lambda: False, progress=lambda: Progress(0.0, 5.0), wait=wait,
                        timeout_s=600.0, stop_waits_s=(0.5, 0.5, 5.0)))
    assert {s: signal.getsignal(s) for s in before} == before  # the handlers before the run are back
    _no_children_left()
    grandchild = int(next(line for line in _log(tmp_path, "parent").splitlines()
                          if line.startswith("grandchild")).split()[1])
    try:  # reparented to init once its parent ended: reaped by it, or dying of the SIGKILL
        _, alive = psutil.wait_procs([psutil.Process(grandchild)], timeout=5.0)
    except psutil.NoSuchProcess:
        alive = []
    assert alive == [], "a node's child outlived the run"


def test_an_interrupt_while_a_node_starts_waits_until_the_node_is_among_those_to_stop(tmp_path, monkeypatch):
    import taiji2_apps.runner.supervise as supervise

    started = []

    def start_then_interrupt(spec, log_dir):
        running = supervise_start(spec, log_dir)  # the process exists, the runner does not know it yet
        started.append(running.popen.pid)
        os.kill(os.getpid(), signal.SIGINT)
        return running

    supervise_start = supervise.start
    monkeypatch.setattr(supervise, "start", start_then_interrupt)
    nodes = [_node("worker", UNTIL_STOPPED), _node("never_started", UNTIL_STOPPED)]
    with pytest.raises(KeyboardInterrupt):
        run_graph(Graph(nodes, tmp_path, done=lambda: False, progress=lambda: Progress(0.0, 5.0), timeout_s=600.0,
                        stop_waits_s=(5.0, 5.0, 5.0)))
    assert len(started) == 1 and not (tmp_path / "never_started.log").exists()
    _no_children_left()
