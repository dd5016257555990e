"""The node processes of a run: start each with its log, tell how one ended, stop them all.

Each node runs in a process group of its own (a new session): a Ctrl-C in the terminal reaches only the
runner, which stops the nodes in order (the recorder last, so that it writes its backlog), and every
signal goes to the node's whole group, so that nothing it started outlives it. A node that has exited is
reaped only after its group has been sent SIGKILL (its pid, and so its group id, cannot be reused before).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from taiji2_apps.runner.graph import NodeProcess

#: lines of a failed node's log quoted under the failure's first line
TAIL_LINES = 8
#: wall time between two looks at processes being stopped [s]
_STOP_POLL_S = 0.02


@dataclass
class Running:
    """A started node process."""

    spec: NodeProcess
    popen: subprocess.Popen
    log: Path
    returncode: int | None = field(default=None)

    @property
    def name(self) -> str:
        return self.spec.name

    def ended(self) -> bool:
        """True once the process has exited; the first time, its group is cleared and it is reaped."""
        if self.returncode is not None:
            return True
        if self.popen.returncode is None:
            try:
                if os.waitid(os.P_PID, self.popen.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is None:
                    return False
                self.signal(signal.SIGKILL)  # what the node left in its group (its pid is not free yet)
            except ChildProcessError:  # reaped elsewhere: its pid may be reused, signal nothing
                pass
        self.returncode = self.popen.wait()
        return True

    def signal(self, signum: int) -> None:
        """Send ``signum`` to the node's process group (nothing once it has been reaped)."""
        if self.popen.returncode is not None:
            return
        try:
            os.killpg(self.popen.pid, signum)
        except (ProcessLookupError, PermissionError):
            pass


def start(spec: NodeProcess, log_dir: Path) -> Running:
    """Start ``spec`` in a process group of its own, its stdout and stderr to ``log_dir/NAME.log``."""
    log = log_dir / f"{spec.name}.log"
    with log.open("w") as handle:
        popen = subprocess.Popen(list(spec.argv), stdin=subprocess.DEVNULL, stdout=handle, stderr=subprocess.STDOUT,
                                 env={**os.environ, **spec.env}, start_new_session=True)
    return Running(spec, popen, log)


def log_lines(log: Path) -> list[str]:
    """The non-empty lines of a node's log (none: unreadable)."""
    try:
        text = log.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return []
    return [line.rstrip() for line in text.splitlines() if line.strip()]


def error_line(log: Path) -> str | None:
    """The last ``error: ...`` line of a node's log (of a traceback: its last line), else its last line."""
    lines = [line.strip() for line in log_lines(log)]
    errors = [line for line in lines if line.startswith(("error:", "Traceback", "[ERROR]", "[FATAL]"))]
    if errors and errors[-1].startswith("Traceback"):
        return lines[-1]
    return errors[-1] if errors else (lines[-1] if lines else None)


def describe_status(returncode: int) -> str:
    """``exited with status N`` or, for a signal, ``was ended by SIGNAME (status -N)``."""
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        return f"was ended by {name} (status {returncode})"
    return f"exited with status {returncode}"


def failure_message(name: str, returncode: int, log: Path, *, early: bool = False) -> str:
    """The one format of a node's failure: ``node NAME exited with status N[ before ...]: <its error line> (log:
    LOG)``, then the tail of its log (indented) where it says more than that line. ``early``: it ended, with
    status 0, while the run still needed it."""
    how = describe_status(returncode)
    if early:
        how += " before the run was done (it runs until the run stops it)"
    line = error_line(log)
    text = f"node {name} {how}" + (f": {line}" if line else ": its log is empty") + f" (log: {log})"
    tail = log_lines(log)[-TAIL_LINES:]
    if tail and [t.strip() for t in tail] != [line]:
        text += "\n  last lines of its log:" + "".join(f"\n    {t}" for t in tail)
    return text


def _escalate(nodes: Sequence[Running], waits_s: Sequence[float], forced: dict[str, str]) -> None:
    """SIGINT, SIGTERM, SIGKILL to ``nodes`` still running, each followed by its wait (bounded); records in
    ``forced`` the nodes a later signal than SIGINT ended."""
    for signum, wait_s in zip((signal.SIGINT, signal.SIGTERM, signal.SIGKILL), waits_s, strict=True):
        alive = [n for n in nodes if not n.ended()]
        if not alive:
            return
        for node in alive:
            node.signal(signum)
            if signum != signal.SIGINT:
                forced[node.name] = signal.Signals(signum).name
        deadline = time.monotonic() + wait_s
        while any(not n.ended() for n in alive) and time.monotonic() < deadline:
            time.sleep(_STOP_POLL_S)


def kill_all(nodes: Sequence[Running]) -> None:
    """SIGKILL every node still running and reap it (the last resort: on a second interrupt while stopping)."""
    for node in nodes:
        node.signal(signal.SIGKILL)
    for node in nodes:
        if node.popen.returncode is None:
            try:
                node.popen.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                continue
        node.ended()


@dataclass
class Stopped:
    """What stopping the nodes found: the nodes a later signal than SIGINT ended, a ``stop_last`` node's problem."""

    forced: dict[str, str] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)


def stop(nodes: Sequence[Running], waits_s: tuple[float, float, float], last_wait_s: float, prefix: str) -> Stopped:
    """Stop every node: SIGINT, then SIGTERM, then SIGKILL, each with a bounded wait; the ``stop_last`` nodes
    after the others, their first wait ``last_wait_s``.

    At the accelerated rate the recorder can trail the graph by a large share of the run: every raw sample is
    already in its subscriptions (reliable, acknowledged to the simulator), and on SIGINT it writes them all
    before it closes the bag. So it is stopped after the others, given the CPU they used, and waited for with
    its own bound; killing it on the nodes' 10 s would lose that backlog. Any exception while stopping (a
    second Ctrl-C) kills what is left at once."""
    out = Stopped()
    try:
        _escalate([n for n in nodes if not n.spec.stop_last], waits_s, out.forced)
        for node in (n for n in nodes if n.spec.stop_last):
            if not node.ended():
                print(f"{prefix}: waiting for the {node.name} to write what it has received", file=sys.stderr)
            _escalate([node], (last_wait_s, *waits_s[1:]), out.forced)
            if node.name in out.forced:
                out.problems.append(f"the {node.name} did not finish writing within {last_wait_s:g} s and was "
                                    f"ended by {out.forced[node.name]}; see {node.log}")
            elif node.returncode:
                out.problems.append(failure_message(node.name, node.returncode, node.log))
    except BaseException:
        kill_all(nodes)
        raise
    return out
