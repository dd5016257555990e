"""Input validation of the raw telemetry, per sample and in bulk.

Every rejected input is counted under a reason (a stable string, for diagnostics); nothing raises
on bad data, and a rejected sample only makes the estimators treat that input as missing.

Reasons
-------
``nan_or_inf``            a non-finite value in a readout or its stamp
``duplicate_stamp``       stamp equal to the last accepted one of the same stream
``out_of_order_stamp``    stamp earlier than the last accepted one of the same stream
``off_grid_stamp``        stamp not on the sample grid ``t0 + k / fs`` (tolerance ``grid_tolerance``)
``non_unit_quaternion``   ``| |q| - 1 |`` above ``quaternion_norm_tolerance``
``sign_flip``             q and the previous readout on opposite hemispheres (same attitude):
                          rejected only with ``sign_flip_policy = "reject"``, else corrected
                          (counted under ``sign_flip_corrected``)
``attitude_jump``         rotation since the last accepted readout above what
                          ``max_rate_rad_s`` and the star-tracker noise allow
``saturated``             an electrode channel at or beyond ``saturation_v``
``unknown_grs``           a GRS id the estimator was not configured for
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.attitude import increment_scalar, quat_conjugate, quat_multiply

__all__ = ["REASONS", "BatchValidation", "Check", "InputValidator", "ValidationOptions", "validate_batch"]

REASONS = ("nan_or_inf", "duplicate_stamp", "out_of_order_stamp", "off_grid_stamp", "non_unit_quaternion",
           "sign_flip", "attitude_jump", "saturated", "unknown_grs")
"""Rejection reasons (``sign_flip_corrected`` is counted too but not a rejection)."""


@dataclass(frozen=True)
class ValidationOptions:
    """Thresholds of the input checks.

    Attributes
    ----------
    sample_rate_hz : float
        Nominal rate fs [Hz] of every stream.
    grid_tolerance : float
        Accepted stamp deviation from the grid, as a fraction of 1/fs.
    quaternion_norm_tolerance : float
        Accepted ``| |q| - 1 |`` (readouts inside are renormalised).
    sign_flip_policy : str
        ``"correct"`` (default: q and -q are the same attitude, the readout is kept with the sign
        of its predecessor) or ``"reject"``.
    max_rate_rad_s : float
        Largest plausible body rate [rad/s] for the jump check.
    star_tracker_sigma_rad : float
        1-sigma star-tracker noise [rad] (jump check allows 10 sigma on top of the rate bound).
    saturation_v : float or None
        Electrode channel full scale [V]; ``|v| >= saturation_v`` is saturated (None: no check).
    grs_ids : tuple of int
        Expected GRS ids.
    """

    sample_rate_hz: float = 10.0
    grid_tolerance: float = 0.05
    quaternion_norm_tolerance: float = 1e-6
    sign_flip_policy: str = "correct"
    max_rate_rad_s: float = 1e-3
    star_tracker_sigma_rad: float = 9.696273622190719e-7
    saturation_v: float | None = 10.0
    grs_ids: tuple[int, ...] = (1, 2)

    def __post_init__(self) -> None:
        if self.sign_flip_policy not in ("correct", "reject"):
            raise ValueError(f"sign_flip_policy: 'correct' or 'reject', got {self.sign_flip_policy!r}")


@dataclass
class Check:
    """Outcome of one input check.

    Attributes
    ----------
    ok : bool
        Accepted.
    reason : str or None
        Rejection reason (see :data:`REASONS`) or None.
    value : numpy.ndarray or None
        Cleaned value (renormalised / sign-corrected quaternion, voltages) when accepted.
    grid_index : int or None
        Sample index on the grid ``t0 + k / fs``.
    """

    ok: bool
    reason: str | None = None
    value: np.ndarray | None = None
    grid_index: int | None = None


class InputValidator:
    """Stateful per-sample checks of star-tracker and GRS readouts.

    Parameters
    ----------
    options : ValidationOptions
        Thresholds.

    Notes
    -----
    The sample grid origin t0 is the first accepted stamp of any stream. Counters are per stream
    (``"star_tracker"``, ``"grs1"``, ``"grs2"``) and reason.
    """

    def __init__(self, options: ValidationOptions | None = None) -> None:
        self.options = options or ValidationOptions()
        self.t0_s: float | None = None
        self._last_stamp: dict[str, float] = {}
        self._last_quat: np.ndarray | None = None
        self._last_raw: np.ndarray | None = None
        self._sign = 1.0
        self._last_quat_t: float | None = None
        self.counts: dict[str, Counter[str]] = {}

    # bookkeeping --------------------------------------------------------------------------------
    def _reject(self, stream: str, reason: str) -> Check:
        self.counts.setdefault(stream, Counter())[reason] += 1
        return Check(False, reason)

    def _note(self, stream: str, what: str) -> None:
        self.counts.setdefault(stream, Counter())[what] += 1

    def rejected_total(self) -> int:
        """Number of rejected inputs over all streams."""
        return sum(n for counter in self.counts.values() for r, n in counter.items() if r in REASONS)

    def count_summary(self) -> dict[str, dict[str, int]]:
        """Counts per stream and reason (plain dicts)."""
        return {stream: dict(counter) for stream, counter in self.counts.items()}

    def _stamp(self, stream: str, t_s: float) -> Check | int:
        if not np.isfinite(t_s):
            return self._reject(stream, "nan_or_inf")
        last = self._last_stamp.get(stream)
        if last is not None and t_s == last:
            return self._reject(stream, "duplicate_stamp")
        if last is not None and t_s < last:
            return self._reject(stream, "out_of_order_stamp")
        if self.t0_s is None:
            self.t0_s = float(t_s)
        position = (t_s - self.t0_s) * self.options.sample_rate_hz
        index = round(position)
        if abs(position - index) > self.options.grid_tolerance:
            return self._reject(stream, "off_grid_stamp")
        if last is not None and index == round((last - self.t0_s) * self.options.sample_rate_hz):
            return self._reject(stream, "duplicate_stamp")
        return int(index)

    # checks -------------------------------------------------------------------------------------
    def check_star_tracker(self, t_s: float, quat_xyzw: ArrayLike) -> Check:
        """Check one star-tracker readout (stamp [s], quaternion xyzw)."""
        stream = "star_tracker"
        q = np.asarray(quat_xyzw, dtype=np.float64).reshape(-1)
        if q.shape != (4,) or not all(math.isfinite(c) for c in q.tolist()):
            return self._reject(stream, "nan_or_inf")
        norm = math.sqrt(float(q @ q))
        if abs(norm - 1.0) > self.options.quaternion_norm_tolerance:
            return self._reject(stream, "non_unit_quaternion")
        stamp = self._stamp(stream, float(t_s))
        if isinstance(stamp, Check):
            return stamp
        q = q / norm
        raw = q
        if self._last_quat is not None:
            if self.options.sign_flip_policy == "reject":
                if float(np.dot(q, self._last_quat)) < 0.0:
                    return self._reject(stream, "sign_flip")
            else:
                # count sign changes of the input stream, keep the output sign-continuous
                if float(np.dot(q, self._last_raw)) < 0.0:  # type: ignore[arg-type]
                    self._note(stream, "sign_flip_corrected")
                    self._sign = -self._sign
                q = self._sign * q
            elapsed = float(t_s) - float(self._last_quat_t)  # type: ignore[arg-type]
            angle = math.hypot(*increment_scalar(self._last_quat, q))
            allowed = self.options.max_rate_rad_s * elapsed + 10.0 * self.options.star_tracker_sigma_rad
            if angle > allowed:
                return self._reject(stream, "attitude_jump")
        self._last_stamp[stream] = float(t_s)
        self._last_quat = q
        self._last_raw = raw
        self._last_quat_t = float(t_s)
        return Check(True, None, q, stamp)

    def check_grs(self, t_s: float, grs_id: int, voltages_v: ArrayLike) -> Check:
        """Check one GRS voltage readout (stamp [s], GRS id, (6,) voltages [V])."""
        if grs_id not in self.options.grs_ids:
            return self._reject(f"grs{grs_id}", "unknown_grs")
        stream = f"grs{grs_id}"
        v = np.asarray(voltages_v, dtype=np.float64).reshape(-1)
        values = v.tolist()  # Python floats: these scalar tests cost a tenth of numpy's on 6 values
        if len(values) != 6 or not all(math.isfinite(c) for c in values):
            return self._reject(stream, "nan_or_inf")
        saturation = self.options.saturation_v
        if saturation is not None and max(max(values), -min(values)) >= saturation:
            return self._reject(stream, "saturated")
        stamp = self._stamp(stream, float(t_s))
        if isinstance(stamp, Check):
            return stamp
        self._last_stamp[stream] = float(t_s)
        return Check(True, None, v.copy(), stamp)

    # checkpoint ---------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Checkpoint."""
        return {
            "t0_s": self.t0_s,
            "last_stamp": dict(self._last_stamp),
            "last_quat": None if self._last_quat is None else self._last_quat.tolist(),
            "last_raw": None if self._last_raw is None else self._last_raw.tolist(),
            "sign": self._sign,
            "last_quat_t": self._last_quat_t,
            "counts": self.count_summary(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a checkpoint of :meth:`state_dict`."""
        self.t0_s = state["t0_s"]
        self._last_stamp = {k: float(v) for k, v in state["last_stamp"].items()}
        self._last_quat = None if state["last_quat"] is None else np.asarray(state["last_quat"], dtype=np.float64)
        self._last_raw = None if state["last_raw"] is None else np.asarray(state["last_raw"], dtype=np.float64)
        self._sign = float(state["sign"])
        self._last_quat_t = state["last_quat_t"]
        self.counts = {k: Counter(v) for k, v in state["counts"].items()}


@dataclass
class BatchValidation:
    """Result of :func:`validate_batch`.

    Attributes
    ----------
    grid_index : numpy.ndarray
        (n,) sample index on the grid (-1 where the stamp itself is unusable).
    star_tracker_ok : numpy.ndarray
        (n,) accepted star-tracker rows.
    grs_ok : numpy.ndarray
        (n, n_grs) accepted GRS rows.
    quat_xyzw : numpy.ndarray
        (n, 4) cleaned quaternions (renormalised, sign-continuous).
    counts : dict
        Per stream and reason.
    """

    grid_index: np.ndarray
    star_tracker_ok: np.ndarray
    grs_ok: np.ndarray
    quat_xyzw: np.ndarray
    counts: dict[str, dict[str, int]] = field(default_factory=dict)


def _row_max_abs(values: np.ndarray) -> np.ndarray:
    """(n,) largest ``|value|`` of each row of an (n, k) array; NaN if the row has a NaN, inf if an inf.

    Column by column (``np.maximum`` propagates NaN): a reduction over a short last axis is ~10x slower.
    """
    largest = np.abs(values[:, 0])
    for column in range(1, values.shape[1]):
        np.maximum(largest, np.abs(values[:, column]), out=largest)
    return largest


def validate_batch(t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike,
                   options: ValidationOptions | None = None, grs_ids: tuple[int, ...] = (1, 2)) -> BatchValidation:
    """Validate a whole record at once (same rules as :class:`InputValidator`, one common stamp column).

    Parameters
    ----------
    t_s : array_like
        (n,) stamps [s] shared by the star tracker and the GRS rows.
    quat_xyzw : array_like
        (n, 4) star-tracker readouts (NaN rows = missing).
    voltages_v : array_like
        (n, n_grs, 6) GRS voltages [V] (NaN = missing).
    options : ValidationOptions, optional
        Thresholds.
    grs_ids : tuple of int
        GRS id of each column of ``voltages_v``.

    Returns
    -------
    BatchValidation
    """
    options = options or ValidationOptions()
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    q = np.array(quat_xyzw, dtype=np.float64, copy=True).reshape(-1, 4)
    v = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, -1, 6)
    n = t.size
    counts: dict[str, Counter[str]] = {"star_tracker": Counter()}
    for gid in grs_ids:
        counts[f"grs{gid}"] = Counter()

    def count(stream: str, reason: str, mask: np.ndarray) -> None:
        number = int(np.count_nonzero(mask))
        if number:
            counts[stream][reason] += number

    # stamps: finite, strictly increasing (against the running maximum), on the grid
    finite_t = np.isfinite(t)
    t_clean = np.where(finite_t, t, -np.inf)
    running = np.maximum.accumulate(t_clean)
    previous = np.concatenate(([-np.inf], running[:-1]))
    duplicate = finite_t & (t_clean == previous)
    out_of_order = finite_t & (t_clean < previous)
    first = int(np.flatnonzero(finite_t)[0]) if np.any(finite_t) else 0
    t0 = t[first] if n else 0.0
    position = (np.where(finite_t, t, t0) - t0) * options.sample_rate_hz
    index = np.rint(position).astype(np.int64)
    off_grid = finite_t & ~duplicate & ~out_of_order & (np.abs(position - index) > options.grid_tolerance)
    stamp_ok = finite_t & ~duplicate & ~out_of_order & ~off_grid
    # two stamps rounding to the same grid index: keep the first
    _, first_of_index = np.unique(np.where(stamp_ok, index, -1), return_index=True)
    same_index = stamp_ok.copy()
    same_index[first_of_index] = False
    stamp_ok &= ~same_index
    grid_index = np.where(stamp_ok, index, -1)
    streams = ["star_tracker", *[f"grs{gid}" for gid in grs_ids]]
    for stream in streams:
        count(stream, "nan_or_inf", ~finite_t)
        count(stream, "duplicate_stamp", duplicate | same_index)
        count(stream, "out_of_order_stamp", out_of_order)
        count(stream, "off_grid_stamp", off_grid)

    # star tracker
    q_finite = np.isfinite(_row_max_abs(q))
    q_safe = np.where(q_finite[:, None], q, 1.0)
    # |q| summed in the order of np.linalg.norm (column by column: a strided view, no reduction over 4)
    norm = np.sqrt(q_safe[:, 0] ** 2 + q_safe[:, 1] ** 2 + q_safe[:, 2] ** 2 + q_safe[:, 3] ** 2)
    non_unit = q_finite & (np.abs(norm - 1.0) > options.quaternion_norm_tolerance)
    st_ok = stamp_ok & q_finite & ~non_unit
    count("star_tracker", "nan_or_inf", stamp_ok & ~q_finite)
    count("star_tracker", "non_unit_quaternion", stamp_ok & non_unit)
    q = q / norm[:, None]
    # sign continuity and jumps: sequential over accepted rows (cheap: vectorised products)
    rows = np.flatnonzero(st_ok)
    if rows.size > 1:
        accepted = q[rows]
        keep = np.ones(rows.size, dtype=bool)
        flips = np.zeros(rows.size, dtype=bool)
        # sign relative to the previous accepted row, propagated as a running parity
        dots = np.einsum("ij,ij->i", accepted[1:], accepted[:-1])
        if options.sign_flip_policy == "reject":
            flips[1:] = dots < 0.0
        else:
            parity = np.concatenate(([1.0], np.cumprod(np.where(dots < 0.0, -1.0, 1.0))))
            accepted = accepted * parity[:, None]
            count("star_tracker", "sign_flip_corrected", np.concatenate(([False], dots < 0.0)))
        # rotation angle between consecutive readouts: |rotvec| = 2 atan2(|vector part|, |scalar part|)
        relative = quat_multiply(quat_conjugate(accepted[:-1]), accepted[1:])
        sine = np.sqrt(relative[:, 0] ** 2 + relative[:, 1] ** 2 + relative[:, 2] ** 2)
        angles = 2.0 * np.arctan2(sine, np.abs(relative[:, 3]))
        elapsed = t[rows[1:]] - t[rows[:-1]]
        allowed = options.max_rate_rad_s * elapsed + 10.0 * options.star_tracker_sigma_rad
        jump = np.concatenate(([False], angles > allowed))
        if np.any(jump | flips):
            # rare: redo sequentially so that a rejected row is not used as the next reference
            validator = InputValidator(options)
            validator.t0_s = t0
            for position_k, row in enumerate(rows):
                check = validator.check_star_tracker(t[row], q[row])
                keep[position_k] = check.ok
                if check.ok:
                    accepted[position_k] = check.value
            for reason, number in validator.counts.get("star_tracker", {}).items():
                if reason in ("attitude_jump", "sign_flip"):
                    counts["star_tracker"][reason] += number
        q[rows] = accepted
        st_ok[rows[~keep]] = False

    # GRS
    grs_ok = np.zeros((n, len(grs_ids)), dtype=bool)
    for column, gid in enumerate(grs_ids):
        stream = f"grs{gid}"
        largest = _row_max_abs(v[:, column])
        finite = np.isfinite(largest)
        saturated = np.zeros(n, dtype=bool)
        if options.saturation_v is not None:
            saturated = finite & (largest >= options.saturation_v)
        count(stream, "nan_or_inf", stamp_ok & ~finite)
        count(stream, "saturated", stamp_ok & saturated)
        grs_ok[:, column] = stamp_ok & finite & ~saturated
    return BatchValidation(grid_index, st_ok, grs_ok, q,
                           {stream: dict(counter) for stream, counter in counts.items()})
