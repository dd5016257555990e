"""Timing effects: a time offset of a stream, actuation delay and thruster response, a GRS time offset.

Part of the effect catalog (:mod:`taiji2_model.effect_catalog`, which documents every effect).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from taiji2_model.config_schema import SimConfig, TimingConfig
from taiji2_model.effect_catalog.base import EffectParameterError, _CatalogEffect, _scalar
from taiji2_model.frames import quat_from_rotvec, quat_multiply


class TimeOffset(_CatalogEffect):
    """Star-tracker time stamps offset from the GRS (and command) clock.

    The star tracker stamped t read the attitude at ``t - offset_s`` (offset > 0: it is late).
    The effect follows the true body rate itself from the applied torque it sees (rigid body,
    without the 1e-9-relative gyroscopic term) and rotates each readout by the body-frame angle
    ``-int_{t - offset}^{t} omega dt`` (exact for the piecewise-linear rate of the simulator; for
    a negative offset the rate is extrapolated over |offset| with the last angular acceleration).
    Put it after every effect that changes the torque or the inertia
    (:func:`effects_from_config` does).

    Parameters
    ----------
    offset_s : float
        Offset [s].
    enabled : bool
        Switch.
    """

    name = "time_offset"
    _params = ("offset_s",)

    def __init__(self, offset_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.offset_s = _scalar(self.name, "offset_s", offset_s)
        self._dt_s = 0.1
        self._inertia_inv: np.ndarray | None = None
        self._omega = np.zeros(3)
        self._history_omega = np.zeros((0, 3))
        self._history_acc = np.zeros((0, 3))
        self._pending_acc: np.ndarray | None = None
        self._torque_block = np.zeros((0, 3))

    @property
    def active(self) -> bool:
        return self.enabled and self.offset_s != 0.0

    def bind(self, config: SimConfig, seed: int) -> None:
        self._dt_s = config.dt_s
        self._inertia_inv = np.linalg.inv(config.spacecraft.inertia_kg_m2)
        self._omega = np.array(config.spacecraft.initial_rate_rad_s, dtype=np.float64)
        steps = math.ceil(abs(self.offset_s) / self._dt_s) + 1
        self._history_omega = np.tile(self._omega, (steps, 1))
        self._history_acc = np.zeros((steps, 3))

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        if self.active:
            self._torque_block = torque_n_m
        return torque_n_m

    def inertia_kg_m2(self, t_s: np.ndarray, inertia_kg_m2: np.ndarray) -> np.ndarray:
        if self.active:
            inverse = np.linalg.inv(inertia_kg_m2)
            self._pending_acc = (np.einsum("nij,nj->ni", inverse, self._torque_block) if inverse.ndim == 3
                                 else self._torque_block @ inverse.T)
        return inertia_kg_m2

    def star_tracker_quat_xyzw(self, t_s: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
        if not self.active:
            return quat_xyzw
        if self._pending_acc is None:
            raise RuntimeError("time_offset: no torque seen for this block")
        acc = self._pending_acc
        self._pending_acc = None
        omega = self._omega + self._dt_s * np.cumsum(acc, axis=0)
        self._omega = omega[-1].copy()
        keep = self._history_omega.shape[0]
        all_omega = np.concatenate((self._history_omega, omega))  # rate at the sample times
        all_acc = np.concatenate((self._history_acc, acc))  # acceleration over the step ending there
        self._history_omega = all_omega[-keep:]
        self._history_acc = all_acc[-keep:]
        dt = self._dt_s
        count = omega.shape[0]
        index = keep + np.arange(count)  # position of each new sample in the combined arrays
        if self.offset_s > 0.0:
            whole, fraction = divmod(self.offset_s / dt, 1.0)
            whole = int(whole)
            angle = np.zeros((count, 3))
            for back in range(whole):  # full steps (t_{j-b-1}, t_{j-b}]
                angle += 0.5 * dt * (all_omega[index - back - 1] + all_omega[index - back])
            tail = fraction * dt  # last part of the step ending at t_{j-whole}
            angle += tail * all_omega[index - whole] - 0.5 * tail * tail * all_acc[index - whole]
            rotation = -angle
        else:
            lead = -self.offset_s
            rotation = lead * omega + 0.5 * lead * lead * acc
        return quat_multiply(quat_xyzw, quat_from_rotvec(self._stepped(t_s, rotation)))


class _ActuationFromOnset(_CatalogEffect):
    """A timing effect with an onset: the applied torque changes from the onset on.

    Present from the start, a latency or lag is a timing convention the simulator applies itself
    (:meth:`timing`). From an onset on, it acts through :meth:`applied_torque_n_m`: the torque the
    hook receives (command through the configured timing, plus thruster noise) is passed through the
    extra delay and lag (:func:`~.timing.actuated_commands`, on the hook's own time step), and
    replaces the torque from the onset on (a thruster whose latency or response changes mid-run).
    Exact in batch; in streaming blocks a history of the taps is kept (a negative delay needs
    later torques, i.e. batch simulation).
    """

    def _extra(self) -> tuple[float, float]:
        raise NotImplementedError

    def bind(self, config: SimConfig, seed: int) -> None:
        self._dt_s = config.dt_s
        self._history = np.zeros((0, 3))
        self._calls = 0

    def _from_onset(self) -> bool:
        return self.active and self.onset_s > 0.0

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        if not self._from_onset() or torque_n_m.shape[0] == 0:
            return torque_n_m
        from taiji2_model.timing import actuated_commands, actuation_weights

        t = np.asarray(t_s, dtype=np.float64)
        dt = float(t[1] - t[0]) if t.shape[0] > 1 else getattr(self, "_dt_s", 0.1)
        delay_s, lag_s = self._extra()
        self._calls = getattr(self, "_calls", 0) + 1
        if delay_s < 0.0 and self._calls > 1:
            raise RuntimeError(f"{self.name}: a negative delay from an onset needs the whole torque series "
                               "(batch simulation)")
        history = getattr(self, "_history", np.zeros((0, 3)))
        series = np.concatenate((history, torque_n_m))
        moved = actuated_commands(series, delay_s, lag_s, dt, before=series[0])[history.shape[0]:]
        m_first, weights = actuation_weights(delay_s, lag_s, dt)
        keep = max(m_first + weights.size, 1)
        self._history = series[-keep:]
        return np.where((t >= self.onset_s)[:, None], moved, torque_n_m)


class ActuationDelay(_ActuationFromOnset):
    """The applied torque lags the command by ``delay_s`` (thruster latency, command transport).

    A timing effect: it adds to ``timing.actuation_latency_s`` and the simulator applies the
    exact fractional delay (:mod:`.timing`); a negative delay (torque before its command stamp:
    a command stamped late) needs the whole command series, i.e. batch simulation.
    """

    name = "actuation_delay"
    _params = ("delay_s",)

    def __init__(self, delay_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.delay_s = _scalar(self.name, "delay_s", delay_s)

    @property
    def active(self) -> bool:
        return self.enabled and self.delay_s != 0.0

    def _extra(self) -> tuple[float, float]:
        return self.delay_s, 0.0

    def timing(self, timing: TimingConfig) -> TimingConfig:
        if not self.active or self.onset_s > 0.0:
            return timing
        return replace(timing, actuation_latency_s=timing.actuation_latency_s + self.delay_s)


class ThrusterResponse(_ActuationFromOnset):
    """First-order response of the thrust, time constant ``time_constant_s`` (rise time 2.2 T).

    A timing effect: it adds to ``timing.thruster_time_constant_s``.
    """

    name = "thruster_response"
    _params = ("time_constant_s",)

    def __init__(self, time_constant_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.time_constant_s = _scalar(self.name, "time_constant_s", time_constant_s)
        if self.time_constant_s < 0.0:
            raise EffectParameterError(self.name, "time_constant_s", f"must be >= 0, got {time_constant_s!r}")

    @property
    def active(self) -> bool:
        return self.enabled and self.time_constant_s != 0.0

    def _extra(self) -> tuple[float, float]:
        return 0.0, self.time_constant_s

    def timing(self, timing: TimingConfig) -> TimingConfig:
        if not self.active or self.onset_s > 0.0:
            return timing
        return replace(timing, thruster_time_constant_s=timing.thruster_time_constant_s + self.time_constant_s)


class GrsTimeOffset(_CatalogEffect):
    """GRS samples stamped ``offset_s`` late against the model's convention (both GRS).

    A timing effect: it adds to ``timing.grs_stamp`` (the sample stamped t covers the interval
    ending at t - grs_stamp).
    """

    name = "grs_time_offset"
    _params = ("offset_s",)

    def __init__(self, offset_s: float = 0.0, enabled: bool = True, onset_s: float = 0.0) -> None:
        super().__init__(enabled, onset_s)
        self.offset_s = _scalar(self.name, "offset_s", offset_s)
        if self.onset_s > 0.0:
            raise EffectParameterError(self.name, "onset_s", "a GRS stamp convention that changes during the run is "
                                       "not simulated; give its reduction, actuation_delay and time_offset "
                                       "(-offset_s) with the same onset (docs/interfaces.md)")

    @property
    def active(self) -> bool:
        return self.enabled and self.offset_s != 0.0

    def timing(self, timing: TimingConfig) -> TimingConfig:
        return replace(timing, grs_stamp=timing.grs_stamp + self.offset_s) if self.active else timing


