"""The default (``gls``) scale-factor estimator: per-sample (node) and bulk (offline) forms of the
two-stage filter on the attitude model of :mod:`.model`.

Length (over 600 lines): one class, :class:`ScaleFactorEstimator`, whose per-sample and bulk forms must give
the same estimate (tests hold them equal) and share its state, gates and checkpoint; split, the two forms
would drift apart.
"""

from __future__ import annotations

import copy
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.attitude import AttitudeIntegrator
from taiji2_estimator_pkg.core.epoch_arrays import EpochArrays
from taiji2_estimator_pkg.core.gate_estimate import GateEstimate, gate_estimate
from taiji2_estimator_pkg.core.gate_span import GateSpan
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.kalman import chi2_gate
from taiji2_estimator_pkg.core.scale_factor.estimate import ScaleFactorEstimate, StepReport
from taiji2_estimator_pkg.core.scale_factor.model import ScaleFactorModel, ScaleFactorOptions
from taiji2_estimator_pkg.core.small_spd import spd_solve
from taiji2_estimator_pkg.core.stale_input import STALE_REASON, stale_star_tracker
from taiji2_estimator_pkg.core.twostage import TwoStageFilter, solve_information
from taiji2_estimator_pkg.core.validation import InputValidator, ValidationOptions, validate_batch

#: false-alarm probability (per gap, under the held-input model) of the test that the input after a gap
#: still is the held one: a needless new segment costs precision, a missed torque switch biases G. At 1e-2
#: (chi-square 11.3, 3 dof) the Type-1 switches (5.5e-9 rad s^-2 on x or y, 1.1e-8 on z: chi-square 17-120
#: against 1e-9 rad s^-2 of gap_acceleration_sigma_rad_s2) are detected (see _switch_in_gap) and the
#: changes between samples of one torque (chi-square at most 2.5 over 18,000 pairs, lags 0.1-10 s) are not
HELD_INPUT_FALSE_ALARM = 1e-2
#: 1-sigma of the attitude and rate that a torque switch at an unknown time inside a gap leaves unexplained,
#: in units of their largest possible value: effectively diffuse along those two directions (only they
#: lose their information, not the whole state as in a new segment), finite for the covariance form
SWITCH_IN_GAP_SIGMA_SCALE = 100.0


class ScaleFactorEstimator:
    """Default (``gls``) scale-factor estimator: per-sample (node) and bulk (offline) forms.

    Parameters
    ----------
    instrument : InstrumentModel
        Geometry, nominal values and noise budget.
    grs_ids : sequence of int
        GRS estimated jointly (one or both).
    options : ScaleFactorOptions, optional
        Tuning.

    Examples
    --------
    Per sample (a node)::

        est = ScaleFactorEstimator(instrument, (1, 2))
        report = est.update(t, quat_xyzw, {1: v1, 2: v2})   # any input may be None / absent
        g = est.estimate()                                   # running estimate + covariance

    In bulk (offline, a whole bag)::

        est = ScaleFactorEstimator(instrument, (1, 2))
        g = est.process_batch(t, quats, voltages)            # (n,), (n, 4), (n, 2, 6)
    """

    method = "gls"

    def __init__(self, instrument: InstrumentModel, grs_ids: Sequence[int] = (1, 2),
                 options: ScaleFactorOptions | None = None) -> None:
        self.instrument = instrument
        self.options = options or ScaleFactorOptions()
        self.model = ScaleFactorModel(instrument, grs_ids, self.options.star_tracker_offset_s)
        self.grs_ids = self.model.grs_ids
        self.filter = TwoStageFilter(self.model.state_space, self.model.n_params, self.options.snap_tolerance)
        validation = self.options.validation
        self.validator = InputValidator(ValidationOptions(**{**validation.__dict__, "grs_ids": self.grs_ids,
                                                             "sample_rate_hz": instrument.sample_rate_hz,
                                                             "star_tracker_sigma_rad": float(np.max(
                                                                 instrument.noise.star_tracker_sigma_rad))}))
        self.attitude = AttitudeIntegrator()
        self.gate = None if self.options.gate_probability is None else chi2_gate(3, self.options.gate_probability)
        self.held_input_gate = chi2_gate(3, HELD_INPUT_FALSE_ALARM)
        self.nominal_g = np.concatenate([instrument.nominal_scale_factors[g] for g in self.grs_ids])
        p = self.model.n_params
        self.st_correction = self.model.regressor_noise_correction(self.filter.innovation_gramian())
        self.st_correction_sum = np.zeros(p)  # accumulated diagonal of the star-tracker CLS term
        self.diff_moment = np.zeros((p, p))  # sum D^T W D over consistent GRS pairs (uncorrected)
        self.n_diff = 0
        self.n_gated_grs = 0
        self.determined = False
        self._cache: tuple[np.ndarray, np.ndarray, bool] | None = None
        self.gate_span = GateSpan(max(1, round(self.options.gate_refresh_s * instrument.sample_rate_hz)))
        self._segments_x0: list[tuple[np.ndarray, np.ndarray]] = []
        #: input regressor and GRS of the last step with GRS data, held over steps without any
        self._held: tuple[np.ndarray, tuple[int, ...]] | None = None
        #: stamp of the last epoch with an accepted GRS sample [s] (stale star tracker: core/stale_input.py)
        self.last_grs_t_s: float | None = None
        self.last_index: int | None = None
        self.t0_s: float | None = None
        self.t_last_s = float("nan")
        self.rates: np.ndarray | None = None
        self.rate_times: np.ndarray | None = None

    # information and solution ------------------------------------------------------------------
    def _total_information(self) -> tuple[np.ndarray, np.ndarray]:
        """Information over (G, x0): two-stage filter plus the CLS-corrected GRS-pair term."""
        info = self.filter.info.copy()
        p = self.model.n_params
        info[:p, :p] -= np.diag(self.st_correction_sum)
        if self.n_diff:
            # the pair's information without its noise along the scale it cannot see (ScaleFactorModel.pair_information)
            info[:p, :p] += self.model.pair_information(self.diff_moment, self.n_diff)
        return info, self.filter.vector

    def _check_determined(self, info: np.ndarray) -> bool:
        """Whether the data determine every parameter well enough to publish an estimate.

        Single GRS: the information is positive definite. Two GRS: in addition the marginal
        information on G must exceed, by ``determination_margin``, the statistical fluctuation
        ``sqrt(2 n) K`` of the bias-corrected GRS-pair term (in the two directions that the pair
        cannot see, the common scale of (phi, theta) and of psi, only the star tracker informs).
        """
        p = self.model.n_params
        _, cov, full = solve_information(info, np.zeros(info.shape[0]))
        if not full:
            return False
        if self.model.cls_correction is None:
            return True
        marginal_inv = cov[:p, :p]
        fluctuation = math.sqrt(2.0 * max(self.n_diff, 1)) * np.diag(self.model.cls_correction)
        scale = np.sqrt(fluctuation)
        # smallest eigenvalue of F^-1/2 I_G F^-1/2 = 1 / largest of F^1/2 I_G^-1 F^1/2
        largest = float(np.linalg.eigvalsh(marginal_inv * scale[:, None] * scale[None, :])[-1])
        return largest > 0.0 and 1.0 / largest > self.options.determination_margin

    def _solve(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """(theta, covariance, determined) over (G, x0), cached until new data arrive."""
        if self._cache is None:
            info, vec = self._total_information()
            theta, cov, full = solve_information(info, vec, positive=self.determined)
            if not self.determined and full:
                self.determined = self._check_determined(info)
            self._cache = (theta, cov, full and self.determined)
        return self._cache

    def _gate_estimate(self, index: int) -> GateEstimate | None:
        """The gates' estimate for the epoch at grid ``index`` (None: not determined): that of the data
        before the first epoch of its span (core/gate_span.py), solved once per span.

        The snapshot is the total information and vector at the span's first epoch, and whether the
        estimate was determined then (:meth:`_solve` decides it, as for a published estimate)."""
        span = self.gate_span
        if span.starts(index, self.filter.n_segments):
            if self.filter.n_updates:
                info, vector = self._total_information()
                determined = self.determined or self._solve()[2]
                span.take(np.column_stack((info, vector)), determined)
            else:
                span.take(None)
        if span.information is None or not span.determined:
            return None
        if span.solved is None:
            span.solved = (b"", self._snapshot_estimate(span.information))
        return span.solved[1]

    @staticmethod
    def _snapshot_estimate(snapshot: np.ndarray) -> GateEstimate | None:
        """The estimate of a snapshot ``[info | vector]`` taken once determined (None where the data then did
        not determine every parameter: the first epochs of a new segment): by a Cholesky factor of the
        information (core/gate_estimate.py: the same algebra as :meth:`_solve`'s inverse, a fraction of its
        cost), by :meth:`_solve`'s eigen-decomposition where the factor fails."""
        info, vector = snapshot[:, :-1], snapshot[:, -1]
        solved = gate_estimate(info, vector)
        if solved is not None:
            return GateEstimate(*solved)
        theta, cov, full = solve_information(info, vector)
        return GateEstimate.from_covariance(theta, cov) if full else None

    def estimate(self) -> ScaleFactorEstimate:
        """Running estimate with its covariance (all GRS jointly); NaN until determined."""
        theta, cov, ok = self._solve()
        p = self.model.n_params
        values = theta[:p] if ok else np.full(p, np.nan)
        covariance = cov[:p, :p] if ok else np.full((p, p), np.nan)
        dof = max(self.filter.dof_total - self.filter.q_total, 1)
        chi2 = float(self.filter.chi2 - self.filter.vector @ theta) if ok else float("nan")
        rejected = self.validator.count_summary()
        if self.filter.n_rejected:
            rejected.setdefault("star_tracker", {})["gated"] = self.filter.n_rejected
        if self.n_gated_grs:
            rejected.setdefault("grs_pair", {})["gated"] = self.n_gated_grs
        return ScaleFactorEstimate(self.grs_ids, values, covariance, ok, self.t_last_s,
                                   self.filter.n_updates, chi2 / dof, rejected, self.method)

    def rate_estimate(self) -> np.ndarray:
        """Filtered body rate omega at the last epoch, CRF [rad/s] (current estimate; NaN if undetermined)."""
        theta, _, ok = self._solve()
        if not ok:
            return np.full(3, np.nan)
        state = self.filter.x + self.filter.sens @ theta
        return self.model.from_model @ state[3:]

    # per-sample path -----------------------------------------------------------------------------
    def _index(self, t_s: float) -> int:
        if self.t0_s is None:
            self.t0_s = float(t_s)
        return round((float(t_s) - self.t0_s) * self.instrument.sample_rate_hz)

    def start_new_segment(self) -> None:
        """The next epoch starts a new segment (diffuse state): its data need not continue the dynamics
        of the epochs before (a restarted source). The information on G is kept."""
        if not self.filter.fresh:
            self.filter.reset_segment()
            self._cache = None

    def _hold(self, diffs: Mapping[int, np.ndarray], present: tuple[int, ...]) -> np.ndarray:
        """The input regressor of a step with the GRS ``present`` (not empty), kept for the steps after
        it that have no GRS data."""
        regressor = self.model.input_regressor(diffs, present)
        self._held = (regressor, present)
        return regressor

    def _step_input(self, diffs: Mapping[int, np.ndarray], present: tuple[int, ...]
                    ) -> tuple[np.ndarray | None, np.ndarray | None, tuple[int, ...]]:
        """(input regressor, process noise (None: the nominal one), GRS) of a step with the GRS
        ``present``: their input, held for later steps; without any, the held one (:meth:`_held_input`)."""
        if not present:
            return self._held_input()
        q_step = None if len(present) == len(self.grs_ids) else \
            self.model.process_noise_model(present, self.options.gap_acceleration_sigma_rad_s2)
        return self._hold(diffs, present), q_step, present

    def _hold_present(self, epochs: EpochArrays, grs_present: np.ndarray, k: int) -> None:
        """:meth:`_hold` of epoch ``k`` of a batch if it has GRS data (as :meth:`update` holds every such epoch)."""
        present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k, j])
        if present:
            self._hold({g: epochs.diffs[k, j] for j, g in enumerate(self.grs_ids)}, present)

    def _held_input(self) -> tuple[np.ndarray | None, np.ndarray, tuple[int, ...]]:
        """(input regressor, process noise, GRS) of a step without GRS data.

        The angular acceleration changes little from one 0.1-s step to the next (the maneuver is a
        square wave of minutes), so the last GRS input is held, with its readout noise plus
        ``gap_acceleration_sigma_rad_s2`` for the change (a torque switch). Taking the unknown
        acceleration as zero-mean noise (sigma 1e-8) instead biased G by 8-11 sigma over 1200 s with
        5 % of the epochs lost at random, and a diffuse one leaves G undetermined; held, G is
        unbiased within the Monte Carlo's resolution (20 seeds), for 11 % more sigma. A torque switch
        inside a gap is the exception (:meth:`_switch_in_gap`). Before any GRS sample: no input, that
        sigma alone.
        """
        gap = self.model.process_noise_model((), self.options.gap_acceleration_sigma_rad_s2)
        if self._held is None:
            return None, gap, ()
        regressor, present = self._held
        return regressor, self.model.process_noise_model(present, self.options.gap_acceleration_sigma_rad_s2) + gap, \
            present

    def _switch_in_gap(self, missing: int, following: tuple[Mapping[int, np.ndarray], tuple[int, ...]]
                       ) -> np.ndarray | None:
        """Extra (6, 6) process noise at the end of a gap of ``missing`` epochs whose next epoch has the GRS
        input ``following`` = (differences, GRS present): None where the held input bridges the gap;
        NaN where no input after the gap tells (the caller starts a new segment).

        The held input is right across a gap only while the acceleration stands still. A torque switch
        inside the gap leaves the held (old) acceleration in the prediction for the rest of the gap, and
        G absorbed the attitude and rate that it missed: one switch in a 0.2-s gap moved G by 0.6 sigma, in
        a 1-s gap by 2 sigma, in 9.9 s by 2.6 sigma (Type-1, 600 s, seed 4; test/estimator/
        test_restart_exact.py). So the input after the gap is tested against the held one (chi-square at
        :data:`HELD_INPUT_FALSE_ALARM` under the readout noise and ``gap_acceleration_sigma_rad_s2``,
        accelerations at the nominal G). Where it changed by ``d``, the switch at an unknown step leaves
        the state after the gap off by ``(beta^2 / 2) d`` in attitude and ``beta d`` in rate, ``beta`` in
        [0, gap] [s]: those two directions get a (nearly) diffuse variance (:data:`SWITCH_IN_GAP_SIGMA_SCALE`
        times their range), and the rest of the state keeps its information. Before any GRS sample nothing
        is held and nothing can go stale."""
        if self._held is None:
            return None
        diffs, present = following
        if not present:
            return np.full((6, 6), np.nan)
        held, held_present = self._held
        change = (self.model.input_regressor(diffs, present) - held) @ self.nominal_g
        noise = self.model.input_noise(present) + self.model.input_noise(held_present) \
            + self.options.gap_acceleration_sigma_rad_s2**2 * (self.model.to_model @ self.model.to_model.T)
        if float(change @ np.linalg.solve(noise, change)) <= self.held_input_gate:
            return None
        span_s = missing * self.instrument.dt_s
        attitude = np.concatenate((change, np.zeros(3))) * (SWITCH_IN_GAP_SIGMA_SCALE * 0.5 * span_s**2)
        rate = np.concatenate((np.zeros(3), change)) * (SWITCH_IN_GAP_SIGMA_SCALE * span_s)
        return np.outer(attitude, attitude) + np.outer(rate, rate)

    def _epoch_input(self, epochs: EpochArrays, k: int) -> tuple[dict[int, np.ndarray], tuple[int, ...]]:
        """(differences, GRS with a valid sample) of epoch ``k`` of a batch (as :meth:`update` sees them)."""
        return ({g: epochs.diffs[k, j] for j, g in enumerate(self.grs_ids)},
                tuple(g for j, g in enumerate(self.grs_ids) if epochs.grs_ok[k, j]))

    def _bridge(self, missing: int, following: tuple[Mapping[int, np.ndarray], tuple[int, ...]],
                g: np.ndarray | None = None) -> None:
        """Advance over ``missing`` epochs without any data (the last GRS input held, see
        :meth:`_held_input`) up to the epoch whose input is ``following`` (see
        :meth:`_switch_in_gap`); ``g``: in an evaluation pass, the scale factors the held input is
        applied with. A gap longer than ``max_bridged_gap_s``, or one across a switch with no GRS input
        after it, starts a new segment."""
        if missing <= 0:
            return
        switch = None
        if missing * self.instrument.dt_s <= self.options.max_bridged_gap_s:
            switch = self._switch_in_gap(missing, following)
        if missing * self.instrument.dt_s > self.options.max_bridged_gap_s or \
                (switch is not None and not np.all(np.isfinite(switch))):
            self.filter.reset_segment()
            self._cache = None
            return
        regressor, q_step, present = self._held_input()
        for step in range(missing):
            q = q_step if switch is None or step < missing - 1 else q_step + switch
            if g is not None:
                self.filter.step(None, None, None if regressor is None else regressor @ g, None, q=q)
                continue
            fresh = self.filter.fresh
            self.filter.step(None, None, None, regressor, q=q)
            if present and not fresh:
                self.st_correction_sum += self.st_correction[present]

    def update(self, t_s: float, quat_xyzw: ArrayLike | None = None,
               voltages: Mapping[int, ArrayLike] | None = None) -> StepReport:
        """Process one epoch (star tracker and GRS readouts stamped ``t_s``).

        Parameters
        ----------
        t_s : float
            Stamp [s] (on the 1/fs grid of the first stamp).
        quat_xyzw : array_like, optional
            (4,) star-tracker attitude (None: missing).
        voltages : mapping of int to array_like, optional
            GRS id to (6,) voltages ``vx1, vx2, vy1, vy2, vz1, vz2`` [V] (absent: missing).

        Returns
        -------
        StepReport
        """
        rejections: list[tuple[str, str]] = []
        q_ok = None
        if quat_xyzw is not None:
            check = self.validator.check_star_tracker(t_s, quat_xyzw)
            if check.ok:
                q_ok = check.value
            else:
                rejections.append(("star_tracker", str(check.reason)))
        diffs: dict[int, np.ndarray] = {}
        for gid, v in (voltages or {}).items():
            check = self.validator.check_grs(t_s, int(gid), v)
            if check.ok:
                v = check.value
                diffs[int(gid)] = np.array((v[2] - v[3], v[4] - v[5], v[0] - v[1]))
            else:
                rejections.append((f"grs{gid}", str(check.reason)))
        if diffs:
            self.last_grs_t_s = float(t_s)
        elif q_ok is not None and self.last_grs_t_s is not None \
                and float(t_s) - self.last_grs_t_s > self.options.max_bridged_gap_s:
            q_ok = None  # no input to predict it with (core/stale_input.py)
            self.validator.counts.setdefault("star_tracker", Counter())[STALE_REASON] += 1
            rejections.append(("star_tracker", STALE_REASON))
        if q_ok is None and not diffs:
            return StepReport(float(t_s), float("nan"), float("nan"), False, tuple(rejections))
        index = self._index(t_s)
        if self.last_index is not None and index <= self.last_index:
            rejections.append(("epoch", "out_of_order_stamp"))
            return StepReport(float(t_s), float("nan"), float("nan"), False, tuple(rejections))
        if self.last_index is not None:
            self._bridge(index - self.last_index - 1, (diffs, tuple(g for g in self.grs_ids if g in diffs)))
        self.last_index = index
        self.t_last_s = float(t_s)
        estimate = self._gate_estimate(index)
        ok = estimate is not None
        present = tuple(g for g in self.grs_ids if g in diffs)
        nis_grs = float("nan")
        if len(self.grs_ids) == 2 and len(present) == 2:
            d_row = self.model.difference_row(diffs[self.grs_ids[0]], diffs[self.grs_ids[1]])
            if estimate is not None:
                p = self.model.n_params
                resid = d_row @ estimate.theta[:p]
                rows = np.zeros((d_row.shape[0], self.filter.q_total))
                rows[:, :p] = d_row
                total = self.model.q_grs[self.grs_ids[0]] + self.model.q_grs[self.grs_ids[1]] + estimate.spread(rows)
                nis_grs = float(resid @ spd_solve(total, resid))
            if self.gate is not None and ok and nis_grs > self.gate:
                self.n_gated_grs += 1  # inconsistent GRS pair: use neither at this epoch
                rejections.append(("grs_pair", "gated"))
                present = ()
            else:
                self.diff_moment += d_row.T @ self.model.w_diff @ d_row
                self.n_diff += 1
        phi = None if q_ok is None else self.attitude.add(q_ok)
        y = None if phi is None else self.model.to_model @ phi
        regressor, q_step, present = self._step_input(diffs, present)
        fresh = self.filter.fresh
        info = self.filter.step(y, None, None, regressor, q=q_step, gate=self.gate if ok else None,
                                estimate=estimate)
        if present and not fresh:
            self.st_correction_sum += self.st_correction[present]
        self._cache = None
        if not info.accepted:
            rejections.append(("star_tracker", "gated"))
        return StepReport(float(t_s), info.nis, nis_grs, y is not None and info.accepted, tuple(rejections))

    # bulk path ----------------------------------------------------------------------------------------
    def process_batch(self, t_s: ArrayLike, quat_xyzw: ArrayLike, voltages_v: ArrayLike,
                      want_rates: bool = False) -> ScaleFactorEstimate:
        """Process a whole record in bulk.

        Parameters
        ----------
        t_s : array_like
            (n,) stamps shared by the star tracker and the GRS [s].
        quat_xyzw : array_like
            (n, 4) star-tracker readouts (NaN rows: missing).
        voltages_v : array_like
            (n, n_grs, 6) voltages of ``grs_ids`` in order [V] (NaN rows: missing).
        want_rates : bool
            Also compute the filtered body rate at every epoch with the final estimate
            (:attr:`rates` (L, 3) CRF [rad/s] at :attr:`rate_times` (L,) [s]).

        Returns
        -------
        ScaleFactorEstimate
            Same numbers as :meth:`update` sample by sample when nothing is gated. The bulk form
            gates on post-fit residuals (NIS of every epoch at the final estimate) and, if any
            epoch exceeds the gate, runs again without those epochs.
        """
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        volts = np.asarray(voltages_v, dtype=np.float64).reshape(t.size, len(self.grs_ids), 6)
        if self.last_index is not None or self.filter.n_updates:
            raise RuntimeError("process_batch runs on a fresh estimator (use update() to continue)")
        checked = validate_batch(t, quat_xyzw, volts, self.validator.options, self.grs_ids)
        on_grid = checked.grid_index >= 0
        stale = stale_star_tracker(t, checked.star_tracker_ok & on_grid, checked.grs_ok & on_grid[:, None],
                                   self.options.max_bridged_gap_s)
        if np.any(stale):
            checked.star_tracker_ok = checked.star_tracker_ok & ~stale
            star_counts = checked.counts.setdefault("star_tracker", {})
            star_counts[STALE_REASON] = star_counts.get(STALE_REASON, 0) + int(np.count_nonzero(stale))
        for stream, counts in checked.counts.items():
            for reason, number in counts.items():
                self.validator.counts.setdefault(stream, Counter())[reason] += number
        epochs = EpochArrays.build(checked, t, volts)
        initial = copy.deepcopy(self.filter)
        gated_st = np.zeros(epochs.count, dtype=bool)
        gated_pair = np.zeros(epochs.count, dtype=bool)
        states = None  # filtered states of the last evaluation pass, if it used the final estimate
        for attempt in range(2):
            self.filter = copy.deepcopy(initial)
            self.diff_moment = np.zeros_like(self.diff_moment)
            self.st_correction_sum = np.zeros_like(self.st_correction_sum)
            self.n_diff = 0
            self.determined = False
            self._cache = None
            self._accumulate(epochs, gated_st, gated_pair)
            self._segments_x0 = list(self.filter.segment_x0)
            theta, _, ok = self._solve()
            if self.gate is None or attempt == 1 or not ok:
                break
            nis_st, nis_pair, states = self._evaluate(initial, epochs, gated_st, gated_pair, theta)
            new_st = (nis_st > self.gate) & ~gated_st
            new_pair = (nis_pair > self.gate) & ~gated_pair
            if not (np.any(new_st) or np.any(new_pair)):
                break  # nothing newly gated: theta is final and ``states`` were evaluated with it
            states = None
            gated_st |= new_st
            gated_pair |= new_pair
        self.filter.n_rejected = int(np.count_nonzero(gated_st))
        self.n_gated_grs = int(np.count_nonzero(gated_pair))
        theta, _, ok = self._solve()
        if want_rates and ok:
            if states is None:
                _, _, states = self._evaluate(initial, epochs, gated_st, gated_pair, theta)
            self.rates = states[:, 3:] @ self.model.from_model.T
            self.rate_times = epochs.t.copy()
        if epochs.count:
            self.last_index = int(epochs.index[-1])
            self.t0_s = float(epochs.t0)
            self.t_last_s = float(epochs.t[-1])
            grs_rows = np.flatnonzero(np.any(epochs.grs_ok, axis=1))
            self.last_grs_t_s = float(epochs.t[grs_rows[-1]]) if grs_rows.size else None
            self.attitude.load_state_dict({"last": epochs.last_quat.tolist(), "phi": epochs.last_phi.tolist()})
        return self.estimate()

    def _epoch_plan(self, epochs: EpochArrays, gated_st: np.ndarray, gated_pair: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        grs_present = epochs.grs_ok & ~gated_pair[:, None]
        st_present = epochs.st_ok & ~gated_st
        regular = st_present & np.all(grs_present, axis=1)
        return regular, st_present, grs_present

    def _accumulate(self, epochs: EpochArrays, gated_st: np.ndarray, gated_pair: np.ndarray) -> None:
        """Accumulation pass: information of every epoch (bulk for regular runs)."""
        regular, st_present, grs_present = self._epoch_plan(epochs, gated_st, gated_pair)
        model = self.model
        if len(self.grs_ids) == 2:
            both = np.all(grs_present, axis=1)
            if np.any(both):
                d_rows = model.difference_regressor(epochs.diffs[both])
                # sum_k D_k^T W D_k = Z^T Z with Z = stacked L^T D_k  (W = L L^T)
                whitened = (model.w_diff_chol.T @ d_rows).reshape(-1, d_rows.shape[-1])
                self.diff_moment += whitened.T @ whitened
                self.n_diff += int(np.count_nonzero(both))
        y_all = epochs.phi @ model.to_model.T
        self._held = None
        for kind, start, stop in self._runs(epochs, regular, st_present):
            if kind == "skip":
                self._hold_present(epochs, grs_present, start)
                continue
            if kind == "gap":
                self._bridge(stop, self._epoch_input(epochs, start))
            elif kind == "regular":
                fresh = self.filter.fresh
                u_reg = model.input_regressor_factors(epochs.diffs[start:stop])
                self.filter.run_regular(y_all[start:stop], None, None, u_reg)
                self.st_correction_sum += (stop - start - int(fresh)) * self.st_correction[self.grs_ids]
                self._hold_present(epochs, grs_present, stop - 1)
            else:
                k = start
                present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k, j])
                diffs = {g: epochs.diffs[k, j] for j, g in enumerate(self.grs_ids)}
                regressor, q_step, present = self._step_input(diffs, present)
                fresh = self.filter.fresh
                self.filter.step(y_all[k] if st_present[k] else None, None, None, regressor, q=q_step)
                if present and not fresh:
                    self.st_correction_sum += self.st_correction[present]
        self._cache = None

    def _runs(self, epochs: EpochArrays, regular: np.ndarray, st_present: np.ndarray) -> Any:
        """Yield ("gap", k, missing) (before epoch k), ("regular", start, stop), ("single", k, k + 1) or
        ("skip", k, k + 1).

        A regular run goes to :meth:`TwoStageFilter.run_regular` whether or not the filter is at its
        steady state (after an irregular epoch the transient back to it is vectorised there too); the
        filter's state is inspected lazily, as the generator is consumed.

        A segment starts at its first star-tracker epoch: before it the state is diffuse (the
        initial state is a GLS parameter), so epochs without a star-tracker measurement, and gaps,
        carry no information on G (any input there is absorbed by the diffuse state) and are
        skipped. Processing them would leave the covariance off its steady state (a prediction
        without update) and send thousands of epochs down the per-sample path until the Riccati
        recursion converges back (the case of a bag whose first GRS sample precedes the first
        star-tracker sample, e.g. a writer stamping a GRS sample with the start of its step).
        """
        k = 0
        count = epochs.count
        # run_end[k]: one past the last epoch of the run of regular, consecutive epochs from k
        continues = np.zeros(count, dtype=bool)
        continues[:-1] = regular[:-1] & regular[1:] & (np.diff(epochs.index) == 1)
        breaks = np.flatnonzero(~continues)
        run_end = breaks[np.searchsorted(breaks, np.arange(count))] + 1
        while k < count:
            if self.filter.fresh and not st_present[k]:
                yield ("skip", k, k + 1)
                k += 1
                continue
            if k > 0 and not self.filter.fresh:
                missing = int(epochs.index[k] - epochs.index[k - 1] - 1)
                if missing > 0:
                    yield ("gap", k, missing)
            if regular[k]:
                stop = int(run_end[k])
                yield ("regular", k, stop)
                k = stop
            else:
                yield ("single", k, k + 1)
                k += 1

    def _evaluate(self, initial: TwoStageFilter, epochs: EpochArrays, gated_st: np.ndarray,
                  gated_pair: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Evaluation pass at the final estimate: post-fit NIS of every epoch and filtered states."""
        regular, st_present, grs_present = self._epoch_plan(epochs, gated_st, gated_pair)
        model = self.model
        p = model.n_params
        g_hat = theta[:p]
        segments = self._segments_x0
        first_theta = theta if not segments else np.concatenate((g_hat, segments[0][0] - segments[0][1] @ g_hat))
        saved = self.filter
        self.filter = initial.evaluation_copy(first_theta)
        segment = 0
        nis_st = np.zeros(epochs.count)
        states = np.zeros((epochs.count, 6))
        y_all = epochs.phi @ model.to_model.T
        skipped: list[int] = []
        self._held = None
        for kind, start, stop in self._runs(epochs, regular, st_present):
            if kind == "skip":
                skipped.append(start)
                self._hold_present(epochs, grs_present, start)
            elif kind == "gap":
                self._bridge(stop, self._epoch_input(epochs, start), g_hat)
                if self.filter.fresh:  # a reset: the next segment's initial state
                    segment += 1
                    if segment < len(segments):
                        offset, gain = segments[segment]
                        self.filter.x = offset - gain @ g_hat
                    else:
                        self.filter.x = theta[p:].copy()
            elif kind == "regular":
                u0 = model.input_batch(epochs.diffs[start:stop], g_hat)
                out = self.filter.run_regular(y_all[start:stop], None, u0, None, want_states=True)
                nis_st[start:stop] = out.nis
                states[start:stop] = out.states
                self._hold_present(epochs, grs_present, stop - 1)
            else:
                k = start
                present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k, j])
                diffs = {g: epochs.diffs[k, j] for j, g in enumerate(self.grs_ids)}
                regressor, q_step, _ = self._step_input(diffs, present)
                result = self.filter.step(y_all[k] if st_present[k] else None, None,
                                          None if regressor is None else regressor @ g_hat, None, q=q_step)
                states[k] = result.state
                if st_present[k]:
                    nis_st[k] = result.post_nis
        self.filter = saved
        # epochs before a segment's first star-tracker epoch: the state propagated back from it,
        # x_{k-1} = F^-1 (x_k - B a_k), a_k the GRS acceleration at the final estimate
        f_inv = np.linalg.inv(model.f)
        for k in reversed(skipped):
            if k + 1 < epochs.count and epochs.index[k + 1] == epochs.index[k] + 1:
                present = tuple(g for j, g in enumerate(self.grs_ids) if grs_present[k + 1, j])
                diffs = {g: epochs.diffs[k + 1, j] for j, g in enumerate(self.grs_ids)}
                states[k] = f_inv @ (states[k + 1] - model.b @ (model.input_regressor(diffs, present) @ g_hat))
        nis_pair = np.zeros(epochs.count)
        if len(self.grs_ids) == 2:
            both = np.all(epochs.grs_ok, axis=1)
            resid = model.difference_residual(epochs.diffs[both], g_hat)
            # r^T W r = |L^T r|^2
            nis_pair[both] = np.sum((resid @ model.w_diff_chol) ** 2, axis=1)
        return nis_st, nis_pair, states

    # checkpoint ---------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Checkpoint: everything needed to resume (plain lists/numbers, JSON-serialisable)."""
        return {
            "method": self.method, "grs_ids": list(self.grs_ids), "filter": self.filter.state_dict(),
            "validator": self.validator.state_dict(), "attitude": self.attitude.state_dict(),
            "diff_moment": self.diff_moment.tolist(), "n_diff": self.n_diff, "n_gated_grs": self.n_gated_grs,
            "st_correction_sum": self.st_correction_sum.tolist(),
            "determined": self.determined, "last_index": self.last_index, "t0_s": self.t0_s,
            "t_last_s": self.t_last_s,
            "held": None if self._held is None else [self._held[0].tolist(), list(self._held[1])],
            "last_grs_t_s": self.last_grs_t_s, "gate_span": self.gate_span.state_dict(),
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Resume from a :meth:`state_dict` checkpoint (same instrument, GRS and options)."""
        if tuple(state["grs_ids"]) != self.grs_ids or state["method"] != self.method:
            raise ValueError("checkpoint of a different estimator configuration")
        self.filter.load_state_dict(state["filter"])
        self.validator.load_state_dict(state["validator"])
        self.attitude.load_state_dict(state["attitude"])
        self.diff_moment = np.asarray(state["diff_moment"], dtype=np.float64)
        self.n_diff = int(state["n_diff"])
        self.st_correction_sum = np.asarray(state["st_correction_sum"], dtype=np.float64)
        self.n_gated_grs = int(state["n_gated_grs"])
        self.determined = bool(state["determined"])
        self.last_index = state["last_index"]
        self.t0_s = state["t0_s"]
        self.t_last_s = float(state["t_last_s"])
        held = state.get("held")  # absent from checkpoints written before it was kept
        self.last_grs_t_s = state.get("last_grs_t_s")
        self._held = None if held is None else (np.asarray(held[0], dtype=np.float64), tuple(int(g) for g in held[1]))
        self._cache = None
        if "gate_span" in state:  # checkpoints before the gate's spans: a snapshot at the next epoch
            self.gate_span.load_state_dict(state["gate_span"])

    @classmethod
    def from_state_dict(cls, instrument: InstrumentModel, state: Mapping[str, Any],
                        options: ScaleFactorOptions | None = None) -> ScaleFactorEstimator:
        """New estimator resumed from a checkpoint."""
        est = cls(instrument, tuple(state["grs_ids"]), options)
        est.load_state_dict(state)
        return est
