"""The information a per-epoch pre-fit gate solves: one snapshot per span of data time.

The gate of an epoch tests ``e^T (Lambda + S Cov S^T)^-1 e`` with ``e = e0 - S theta``. Any estimate
``(theta, Cov)`` from data before the epoch makes the same chi-square test: the epoch's innovation is
independent of those data, and ``Cov`` is that estimate's own covariance. Solving the information at
every epoch (10 Hz) cost a fifth of the c.m.-offset estimator's per-epoch time, so its gate solves the
information as it stood at the first epoch of each span of ``gate_refresh_s`` of data: once per span
(and per scale factors G in use), from data at most one span older than the epoch tested.

Both estimators gate this way: the c.m.-offset estimator solves its snapshot per scale factors G, the
scale-factor estimator (whose gates test the star-tracker innovation and the GRS pair's difference) once.

Spans are fixed by the epochs' grid indices, never by arrival, so a run gates the same whatever its
delivery timing; the snapshot is part of the checkpoint, so a resumed run gates as an uninterrupted one.
A new filter segment (a restarted source) takes a new snapshot at once: an estimate of the old
segment's initial state says nothing about the new one's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class GateSpan:
    """The snapshot of the current span and the gate estimate solved from it.

    Attributes
    ----------
    span_epochs : int
        Epochs per span (1: a snapshot at every epoch).
    span : int or None
        Index of the current span (grid index // span_epochs); None before the first epoch.
    segment : int
        Filter segment of the snapshot.
    information : numpy.ndarray or None
        The information the gate solves in this span (None: no data before the span).
    solved : tuple or None
        ``(G as bytes, estimate)`` for the last G asked for in this span (an estimator without outside
        parameters keys it by ``b""``).
    determined : bool
        Whether the estimator had declared its estimate determined when the snapshot was taken (for an
        estimator whose gate waits for that; the data after the snapshot must not decide it).
    """

    span_epochs: int
    span: int | None = None
    segment: int = 0
    information: np.ndarray | None = None
    solved: tuple[bytes, Any] | None = None
    determined: bool = False

    def __post_init__(self) -> None:
        if self.span_epochs < 1:
            raise ValueError(f"gate span: need at least 1 epoch, got {self.span_epochs}")

    def starts(self, index: int, segment: int) -> bool:
        """Whether the epoch at grid ``index`` of filter ``segment`` needs a new snapshot (a new span or
        segment); if so, the span moves there and the caller stores the snapshot with :meth:`take`."""
        span = index // self.span_epochs
        if span == self.span and segment == self.segment:
            return False
        self.span, self.segment = span, segment
        return True

    def take(self, information: np.ndarray | None, determined: bool = False) -> None:
        """Store the span's snapshot (None: nothing to solve yet) and whether it was determined; forgets
        what was solved before."""
        self.information = information
        self.determined = bool(determined)
        self.solved = None

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint (plain lists/numbers)."""
        return {"span": self.span, "segment": self.segment, "determined": self.determined,
                "information": None if self.information is None else self.information.tolist()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a :meth:`state_dict` checkpoint."""
        self.span, self.segment = state["span"], int(state["segment"])
        info = state["information"]
        self.take(None if info is None else np.asarray(info, dtype=np.float64), bool(state.get("determined", False)))
