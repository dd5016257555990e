"""Flow control of the accelerated simulator by its reliable subscribers' acknowledgements.

An accelerated run publishes far faster than real time, and DDS buffers hundreds of kB of
unacknowledged samples per writer before a write blocks. A killed subscriber's reader stays matched
until its participant's lease expires (10 s by default), so without flow control the run races ahead
of it by minutes of simulated data, which a restarted estimator then never receives. Here the run
waits, every ``window_s`` of simulated time, until every matched reliable reader has acknowledged
everything published: a dead reader holds the run until DDS removes it (the simulator's
resubscribe hold then waits for the restarted node), a slow one paces it. A reader that stays alive
but never acknowledges is given up after ``timeout_s`` of wall time, so nothing can hold the run
forever. Best-effort readers (plotting tools) never take part.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from taiji2_runtime.ros import rclpy

#: One blocking wait for acknowledgements inside a timer callback [s]: a few round trips of a local
#: peer, short enough to keep the executor responsive to commands.
_WAIT_PER_CALL_S = 0.02


class AckWindow:
    """Gate the accelerated run on acknowledgements every ``window_ns`` of simulated time.

    Parameters
    ----------
    publishers : sequence of rclpy publishers
        The reliable raw-data writers whose readers must keep up.
    window_ns : int
        Simulated time between acknowledgement checks [ns]; 0 disables the gate.
    timeout_s : float
        Wall time after which a reader that does not acknowledge is given up for [s].
    """

    def __init__(self, publishers: Sequence[Any], window_ns: int, timeout_s: float) -> None:
        self._publishers = list(publishers)
        self._window_ns = int(window_ns)
        #: see the class docstring [s]
        self.timeout_s = float(timeout_s)
        self._next_check_ns = self._window_ns
        self._waiting_since: float | None = None
        #: wall time the run waited for acknowledgements, in total [s]
        self.held_s = 0.0
        #: checks given up after ``timeout_s`` (a live reader that did not acknowledge)
        self.given_up = 0

    def open(self, t_ns: int) -> bool:
        """True when the run may step on from simulated time ``t_ns`` [ns]."""
        if self._window_ns <= 0 or t_ns < self._next_check_ns:
            return True
        wait = rclpy.duration.Duration(nanoseconds=int(_WAIT_PER_CALL_S * 1e9))
        acked = all(p.wait_for_all_acked(wait) for p in self._publishers)
        now = time.monotonic()
        since = now if self._waiting_since is None else self._waiting_since
        if not acked and now - since <= self.timeout_s:
            self._waiting_since = since
            return False
        if not acked:
            self.given_up += 1
        self.held_s += now - since
        self._waiting_since = None
        self._next_check_ns = t_ns + self._window_ns
        return True
