"""Raw-data input of the diagnosis: the streams on their epochs, validated, with counted rejections.

The diagnosis works on plain arrays that follow the raw-data contract (``interfaces.md``): star-
tracker attitude, the six electrode voltages of both GRS and the commanded torque, on the 10 Hz
sample grid. :func:`align_streams` (separately stamped streams, as a bag gives them) and
:func:`prepare_input` (arrays already on one grid, e.g. an ``.npz``) both assign the samples to epochs
by the one rule of :mod:`taiji2_estimator_pkg.epochs` (the same as ``taiji2 calibrate`` and the
estimator nodes: GRS instants, each stream at its own constant offset, counted reasons).

Gaps. The diagnosis's channels difference consecutive samples and its fits are spectral (one
contiguous grid), so a gap cannot simply be left empty. A gap of a stream of at most
:data:`MAX_BRIDGE_SAMPLES` samples (5 s at 10 Hz: lost packets and their bursts) with samples on both
sides is *bridged* (:func:`_bridge_all`), counted per stream in ``bridged``, and used: the attitude
along the rotation between its neighbours (over 5 s at most ``|omega_dot| T^2 / 8 = 5e-9 x 25 / 8 =
1.6e-8 rad`` from the true attitude with the nominal maneuvers, 1/60 of the star tracker's noise); a
GRS from the other GRS where it has the sample, else from the command's step and its neighbours. A
bridged sample carries no noise of its own, so the diagnosis's noise estimates are slightly low where
many are bridged (its report gives ``inputs.bridged``). A longer gap ends a segment; the diagnosis
uses the longest segment and counts the valid samples outside it as ``outside_run``. The epochs that
hold an estimate (a bridged sample in any stream, or a command lost at a change and placed within a
GRS gap: :func:`_locate_lost_changes`) are marked (``DiagnosisInput.filled``): the location scan treats
them as missing (:mod:`.locations`); the fits use them.

Reasons: those of the epoch rule (``duplicate_stamp``, ``off_grid_stamp``, ``before_start``,
``duplicate_epoch``; a bulk read sorts each stream, so no ``out_of_order_stamp``), ``nan_or_inf``,
``non_unit_quaternion``, ``unmatched`` (an epoch of the segment edges held by some streams only),
``outside_run`` (valid epochs outside the longest segment), summed over the streams.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.attitude import quat_conjugate, quat_multiply, rotvec_from_quat
from taiji2_estimator_pkg.diagnosis.angular_gaps import angular_gap_weight, runs
from taiji2_estimator_pkg.epochs import GRID_TOLERANCE, UndeterminedError, circular_offset, grid_streams

__all__ = ["MAX_BRIDGE_SAMPLES", "DiagnosisInput", "InputError", "align_streams", "commands_on_grid",
           "prepare_input"]

_QUAT_NORM_TOL = 1e-6  # accepted | |q| - 1 | (renormalised inside)
_GRID_TOL = GRID_TOLERANCE  # accepted stamp deviation from the grid, fraction of 1/fs (the epoch rule's)
#: longest gap of a stream bridged [samples] (5 s at 10 Hz)
MAX_BRIDGE_SAMPLES = 50
_STREAMS = ("star_tracker", "grs1", "grs2")


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
        Constant sub-step phase of the GRS and command stamps against the star-tracker instants
        ``t_s`` [s] (the epoch rule keeps each stream's own offset; :func:`align_streams`); a timing
        convention the diagnosis adds to its nominal model.
    bridged : dict of str to int
        Per stream: samples interpolated across gaps of at most :data:`MAX_BRIDGE_SAMPLES`.
    filled : numpy.ndarray or None
        (n,) True on the epochs that hold an estimate, not a received value, in some stream: a bridged
        sample, or a command lost where it changed (:func:`_locate_lost_changes`). The fits use them
        (one contiguous grid); the location scan treats them as missing (:mod:`.locations`). None: none.
    angular_gap_weight : numpy.ndarray or None
        (n,) the angular acceleration that neither GRS measured, per epoch, in units of one epoch's white
        noise (:func:`.angular_gaps.angular_gap_weight`); the noise model adds its mean
        (:class:`.spectral.NoiseSpectrum`). None: every bridged epoch had a GRS sample.
    command_doubt : numpy.ndarray or None
        (c, 5) per command change lost inside a gap of the GRS and placed in its middle
        (:func:`_locate_lost_changes`): epoch, torque step x, y, z [N m], variance of its placement
        [epochs^2]; the noise model adds what the misplacement leaves (:mod:`.angular_gaps`). None: none.
    """

    t_s: np.ndarray
    st_quat_xyzw: np.ndarray
    voltages_v: np.ndarray
    torque_cmd_n_m: np.ndarray
    sample_rate_hz: float
    rejected: dict[str, int] = field(default_factory=dict)
    stamp_phase_s: dict[str, float] = field(default_factory=lambda: {"grs": 0.0, "command": 0.0})
    bridged: dict[str, int] = field(default_factory=dict)
    filled: np.ndarray | None = None
    angular_gap_weight: np.ndarray | None = None
    command_doubt: np.ndarray | None = None

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
                              self.torque_cmd_n_m[window], self.sample_rate_hz, dict(self.rejected),
                              dict(self.stamp_phase_s), dict(self.bridged),
                              None if self.filled is None else self.filled[window].copy(),
                              None if self.angular_gap_weight is None else self.angular_gap_weight[window].copy(),
                              _doubt_window(self.command_doubt, start, stop, self.n))

    @property
    def angular_loss(self) -> tuple[float, np.ndarray]:
        """What the bridged gaps leave of the angular acceleration, per epoch (:mod:`.angular_gaps`): the mean
        of :attr:`angular_gap_weight` (units of the torque channel's white noise) and the mean torque
        covariance of the misplaced command changes, ``sum var s s^T / n`` (3, 3) [N^2 m^2]."""
        weight = 0.0 if self.angular_gap_weight is None or self.n == 0 else float(np.mean(self.angular_gap_weight))
        torque = np.zeros((3, 3))
        if self.command_doubt is not None and self.n:
            steps, variance = self.command_doubt[:, 1:4], self.command_doubt[:, 4]
            torque = np.einsum("c,ci,cj->ij", variance, steps, steps) / self.n
        return weight, torque


def _doubt_window(doubt: np.ndarray | None, start: int | None, stop: int | None, n: int) -> np.ndarray | None:
    """The rows of :attr:`DiagnosisInput.command_doubt` within epochs ``start:stop``, epochs renumbered."""
    if doubt is None:
        return None
    first, last, _ = slice(start, stop).indices(n)
    inside = (doubt[:, 0] >= first) & (doubt[:, 0] < last)
    if not np.any(inside):
        return None
    out = doubt[inside].copy()
    out[:, 0] -= first
    return out


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


def _rotvec_to_quat(rotvec: np.ndarray) -> np.ndarray:
    """(..., 4) xyzw unit quaternions of (..., 3) rotation vectors [rad]."""
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * angle
    scale = np.where(angle > 0.0, np.sin(half) / np.where(angle > 0.0, angle, 1.0), 0.5)
    return np.concatenate((rotvec * scale, np.cos(half)), axis=-1)


def _command_response(values: np.ndarray, present: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """(3, k) least-squares response of the rows to the commanded torque, from consecutive present pairs.

    ``values[j] - values[j-1] = (torque[j] - torque[j-1]) @ B``: the steps of the maneuver, fitted on
    differences so that slow drifts do not enter. Zero when the torque never changes.
    """
    pair = present[1:] & present[:-1]
    d_torque = np.diff(torque, axis=0)[pair]
    d_values = np.diff(values, axis=0)[pair]
    moving = np.any(d_torque != 0.0, axis=1)
    if not np.any(moving):
        return np.zeros((3, values.shape[1]))
    response, *_ = np.linalg.lstsq(d_torque[moving], d_values[moving], rcond=None)
    return response


def _bridge(values: np.ndarray, present: np.ndarray, quaternion: bool, torque: np.ndarray | None = None) -> int:
    """Interpolate, in place, gaps of at most MAX_BRIDGE_SAMPLES rows between present rows; returns rows filled.

    Quaternions: along the rotation from the sample before to the sample after (``q_a exp(s log(q_a^* q_b))``).
    Other rows (GRS voltages): the part the commanded ``torque`` explains (:func:`_command_response`, so that a
    maneuver step inside a gap stays a step) plus the rest interpolated linearly. ``present`` is updated.
    """
    if torque is not None and not quaternion:
        response = _command_response(values, present, torque)
        explained = torque @ response
        rest = values - explained
        before = present.copy()
        filled = _bridge(rest, present, quaternion=False)
        new = present & ~before
        values[new] = rest[new] + explained[new]  # the samples received stay bit for bit
        return filled
    starts, stops = runs(~present)  # [start, stop) of the runs of missing rows
    filled = 0
    for start, stop in zip(starts, stops, strict=True):
        if start == 0 or stop == present.size or stop - start > MAX_BRIDGE_SAMPLES:
            continue
        a, b = values[start - 1], values[stop]
        s = (np.arange(start, stop) - (start - 1)) / (stop - (start - 1))
        if quaternion:
            rotation = rotvec_from_quat(quat_multiply(quat_conjugate(a), b))
            values[start:stop] = quat_multiply(a[None], _rotvec_to_quat(s[:, None] * rotation[None]))
        else:
            values[start:stop] = a + s.reshape(-1, *([1] * a.ndim)) * (b - a)
        present[start:stop] = True
        filled += stop - start
    return filled


def _phase_steps(t_s: np.ndarray, t0_s: float, dt: float) -> float:
    """Circular median offset of stamps from the grid t0 + j dt, in steps, in [-0.5, 0.5)."""
    if not t_s.size:
        return 0.0
    offsets = np.rint((t_s - t0_s) * 1e9).astype(np.int64)
    return circular_offset(offsets, round(dt * 1e9)) / (dt * 1e9)


def _on_epochs(streams: dict[str, tuple[np.ndarray, np.ndarray]], fs: float, counts: Counter
               ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray], float]:
    """The epoch rule on the three streams; returns (star-tracker instants [s], values and presence on the
    epochs per stream, GRS phase against the star tracker [s])."""
    gridded = grid_streams({name: (np.rint(t * 1e9).astype(np.int64), x) for name, (t, x) in streams.items()},
                           1.0 / fs)
    for name in _STREAMS:
        refused = gridded.refused.get(name, {})
        for reason, n in refused.items():
            counts[reason] += n
        if gridded.n == 0 or not gridded.index[name].size:
            why = ("every sample refused (" + ", ".join(f"{r} {n}" for r, n in refused.items()) + ")"
                   if refused else "no valid sample")
            raise UndeterminedError(name, why)
    values = {name: gridded.on_grid(name, fill=0.0) for name in _STREAMS}
    present = {name: gridded.present(name) for name in _STREAMS}
    # the diagnosis's grid is the star tracker's instants: the GRS are stamped -offset against it
    grid = (gridded.t_ns + gridded.slot_ns["star_tracker"]) / 1e9
    return grid, values, present, -gridded.offset_s("star_tracker")


def _bridge_all(values: dict[str, np.ndarray], present: dict[str, np.ndarray], torque: np.ndarray
                ) -> tuple[dict[str, int], np.ndarray]:
    """Bridge the short gaps of every stream in place; returns the samples filled per stream and the
    angular acceleration neither GRS measured (:func:`.angular_gaps.angular_gap_weight`).

    The star tracker along the rotation between its neighbours. The GRS: the spacecraft's common angular
    and linear acceleration (thruster noise, ~30 times a GRS's own noise) must cancel in the differences
    of the two GRS as it does in the data, which a fill from a sample's own neighbours would not give. So a
    GRS1 sample missing where GRS2 has one is taken from GRS2 through the least-squares linear map
    between the two GRS's voltages and the command (fitted on the epochs both hold) plus the interpolated
    rest (their own noise); where both are missing, GRS1 from the command's step and its neighbours
    (:func:`_bridge`) and GRS2 from that GRS1 through the map, so their difference is again the rest alone.
    """
    bridged = {}
    n = _bridge(values["star_tracker"], present["star_tracker"], quaternion=True)
    if n:
        bridged["star_tracker"] = int(n)
    received = {g: present[g].copy() for g in ("grs1", "grs2")}
    own = {}  # each GRS from the command's step and its neighbours: the fallback, and the map's regressors
    for g in received:
        own[g] = values[g].copy()
        own[g + "_present"] = received[g].copy()
        _bridge(own[g], own[g + "_present"], quaternion=False, torque=torque)
    weight = angular_gap_weight(received["grs1"], received["grs2"], own["grs1_present"])
    both = received["grs1"] & received["grs2"]
    for g, o, source in (("grs1", "grs2", received["grs2"]), ("grs2", "grs1", own["grs1_present"])):
        from_other = own[g + "_present"] & ~received[g] & source
        if np.count_nonzero(both) > 20 and np.any(from_other):
            regressors = np.column_stack((own[o], torque))
            pair = both[1:] & both[:-1]
            slope, *_ = np.linalg.lstsq(np.diff(regressors, axis=0)[pair], np.diff(values[g], axis=0)[pair],
                                        rcond=None)
            mapped = regressors @ slope
            # what the map leaves (the two GRS's own noise), known where both have a sample, interpolated between
            rest = np.where(both[:, None], values[g] - mapped, 0.0)
            rest_present = both.copy()
            _bridge(rest, rest_present, quaternion=False)
            from_other &= rest_present
            own[g][from_other] = (mapped + rest)[from_other]
    for g in received:
        values[g][:] = own[g]
        present[g][:] = own[g + "_present"]
        n = int(np.count_nonzero(present[g] & ~received[g]))
        if n:
            bridged[g] = n
    return bridged, weight


def _finish(grid: np.ndarray, values: dict[str, np.ndarray], present: dict[str, np.ndarray], tau: np.ndarray,
            fs: float, counts: Counter, bridged: dict[str, int], stamp_phase_s: dict[str, float],
            estimated: np.ndarray, weight: np.ndarray, doubt: np.ndarray | None = None) -> DiagnosisInput:
    """The longest segment of epochs holding every stream (after bridging); the rest counted. ``estimated``: (n,)
    epochs where some stream holds an estimate (bridged, or the command unknown), ``DiagnosisInput.filled``."""
    valid = present["star_tracker"] & present["grs1"] & present["grs2"]
    partial = (present["star_tracker"] | present["grs1"] | present["grs2"]) & ~valid
    counts["unmatched"] += int(np.count_nonzero(partial))
    start, stop = _longest_run(valid)
    outside = int(np.count_nonzero(valid)) - (stop - start)
    if outside:
        counts["outside_run"] += outside
    q = values["star_tracker"][start:stop].copy()
    if q.shape[0]:
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        # q and -q are the same attitude: keep one hemisphere along the run
        flips = np.sum(q[1:] * q[:-1], axis=1) < 0.0
        sign = np.concatenate(([1.0], np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)))
        q *= sign[:, None]
    voltages = np.stack((values["grs1"], values["grs2"]), axis=1)[start:stop].copy()
    filled = np.asarray(estimated, dtype=bool)[start:stop].copy()
    weight = weight[start:stop].copy()
    return DiagnosisInput(grid[start:stop].copy(), q, voltages, np.asarray(tau)[start:stop].copy(), fs,
                          {key: int(value) for key, value in counts.items() if value}, dict(stamp_phase_s),
                          dict(bridged), filled if np.any(filled) else None, weight if np.any(weight) else None,
                          _doubt_window(doubt, start, stop, grid.shape[0]))


def _valid_rows(name: str, t: np.ndarray, x: np.ndarray, counts: Counter) -> np.ndarray:
    """Rows with a finite stamp and finite values (and a unit quaternion), the others counted."""
    good = np.isfinite(t) & np.all(np.isfinite(x.reshape(x.shape[0], -1)), axis=1)
    counts["nan_or_inf"] += int(np.count_nonzero(~good))
    if x.shape[1:] == (4,):
        unit = np.abs(np.linalg.norm(np.where(good[:, None], x, 0.0), axis=1) - 1.0) <= _QUAT_NORM_TOL
        counts["non_unit_quaternion"] += int(np.count_nonzero(good & ~unit))
        good &= unit
    return good


def prepare_input(t_s: ArrayLike, st_quat_xyzw: ArrayLike, voltages_v: ArrayLike, torque_cmd_n_m: ArrayLike,
                  sample_rate_hz: float = 10.0) -> DiagnosisInput:
    """Validate arrays already on one sample grid (the epoch rule, every stream stamped ``t_s``).

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
        A bad value removes that stream's sample only (a gap, bridged if short); the longest
        segment; rejections counted.

    Raises
    ------
    InputError
        Wrong shapes or lengths, non-positive rate.
    UndeterminedError
        A stream without a single valid sample.
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
    streams = {}
    for name, x in (("star_tracker", q), ("grs1", v[:, 0]), ("grs2", v[:, 1])):
        good = _valid_rows(name, t, x, counts)
        streams[name] = (t[good], x[good])
    grid, values, present, phase_grs = _on_epochs(streams, fs, counts)
    # the command rows as stamped: the one in force at each epoch (by stamp; rows with a bad torque left out)
    good = np.isfinite(t) & np.all(np.isfinite(tau), axis=1)
    counts["nan_or_inf"] += int(np.count_nonzero(~good))
    held = commands_on_grid(t[good] - 1.0 / fs, tau[good], grid, fs)
    received = present["star_tracker"] & present["grs1"] & present["grs2"]
    bridged, weight = _bridge_all(values, present, held)
    return _finish(grid, values, present, held, fs, counts, bridged, {"grs": phase_grs, "command": 0.0}, ~received,
                   weight)


def _locate_lost_changes(command_t_s: ArrayLike, command_torque_n_m: ArrayLike, grid: np.ndarray, fs: float,
                         tau: np.ndarray, values: dict[str, np.ndarray], present: dict[str, np.ndarray]
                         ) -> tuple[np.ndarray, np.ndarray | None]:
    """Commands lost where they changed: the change put at the epoch the GRS show, else its epochs marked unknown.

    The held command (:func:`commands_on_grid`) changes at the first row received with the new value. When the
    rows before it were lost (a stream with a row per epoch, as recorded, and an interval longer than that:
    rows only at changes and at 1 Hz, the contract's minimum, leave a lost change no trace), the change
    lies anywhere in that interval, and holding the old value to the next row received puts the maneuver's
    step late (on the deep_space link: 100 sigma of the torque channel per wrong epoch). The GRS show the
    step: unless the GRS difference at the new row's own epoch shows it (then nothing changes), of the epochs
    it can lie at, the one whose GRS difference (both GRS received on it and the epoch before) is closer to
    the command's step response (:func:`_command_response`) than to no step, the best, takes it; ``tau`` is
    corrected in place. Where no epoch is (the step hidden in the GRS's own gap), the epochs in doubt are
    returned (True) as unknown: estimates, like bridged samples; the change is then put in the middle of the
    GRS's gap, so that the GRS bridged across it (:func:`_bridge`, which follows the
    command's step) step with it and the channels stay consistent there (the 3-h deep_space run: five such
    changes; held to the next row instead, each read 20 to 100 sigma per epoch in the torque channel and a
    GRS time offset in the fits). Each such change is also returned as a row of
    :attr:`DiagnosisInput.command_doubt`: where it lies in the GRS gap is unknown, so the attitude rate the
    channels integrate across it is uncertain by the step times that (:mod:`.angular_gaps`).
    """
    unknown = np.zeros(grid.shape[0], dtype=bool)
    stamps = np.asarray(command_t_s, dtype=np.float64)
    torque = np.asarray(command_torque_n_m, dtype=np.float64).reshape(-1, 3)
    good = np.isfinite(stamps) & np.all(np.isfinite(torque), axis=1)
    order = np.argsort(stamps[good], kind="stable")
    stamps, torque = stamps[good][order], torque[good][order]
    if stamps.shape[0] < 3 or grid.shape[0] < 3:
        return unknown, None
    dt = 1.0 / fs
    interval = np.diff(stamps)
    cadence = max(float(np.median(interval)), dt)
    if cadence > dt * (1.0 + _GRID_TOL):
        return unknown, None  # rows at changes and at 1 Hz (the contract's minimum): a lost change leaves no trace
    changed = np.any(np.diff(torque, axis=0) != 0.0, axis=1)
    doubtful = np.flatnonzero(changed & (interval > cadence + _GRID_TOL * dt)) + 1  # rows whose change may be early
    if not doubtful.size:
        return unknown, None
    grs = np.concatenate((values["grs1"], values["grs2"]), axis=1)
    both = present["grs1"] & present["grs2"]
    response = _command_response(grs, both, tau)
    pair = np.concatenate(([False], both[1:] & both[:-1]))
    d_grs = np.concatenate((np.zeros((1, grs.shape[1])), np.diff(grs, axis=0)))
    # a row is in force from the first epoch whose step starts at or after its stamp (commands_on_grid)
    reach = grid - dt + _GRID_TOL * dt
    doubt: list[tuple[float, ...]] = []
    for i in doubtful:
        first = int(np.searchsorted(reach, stamps[i - 1], side="left"))  # the old value's epoch, received
        new = int(np.searchsorted(reach, stamps[i], side="left"))  # the new value's first epoch, received
        if new >= grid.shape[0]:
            unknown[first + 1:] = True
            continue
        if new <= first + 1:
            continue  # no epoch in doubt
        step = (torque[i] - torque[i - 1]) @ response
        candidates = np.arange(first + 1, new + 1)  # the change takes effect at one of these epochs
        score = np.where(pair[candidates], 2.0 * d_grs[candidates] @ step - step @ step, -np.inf)
        if score[-1] > 0.0:
            continue  # the GRS step at the new row's own epoch: held as received
        best = int(np.argmax(score))
        if np.isfinite(score[best]) and score[best] > 0.0:
            tau[candidates[best]:new + 1] = torque[i]
            continue
        unknown[first + 1:new] = True
        hidden = candidates[~pair[candidates]]
        if hidden.size:  # in the GRS's own gap: in its middle, so that the GRS bridged there step with it
            placed = hidden[hidden.size // 2]
            tau[placed:new + 1] = torque[i]
            # it took effect at any of the hidden epochs, equally likely: the placement's mean square error
            doubt.append((placed, *(torque[i] - torque[i - 1]), float(np.mean((hidden - placed) ** 2))))
    return unknown, (np.array(doubt, dtype=np.float64) if doubt else None)


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
    """Put separately stamped streams on their epochs by the one rule (what a bag gives).

    The epochs are the GRS instants; each stream keeps its own constant offset
    (:mod:`taiji2_estimator_pkg.epochs`). The diagnosis's grid ``t_s`` is the star tracker's
    instants (the epochs shifted by its offset): the GRS phase against it, and the commands' (the
    circular median of their stamps' offsets from the grid), are reported in ``stamp_phase_s``,
    which the diagnosis adds to its model's timing. Gaps of a stream up to
    :data:`MAX_BRIDGE_SAMPLES` are bridged (module docstring); each stream is sorted by stamp first,
    so samples played back out of order are used.

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
        Malformed arrays.
    UndeterminedError
        A stream without a single valid sample on an epoch.
    """
    fs = float(sample_rate_hz)
    dt = 1.0 / fs
    counts: Counter = Counter()
    streams = {}
    for name, t_raw, x_raw, tail in (("star_tracker", st_t_s, st_quat_xyzw, (4,)),
                                     ("grs1", grs1_t_s, grs1_voltages_v, (6,)),
                                     ("grs2", grs2_t_s, grs2_voltages_v, (6,))):
        t = _array(f"{name} stamps", t_raw, ())
        x = _array(name, x_raw, tail)
        if x.shape[0] != t.shape[0]:
            raise InputError(f"{name}: {x.shape[0]} samples but {t.shape[0]} stamps")
        good = _valid_rows(name, t, x, counts)
        streams[name] = (t[good], x[good])
    grid, values, present, phase_grs = _on_epochs(streams, fs, counts)
    command_t = np.asarray(command_t_s, dtype=np.float64)
    phase_c = _phase_steps(command_t[np.isfinite(command_t)], float(grid[0]), dt)
    tau = commands_on_grid(command_t - phase_c * dt, command_torque_n_m, grid, fs)
    received = present["star_tracker"] & present["grs1"] & present["grs2"]
    unknown, doubt = _locate_lost_changes(command_t - phase_c * dt, command_torque_n_m, grid, fs, tau, values,
                                          present)
    bridged, weight = _bridge_all(values, present, tau)
    return _finish(grid, values, present, tau, fs, counts, bridged, {"grs": phase_grs, "command": phase_c * dt},
                   ~received | unknown, weight, doubt)
