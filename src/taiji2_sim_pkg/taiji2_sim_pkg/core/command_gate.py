"""Validation of incoming torque commands before they reach the dynamics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike


@dataclass
class CommandGate:
    """Accepts finite torques within what the thrusters can make; remembers the last valid one.

    Parameters
    ----------
    max_torque_n_m : float
        Largest torque per axis the thrusters can deliver, max thrust x lever arm [N m].
    frame_id : str
        Required ``header.frame_id`` of a command ("" accepts any).
    """

    max_torque_n_m: float
    frame_id: str = "crf"
    torque_n_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accepted: int = 0
    rejected: dict[str, int] = field(default_factory=dict)

    def offer(self, torque_n_m: ArrayLike, frame_id: str) -> str | None:
        """Take a command; returns None if accepted, else why it was rejected (and counts it by kind)."""
        torque = np.asarray(torque_n_m, dtype=np.float64).reshape(-1)
        kind, reason = None, None
        if torque.shape != (3,):
            kind, reason = "shape", "torque is not a 3-vector"
        elif not np.all(np.isfinite(torque)):
            kind, reason = "non_finite", "torque is NaN or Inf"
        elif np.any(np.abs(torque) > self.max_torque_n_m):
            kind, reason = "too_large", (f"torque {np.abs(torque).max():.3g} N m exceeds what the thrusters "
                                         f"can deliver ({self.max_torque_n_m:.3g} N m)")
        elif self.frame_id and frame_id != self.frame_id:
            kind, reason = "frame_id", f"frame_id {frame_id!r} is not {self.frame_id!r}"
        if kind is not None:
            self.rejected[kind] = self.rejected.get(kind, 0) + 1
            return reason
        self.torque_n_m = torque
        self.accepted += 1
        return None

    @property
    def rejected_total(self) -> int:
        """Commands rejected so far."""
        return sum(self.rejected.values())


@dataclass
class CommandSchedule:
    """Time-tagged torque commands: the command in effect at t is the latest one stamped <= t.

    Commands arrive in stamp order (one commander, reliable transport); one stamped at or after t
    proves every command up to t has arrived, so the interval starting at t can be simulated.
    """

    torque_n_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    latest_stamp_ns: int = -1
    out_of_order: int = 0
    _pending: list[tuple[int, np.ndarray]] = field(default_factory=list)

    def offer(self, stamp_ns: int, torque_n_m: np.ndarray) -> bool:
        """Queue a command; False (and counted) if it is stamped before one already received."""
        if stamp_ns < self.latest_stamp_ns:
            self.out_of_order += 1
            return False
        self._pending.append((int(stamp_ns), np.asarray(torque_n_m, dtype=np.float64)))
        self.latest_stamp_ns = int(stamp_ns)
        return True

    def covers(self, t_ns: int) -> bool:
        """Has a command stamped >= t arrived (so the command in effect at t is known)?"""
        return self.latest_stamp_ns >= t_ns

    def covered_steps(self, t_ns: int, dt_ns: int) -> int:
        """How many consecutive steps from t on have their command known (0 if t is not covered)."""
        return 0 if self.latest_stamp_ns < t_ns else (self.latest_stamp_ns - t_ns) // dt_ns + 1

    def command_at(self, t_ns: int) -> np.ndarray:
        """The command in effect at t (the last one if none is stamped <= t yet)."""
        index = 0
        while index < len(self._pending) and self._pending[index][0] <= t_ns:
            self.torque_n_m = self._pending[index][1]
            index += 1
        del self._pending[:index]
        return self.torque_n_m
