"""Sets the ground's parameters in Yamcs from a thread of its own, at most once per period: a node hands it
the latest values and never waits on Yamcs (a slow or dead Yamcs costs the node nothing).

Only the latest value of each parameter is kept between pushes (a display shows the latest; Yamcs
archives what it is given, about once a second); :meth:`close` pushes what is left, so the final
estimates reach Yamcs.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping

__all__ = ["ParameterWriter"]


class ParameterWriter:
    """Latest values, pushed by ``push(values)`` (e.g. :func:`~.yamcs_api.set_parameters` bound to an
    address) every ``period_s`` of wall time while there is something new."""

    def __init__(self, push: Callable[[dict[str, float]], None], period_s: float = 1.0) -> None:
        self._push = push
        self._period_s = float(period_s)
        self._pending: dict[str, float] = {}
        self._lock = threading.Condition()
        self._closed = False
        self.pushes = 0
        self.failures = 0
        self.last_error = ""
        self._thread = threading.Thread(target=self._run, name="yamcs-parameters", daemon=True)
        self._thread.start()

    def update(self, values: Mapping[str, float]) -> None:
        """Keep ``values`` for the next push (returns at once)."""
        with self._lock:
            self._pending.update(values)

    def close(self, timeout_s: float = 10.0) -> None:
        """Push what is left and stop."""
        with self._lock:
            self._closed = True
            self._lock.notify()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._lock:
                if not self._closed:
                    self._lock.wait(self._period_s)
                values, self._pending = self._pending, {}
                closed = self._closed
            if values:
                try:
                    self._push(values)
                    self.pushes += 1
                except Exception as exc:  # a refused or unanswered push: counted and said, never raised here
                    self.failures += 1
                    self.last_error = str(exc)
                    with self._lock:  # newer values win; the others are tried again
                        self._pending = {**values, **self._pending}
            if closed:
                return
