"""Raw-data input of the diagnosis: one regular sample grid, validated, with counted rejections.

The diagnosis works on plain arrays that follow the raw-data contract (``interfaces.md``): star-
tracker attitude, the six electrode voltages of both GRS and the commanded torque, on the 10 Hz
sample grid. :func:`align_streams` builds that grid from separately stamped streams (as a bag
gives them); :func:`prepare_input` checks arrays that are already on one grid. Bad samples are
dropped and counted by reason; the diagnosis then uses the longest gap-free run (its equations
difference consecutive samples), and reports how many samples that left out.

Reasons: ``nan_or_inf``, ``non_unit_quaternion``, ``duplicate_stamp``, ``out_of_order_stamp``,
``off_grid_stamp``, ``unmatched`` (a stamp present in one sensor stream only), ``outside_run``
(valid samples outside the longest gap-free run).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["DiagnosisInput", "InputError", "align_streams", "commands_on_grid", "prepare_input"]

_QUAT_NORM_TOL = 1e-6  # accepted | |q| - 1 | (renormalised inside)
_GRID_TOL = 0.25  # accepted stamp deviation from the grid, fraction of 1/fs


class InputError(ValueError):
    """Input that cannot be diagnosed (malformed arrays); the message is one line."""


@dataclass(frozen=True)
class DiagnosisInput:
    """Raw telemetry of one experiment on a regular grid.

    Attributes
    ----------
    t_s : numpy.ndarray
        (n,) sample times t_j = t_0 + j / fs [s].
    st_quat_xyzw : numpy.ndarray
        (n, 4) star-tracker attitude at t_j (orientation of the CRF in the inertial frame).
    voltages_v : numpy.ndarray
        (n, 2, 6) GRS1, GRS2 electrode voltages vx1, vx2, vy1, vy2, vz1, vz2 of the step ending
        at t_j [V].
    torque_cmd_n_m : numpy.ndarray
        (n, 3) commanded torque held over (t_j - 1/fs, t_j], CRF [N m].
    sample_rate_hz : float
        fs [Hz].
    rejected : dict of str to int
        Samples dropped, by reason.
    stamp_phase_s : dict of str to float
        Constant sub-step phase of the GRS and command stamps against the star-tracker grid [s],
        removed when the streams were put on the grid (:func:`align_streams`); a timing convention
        the diagnosis adds to its nominal model.
    """

    t_s: np.ndarray
    st_quat_xyzw: np.ndarray
    voltages_v: np.ndarray
    torque_cmd_n_m: np.ndarray
    sample_rate_hz: float
    rejected: dict[str, int] = field(default_factory=dict)
    stamp_phase_s: dict[str, float] = field(default_factory=lambda: {"grs": 0.0, "command": 0.0})

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t_s.shape[0])

    @property
    def dt_s(self) -> float:
        """Sample interval [s]."""
        return 1.0 / self.sample_rate_hz

    @property
    def duration_s(self) -> float:
        """n / fs [s]."""
        return self.n / self.sample_rate_hz

    def slice(self, start: int, stop: int) -> DiagnosisInput:
        """Samples ``start:stop`` (same rejection counts)."""
        window = slice(start, stop)
        return DiagnosisInput(self.t_s[window], self.st_quat_xyzw[window], self.voltages_v[window],
                              self.torque_cmd_n_m[window], self.sample_rate_hz, dict(self.rejected))


def _array(name: str, value: ArrayLike, shape_tail: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: not a numeric array") from None
    if array.ndim != 1 + len(shape_tail) or array.shape[1:] != shape_tail:
        expected = "(n" + "".join(f", {s}" for s in shape_tail) + ")"
        raise InputError(f"{name}: wrong shape {array.shape}, expected {expected}")
    return array


def _longest_run(valid: np.ndarray) -> tuple[int, int]:
    """[start, stop) of the longest run of True."""
    if not np.any(valid):
        return 0, 0
    padded = np.concatenate(([False], valid, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    starts, stops = edges[0::2], edges[1::2]
    best = int(np.argmax(stops - starts))
    return int(starts[best]), int(stops[best])


def _finish(t: np.ndarray, q: np.ndarray, v: np.ndarray, tau: np.ndarray, valid: np.ndarray, fs: float,
            counts: Counter, stamp_phase_s: dict[str, float] | None = None) -> DiagnosisInput:
    start, stop = _longest_run(valid)
    outside = int(np.count_nonzero(valid)) - (stop - start)
    if outside:
        counts["outside_run"] += outside
    q = q[start:stop].copy()
    if q.shape[0]:
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        # q and -q are the same attitude: keep one hemisphere along the run
        flips = np.sum(q[1:] * q[:-1], axis=1) < 0.0
        sign = np.concatenate(([1.0], np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)))
        q *= sign[:, None]
    return DiagnosisInput(t[start:stop].copy(), q, v[start:stop].copy(), tau[start:stop].copy(), fs,
                          {key: int(value) for key, value in counts.items() if value},
                          dict(stamp_phase_s or {"grs": 0.0, "command": 0.0}))


def prepare_input(t_s: ArrayLike, st_quat_xyzw: ArrayLike, voltages_v: ArrayLike, torque_cmd_n_m: ArrayLike,
                  sample_rate_hz: float = 10.0) -> DiagnosisInput:
    """Validate arrays already on one sample grid.

    Parameters
    ----------
    t_s : array_like
        (n,) sample times [s], increasing by 1/fs.
    st_quat_xyzw : array_like
        (n, 4) star-tracker quaternions.
    voltages_v : array_like
        (n, 2, 6) electrode voltages of GRS1 and GRS2 [V].
    torque_cmd_n_m : array_like
        (n, 3) command held over the step ending at each sample [N m].
    sample_rate_hz : float
        fs [Hz].

    Returns
    -------
    DiagnosisInput
        The longest gap-free run of valid samples; rejections counted.

    Raises
    ------
    InputError
        Wrong shapes or lengths, non-positive rate.
    """
    if not (isinstance(sample_rate_hz, int | float) and np.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise InputError(f"sample_rate_hz: must be a positive number, got {sample_rate_hz!r}")
    fs = float(sample_rate_hz)
    t = _array("t_s", t_s, ())
    q = _array("st_quat_xyzw", st_quat_xyzw, (4,))
    v = _array("voltages_v", voltages_v, (2, 6))
    tau = _array("torque_cmd_n_m", torque_cmd_n_m, (3,))
    n = t.shape[0]
    for name, array in (("st_quat_xyzw", q), ("voltages_v", v), ("torque_cmd_n_m", tau)):
        if array.shape[0] != n:
            raise InputError(f"{name}: {array.shape[0]} samples, but t_s has {n}")
    counts: Counter = Counter()
    finite = (np.isfinite(t) & np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(v), axis=(1, 2))
              & np.all(np.isfinite(tau), axis=1))
    counts["nan_or_inf"] += int(np.count_nonzero(~finite))
    norm = np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1)
    unit = np.abs(norm - 1.0) <= _QUAT_NORM_TOL
    counts["non_unit_quaternion"] += int(np.count_nonzero(finite & ~unit))
    valid = finite & unit
    # the grid: t_0 + j dt; a sample off the grid, or out of order, breaks the run
    dt = 1.0 / fs
    if np.any(valid):
        t0 = t[np.flatnonzero(valid)[0]]
        position = (t - t0) / dt
        index = np.rint(position)
        off = valid & (np.abs(position - index) > _GRID_TOL)
        counts["off_grid_stamp"] += int(np.count_nonzero(off))
        valid &= ~off
        previous = -np.inf
        order = np.ones(n, dtype=bool)
        for j in np.flatnonzero(valid):  # sequential: duplicates and disorder relative to the last kept
            if index[j] == previous:
                counts["duplicate_stamp"] += 1
                order[j] = False
            elif index[j] < previous:
                counts["out_of_order_stamp"] += 1
                order[j] = False
            else:
                previous = index[j]
        valid &= order
        # consecutive kept samples must be one step apart, else the run is cut there
        kept = np.flatnonzero(valid)
        if kept.size:
            step = np.diff(index[kept])
            breaks = np.flatnonzero(step != 1.0)
            contiguous = np.zeros(n, dtype=bool)
            segments = np.split(kept, breaks + 1)
            best = max(segments, key=len)
            contiguous[best] = True
            outside = int(np.count_nonzero(valid & ~contiguous))
            if outside:
                counts["outside_run"] += outside
            valid = contiguous
    return _finish(t, q, v, tau, valid, fs, counts)


def commands_on_grid(command_t_s: ArrayLike, command_torque_n_m: ArrayLike, sample_t_s: ArrayLike,
                     sample_rate_hz: float) -> np.ndarray:
    """Zero-order hold of a command stream onto the steps ending at the sample times.

    The step ending at t_j starts at ``t_j - 1/fs``; the command in force over it is the last one
    stamped at or before that start, within the grid tolerance of a quarter step (sensor stamps
    jitter by that much). Before the first command: zero.

    Parameters
    ----------
    command_t_s : array_like
        (m,) command stamps [s], increasing.
    command_torque_n_m : array_like
        (m, 3) commanded torque [N m].
    sample_t_s : array_like
        (n,) sample times [s].
    sample_rate_hz : float
        fs [Hz].

    Returns
    -------
    numpy.ndarray
        (n, 3) [N m].
    """
    stamps = _array("command_t_s", command_t_s, ())
    torque = _array("command_torque_n_m", command_torque_n_m, (3,))
    if stamps.shape[0] != torque.shape[0]:
        raise InputError(f"command_torque_n_m: {torque.shape[0]} commands, but command_t_s has {stamps.shape[0]}")
    good = np.isfinite(stamps) & np.all(np.isfinite(torque), axis=1)
    stamps, torque = stamps[good], torque[good]
    order = np.argsort(stamps, kind="stable")
    stamps, torque = stamps[order], torque[order]
    starts = np.asarray(sample_t_s, dtype=np.float64) - 1.0 / sample_rate_hz
    index = np.searchsorted(stamps, starts + _GRID_TOL / sample_rate_hz, side="right") - 1
    out = np.zeros((starts.shape[0], 3))
    known = index >= 0
    out[known] = torque[index[known]]
    return out


def align_streams(st_t_s: ArrayLike, st_quat_xyzw: ArrayLike, grs1_t_s: ArrayLike, grs1_voltages_v: ArrayLike,
                  grs2_t_s: ArrayLike, grs2_voltages_v: ArrayLike, command_t_s: ArrayLike,
                  command_torque_n_m: ArrayLike, sample_rate_hz: float = 10.0) -> DiagnosisInput:
    """Put separately stamped streams on one grid (what a bag gives).

    The grid is that of the star tracker (t_0 its first valid stamp). The GRS and command streams
    may be stamped at a constant sub-step phase against it (their own timing convention): each
    stream's phase (the median of its stamps' offsets from the grid) is removed before a sample is
    put on the grid point within a quarter step of its stamp, and reported in
    ``stamp_phase_s`` (the GRS phase as the mean of the two). Grid points lacking any sensor are gaps.

    Parameters
    ----------
    st_t_s, st_quat_xyzw : array_like
        (a,) stamps [s] and (a, 4) quaternions.
    grs1_t_s, grs1_voltages_v, grs2_t_s, grs2_voltages_v : array_like
        (b,) stamps and (b, 6) voltages of each GRS [V].
    command_t_s, command_torque_n_m : array_like
        (m,) stamps and (m, 3) commanded torques [N m] (held until the next command).
    sample_rate_hz : float
        fs [Hz].

    Returns
    -------
    DiagnosisInput

    Raises
    ------
    InputError
        Malformed arrays, or a stream without a single valid sample.
    """
    fs = float(sample_rate_hz)
    dt = 1.0 / fs
    counts: Counter = Counter()

    def clean(name: str, t_raw: ArrayLike, x_raw: ArrayLike, tail: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        t = _array(f"{name} stamps", t_raw, ())
        x = _array(name, x_raw, tail)
        if x.shape[0] != t.shape[0]:
            raise InputError(f"{name}: {x.shape[0]} samples but {t.shape[0]} stamps")
        good = np.isfinite(t) & np.all(np.isfinite(x.reshape(x.shape[0], -1)), axis=1)
        counts["nan_or_inf"] += int(np.count_nonzero(~good))
        if tail == (4,):
            unit = np.abs(np.linalg.norm(np.where(good[:, None], x, 0.0), axis=1) - 1.0) <= _QUAT_NORM_TOL
            counts["non_unit_quaternion"] += int(np.count_nonzero(good & ~unit))
            good &= unit
        t, x = t[good], x[good]
        if t.size == 0:
            raise InputError(f"{name}: no valid sample")
        return t, x

    st_t, st_q = clean("star tracker", st_t_s, st_quat_xyzw, (4,))
    g1_t, g1_v = clean("grs1", grs1_t_s, grs1_voltages_v, (6,))
    g2_t, g2_v = clean("grs2", grs2_t_s, grs2_voltages_v, (6,))
    t0 = float(st_t[0])
    last = max(float(st_t.max()), float(g1_t.max()), float(g2_t.max()))
    n = int(np.floor((last - t0) / dt + _GRID_TOL)) + 1

    def phase(t: np.ndarray) -> float:
        """Median offset of the stamps from the grid, in steps, in [-0.5, 0.5)."""
        offset = (t - t0) / dt
        return float(np.median((offset - np.rint(offset) + 0.5) % 1.0 - 0.5)) if t.size else 0.0

    phase_g1, phase_g2 = phase(g1_t), phase(g2_t)
    g1_t, g2_t = g1_t - phase_g1 * dt, g2_t - phase_g2 * dt

    def place(name: str, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        position = (t - t0) / dt
        index = np.rint(position).astype(np.int64)
        on_grid = (np.abs(position - index) <= _GRID_TOL) & (index >= 0) & (index < n)
        counts["off_grid_stamp"] += int(np.count_nonzero(~on_grid))
        filled = np.zeros(n, dtype=bool)
        out = np.zeros((n, *x.shape[1:]))
        previous = -1
        for j in np.flatnonzero(on_grid):  # stream order: duplicates and disorder are rejected
            k = index[j]
            if k == previous or filled[k]:
                counts["duplicate_stamp" if k == previous else "out_of_order_stamp"] += 1
                continue
            if k < previous:
                counts["out_of_order_stamp"] += 1
                continue
            filled[k] = True
            out[k] = x[j]
            previous = k
        return filled, out

    st_ok, q = place("star tracker", st_t, st_q)
    g1_ok, v1 = place("grs1", g1_t, g1_v)
    g2_ok, v2 = place("grs2", g2_t, g2_v)
    present = st_ok | g1_ok | g2_ok
    valid = st_ok & g1_ok & g2_ok
    counts["unmatched"] += int(np.count_nonzero(present & ~valid))
    grid = t0 + dt * np.arange(n)
    command_t = np.asarray(command_t_s, dtype=np.float64)
    finite = command_t[np.isfinite(command_t)]
    phase_c = phase(finite)
    tau = commands_on_grid(command_t - phase_c * dt, command_torque_n_m, grid, fs)
    voltages = np.stack((v1, v2), axis=1)
    return _finish(grid, q, voltages, tau, valid, fs, counts,
                   {"grs": 0.5 * (phase_g1 + phase_g2) * dt, "command": phase_c * dt})
