"""Residual channels: data minus the calibrated nominal model, with exactly known noise.

Fifteen channels (CRF axes x, y, z each), all linear in the calibrated parameters and in the
noise sources, built from the raw arrays only:

=================  ==============================================================================
``st``             star tracker vs GRS: ``(inc_j - inc_{j-1}) / dt^2 - (m_j + m_{j-1}) / 2``, the
                   second difference of the star-tracker attitude (body increments
                   ``inc_j = log(q_{j-1}^* q_j)``) minus the same combination of the calibrated
                   GRS angular acceleration m (mean of both GRS, CRF). Zero for the nominal
                   model (the integrating GRS sample and the midpoint attitude step make it exact);
                   the attitude and rate constants of the integration drop out.
``torque``         GRS vs command: ``m - J^-1 (tau_cmd - w x J w)``.
``ang_diff``       GRS1 vs GRS2 angular, CRF: ``g_1 - g_2``.
``lin_common``     mean linear acceleration minus the modelled coupling: ``(l_1 + l_2)/2 - A~ d_mean``,
                   prewhitened by ``1 - phi z`` (phi the SRP AR(1) coefficient).
``lin_diff``       linear difference, the common spacecraft acceleration cancels:
                   ``l_1 - l_2 - A~ (d_1 - d_2)``.
=================  ==============================================================================

``A~ d = m x d + w x (w x d)`` uses the calibrated GRS angular acceleration m and the midpoint
rate w (cumulative sum of m, initial rate fitted to the star tracker). The first samples of the
channels with memory (two of ``st``, one of ``lin_common``) are set to zero; the fit frees them
(impulse columns), which makes the circular (FFT) noise model exact (:mod:`.spectral`).

Effects and nuisance parameters enter as *perturbations* of the data-side quantities (angular
and linear accelerations of each GRS, star-tracker attitude, torque prediction, spacecraft
acceleration), mapped to the channels by :func:`perturbation_channels`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import eval_laguerre

from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import ANGULAR_TO_LINEAR, NominalModel
from taiji2_model.frames import cross, quat_conjugate, quat_multiply, rotvec_from_quat
from taiji2_model.timing import actuated_commands

__all__ = [
    "CHANNELS",
    "GROUPS",
    "N_CHANNELS",
    "TIMING_REACH_S",
    "WRAP_SAMPLES",
    "Linearization",
    "Readouts",
    "actuated_torque",
    "linearize",
    "nuisance_column",
    "nuisance_names",
    "perturbation_channels",
    "readouts_from_input",
    "startup_function",
    "torque_edges",
    "zero_wrap",
]

GROUPS = ("st", "torque", "ang_diff", "lin_common", "lin_diff")
CHANNELS = tuple(f"{group}_{axis}" for group in GROUPS for axis in "xyz")
N_CHANNELS = len(CHANNELS)
ST, TORQUE, ANG_DIFF, LIN_COMMON, LIN_DIFF = (slice(3 * i, 3 * i + 3) for i in range(5))
WRAP_SAMPLES = {"st": 2, "lin_common": 1}
"""Leading samples of the channels with memory that the fit frees (impulse columns)."""

STARTUP_TIME_SCALE_S = 5.0
"""Time scale a [s] of the GRS start-up transient basis (:func:`startup_function`)."""

STARTUP_ORDER = 8
"""Laguerre functions per GRS angular readout in the start-up transient (:func:`startup_function`)."""

STARTUP_SUPPORT_S = 550.0
"""Time after the first sample beyond which the start-up functions are set to zero [s] (every one of
them is below 1e-12 of its unit peak after 510 s)."""

TIMING_REACH_S = 0.5
"""Largest delay change [s] the timing candidates consider: the torque channel is set to zero over
the samples at either end of the record whose thrust would then depend on commands outside it."""


@dataclass(frozen=True)
class Readouts:
    """Raw-data quantities that do not depend on the calibration.

    Attributes
    ----------
    t_s : numpy.ndarray
        (n,) sample times [s].
    u : numpy.ndarray
        (n, 2, 3) angular voltage differences (vy1-vy2, vz1-vz2, vx1-vx2) per GRS [V].
    s : numpy.ndarray
        (n, 2, 3) linear voltage sums (vx1+vx2, vy1+vy2, vz1+vz2) per GRS [V].
    inc : numpy.ndarray
        (n, 3) star-tracker body increments ``log(q_{j-1}^* q_j)`` (row 0 zero) [rad].
    dinc : numpy.ndarray
        (n, 3) ``(inc_j - inc_{j-1}) / dt^2`` (rows 0, 1 zero) [rad s^-2].
    torque_cmd_n_m : numpy.ndarray
        (n, 3) mean thrust torque over each sample's interval that the model's timing gives the
        commands (the commands themselves with the default timing) [N m].
    dt_s : float
        Sample interval [s].
    torque_raw_n_m : numpy.ndarray
        (n, 3) commanded torque held over each sample's interval, as recorded [N m].
    """

    t_s: np.ndarray
    u: np.ndarray
    s: np.ndarray
    inc: np.ndarray
    dinc: np.ndarray
    torque_cmd_n_m: np.ndarray
    dt_s: float
    torque_raw_n_m: np.ndarray

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t_s.shape[0])


def readouts_from_input(inp: DiagnosisInput, model: NominalModel) -> Readouts:
    """Voltage combinations, star-tracker increments and actuated torque of an input."""
    volts = inp.voltages_v
    first, second = volts[..., 0::2], volts[..., 1::2]
    u = (first - second)[..., [1, 2, 0]]  # (phi: y pair, theta: z pair, psi: x pair)
    s = first + second
    q = inp.st_quat_xyzw
    inc = np.zeros((inp.n, 3))
    if inp.n > 1:
        inc[1:] = rotvec_from_quat(quat_multiply(quat_conjugate(q[:-1]), q[1:]))
    dinc = np.zeros((inp.n, 3))
    if inp.n > 2:
        dinc[2:] = (inc[2:] - inc[1:-1]) / inp.dt_s ** 2
    actuated = actuated_torque(inp.torque_cmd_n_m, model.delay_s, model.time_constant_s, inp.dt_s)
    return Readouts(inp.t_s, u, s, inc, dinc, actuated, inp.dt_s, inp.torque_cmd_n_m)


def actuated_torque(torque_cmd_n_m: np.ndarray, delay_s: float, time_constant_s: float, dt_s: float) -> np.ndarray:
    """Mean thrust torque over each sample's interval (n, 3) [N m] from the per-sample commands.

    The recorded command of a sample is the one held over its interval; with a delay D and a lag T
    the thrust over that interval mixes neighbouring commands exactly
    (:func:`~taiji2_model.timing.actuated_commands`).
    Before the record the thrusters are taken idle, after it the last command held; the samples
    this guess touches are left out of the torque channel (:func:`torque_edges`).
    """
    if delay_s == 0.0 and time_constant_s == 0.0:
        return torque_cmd_n_m
    return actuated_commands(torque_cmd_n_m, delay_s, time_constant_s, dt_s)


def torque_edges(model: NominalModel, n: int) -> tuple[int, int]:
    """Samples at the start and at the end of the torque channel set to zero: those whose thrust,
    under the model's delay changed by up to :data:`TIMING_REACH_S`, needs commands outside the record."""
    head = math.ceil((max(model.delay_s, 0.0) + TIMING_REACH_S) / model.dt_s) + 1
    tail = math.ceil((max(-model.delay_s, 0.0) + TIMING_REACH_S) / model.dt_s) + 1
    return min(head, n), min(tail, max(n - head, 0))


@dataclass(frozen=True)
class Linearization:
    """Calibrated accelerations and channels at one point (G, d) of the nominal model.

    Attributes
    ----------
    g_angular : numpy.ndarray
        (2, 3) angular scale factors used [rad s^-2 V^-1] (linear ones: r times, tied).
    com_offset_m : numpy.ndarray
        (2, 3) d_i used, CRF [m].
    ghat : numpy.ndarray
        (n, 2, 3) angular accelerations per GRS, TMRF (phi, theta, psi) [rad s^-2].
    lhat : numpy.ndarray
        (n, 2, 3) linear accelerations per GRS, TMRF [m s^-2].
    g_crf, l_crf : numpy.ndarray
        (n, 2, 3) the same in CRF.
    m : numpy.ndarray
        (n, 3) mean GRS angular acceleration, CRF [rad s^-2].
    omega : numpy.ndarray
        (n, 3) body rate at the sample times [rad/s] (cumulative GRS angular acceleration plus an
        initial rate and a rate drift fitted to the star tracker).
    w_mid : numpy.ndarray
        (n, 3) midpoint rate of each step [rad/s].
    channels : numpy.ndarray
        (n, 15) residual channels (:data:`CHANNELS`).
    acc_pred : numpy.ndarray
        (n, 3) angular acceleration predicted from the commanded torque, ``J^-1 (tau - w x J w)``,
        CRF [rad s^-2]: the noise-free regressor.
    ghat_pred : numpy.ndarray
        (n, 2, 3) its TMRF components per GRS [rad s^-2].
    lhat_pred : numpy.ndarray
        (n, 2, 3) predicted linear acceleration ``C_i A~(acc_pred, w) d_i`` (no spacecraft
        acceleration: that is noise), TMRF [m s^-2].
    torque_edges : tuple of int
        Samples at the start and end left out of the torque channel (:func:`torque_edges`).

    Notes
    -----
    Columns of parameters that scale the data (scale factors, and effects built on measured
    accelerations) use the predicted, noise-free accelerations: built on the measured ones, they
    would contain the very noise of the channel they explain, and the least-squares estimate would
    shrink that noise (an errors-in-variables bias of the noise-to-signal power ratio, 0.2 % for
    the scale factors).
    """

    g_angular: np.ndarray
    com_offset_m: np.ndarray
    ghat: np.ndarray
    lhat: np.ndarray
    g_crf: np.ndarray
    l_crf: np.ndarray
    m: np.ndarray
    omega: np.ndarray
    w_mid: np.ndarray
    channels: np.ndarray
    acc_pred: np.ndarray
    ghat_pred: np.ndarray
    lhat_pred: np.ndarray
    torque_edges: tuple[int, int] = (0, 0)

    def noise_free(self) -> Linearization:
        """This linearization with the measured accelerations ``ghat`` and ``lhat`` replaced by the
        predicted ones plus the straight line (a mean and a slope over the record) fitted to measured
        minus predicted: an instrument for the columns of effects built on measured accelerations.

        Such a column contains the noise of the channel it explains; fitted with G, its estimate is
        shrunk (errors in variables) and G moves with it. A readout nonlinearity of GRS2 psi (Type 1,
        k = 7.8e6, 3 h) was re-fitted at 6.0e6 +- 0.6e6 beside G, and G2 psi moved 2.6 sigma from its
        nominal, unbiased value. Columns built on this linearization have the measured accelerations'
        slow part, through which a quadratic term aliases with G (``2 k a0 a``), without their noise.
        """
        n = self.ghat.shape[0]
        t = np.linspace(-1.0, 1.0, n)
        basis = np.column_stack((np.ones(n), t))

        def line_plus_predicted(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
            difference = (measured - predicted).reshape(n, -1)
            coefficients, *_ = np.linalg.lstsq(basis, difference, rcond=None)
            return predicted + (basis @ coefficients).reshape(measured.shape)

        return replace(self, ghat=line_plus_predicted(self.ghat, self.ghat_pred),
                       lhat=line_plus_predicted(self.lhat, self.lhat_pred))

    @property
    def d_mean(self) -> np.ndarray:
        """(d_1 + d_2) / 2 [m]."""
        return 0.5 * (self.com_offset_m[0] + self.com_offset_m[1])

    @property
    def d_diff(self) -> np.ndarray:
        """d_1 - d_2 [m]."""
        return self.com_offset_m[0] - self.com_offset_m[1]


def _to_crf(model: NominalModel, tmrf: np.ndarray) -> np.ndarray:
    """(n, 2, 3) TMRF_i -> CRF per GRS."""
    return np.einsum("gij,ngj->ngi", model.p_crf, tmrf)


def _coupling(m: np.ndarray, w: np.ndarray, d: np.ndarray) -> np.ndarray:
    """A~ d = m x d + w x (w x d) for (n, 3) m, w and a (3,) or (n, 3) d."""
    return cross(m, d) + cross(w, cross(w, d))


def _prewhiten_common(x: np.ndarray, decay: float) -> np.ndarray:
    """``x_j - phi x_{j-1}`` (row 0 left for the wrap)."""
    out = np.array(x, dtype=np.float64)
    out[1:] = x[1:] - decay * x[:-1]
    return out


def linearize(readouts: Readouts, model: NominalModel, g_angular: np.ndarray,
              com_offset_m: np.ndarray) -> Linearization:
    """Calibrated accelerations and residual channels at (G, d).

    Parameters
    ----------
    readouts : Readouts
        Raw-data quantities.
    model : NominalModel
        Nominal model.
    g_angular : numpy.ndarray
        (2, 3) angular scale factors [rad s^-2 V^-1].
    com_offset_m : numpy.ndarray
        (2, 3) c.m. offsets, CRF [m].

    Returns
    -------
    Linearization
    """
    g_angular = np.asarray(g_angular, dtype=np.float64)
    d = np.asarray(com_offset_m, dtype=np.float64)
    dt = readouts.dt_s
    n = readouts.n
    ghat = readouts.u * g_angular
    lhat = readouts.s * model.g_linear(g_angular)
    g_crf = _to_crf(model, ghat)
    l_crf = _to_crf(model, lhat)
    m = 0.5 * (g_crf[:, 0] + g_crf[:, 1])
    # rate: cumulative sum of m, plus an initial rate and a rate drift fitted to the star-tracker
    # increments. The drift absorbs a GRS angular bias (a constant in m integrates to a ramp of the
    # rate, 3e-6 rad/s over 3 h for 3e-10 rad s^-2, ten times the maneuver rate), which would
    # otherwise corrupt the centripetal and gyroscopic terms.
    integrated = dt * np.cumsum(m, axis=0)
    previous = np.vstack((np.zeros((1, 3)), integrated[:-1]))
    mid_integrated = 0.5 * (previous + integrated)
    t_mid_steps = (np.arange(n) - 0.5) * dt  # midpoint of each step from the first sample
    if n > 2:
        # inc_j / dt = w_mid_j = c0 + c1 t_j + mid_integrated_j  (j >= 1)
        design = np.column_stack((np.ones(n - 1), t_mid_steps[1:]))
        coefficients, *_ = np.linalg.lstsq(design, readouts.inc[1:] / dt - mid_integrated[1:], rcond=None)
    else:
        coefficients = np.zeros((2, 3))
    w_mid = coefficients[0] + np.outer(t_mid_steps, coefficients[1]) + mid_integrated
    omega = coefficients[0] + np.outer(t_mid_steps + 0.5 * dt, coefficients[1]) + integrated
    channels = np.zeros((n, 15))
    channels[:, ST] = readouts.dinc
    channels[1:, ST] -= 0.5 * (m[1:] + m[:-1])
    if model.st_offset_s != 0.0 and n > 2:
        # the star tracker stamped t read q(t - e): its attitude lags by -omega e (the time_offset
        # signature), which the model's timing takes back
        channels[2:, ST] += model.st_offset_s * (omega[2:] - 2.0 * omega[1:-1] + omega[:-2]) / dt ** 2
    inertia = model.inertia_kg_m2
    predicted = (readouts.torque_cmd_n_m - cross(w_mid, w_mid @ inertia.T)) @ model.inertia_inv.T
    channels[:, TORQUE] = m - predicted
    channels[:, ANG_DIFF] = g_crf[:, 0] - g_crf[:, 1]
    d_mean = 0.5 * (d[0] + d[1])
    d_diff = d[0] - d[1]
    common = 0.5 * (l_crf[:, 0] + l_crf[:, 1]) - _coupling(m, w_mid, d_mean)
    channels[:, LIN_COMMON] = _prewhiten_common(common, model.srp_decay)
    channels[:, LIN_DIFF] = l_crf[:, 0] - l_crf[:, 1] - _coupling(m, w_mid, d_diff)
    edges = torque_edges(model, n)
    zero_wrap(channels, edges)
    ghat_pred = np.einsum("gij,nj->ngi", model.c_tmrf, predicted)
    lhat_pred = np.stack([_coupling(predicted, w_mid, d[g]) @ model.c_tmrf[g].T for g in range(2)], axis=1)
    return Linearization(g_angular, d, ghat, lhat, g_crf, l_crf, m, omega, w_mid, channels, predicted,
                         ghat_pred, lhat_pred, edges)


def zero_wrap(channels: np.ndarray, edges: tuple[int, int]) -> None:
    """Zero, in place, the wrap samples of the channels with memory and the torque channel's edge samples."""
    channels[: WRAP_SAMPLES["st"], ST] = 0.0
    channels[: WRAP_SAMPLES["lin_common"], LIN_COMMON] = 0.0
    head, tail = edges
    channels[:head, TORQUE] = 0.0
    if tail:
        channels[-tail:, TORQUE] = 0.0


def perturbation_channels(lin: Linearization, model: NominalModel, dg: np.ndarray | None = None,
                          dl: np.ndarray | None = None, datt: np.ndarray | None = None,
                          dtorque: np.ndarray | None = None, dacc: np.ndarray | None = None) -> np.ndarray:
    """Change of the 15 channels caused by changes of the data-side quantities (first order).

    Parameters
    ----------
    lin : Linearization
        Linearization point (uses its d and rate).
    model : NominalModel
        Nominal model (dt, SRP prewhitening).
    dg : numpy.ndarray, optional
        (n, 2, 3) change of the calibrated angular acceleration of each GRS, CRF [rad s^-2].
    dl : numpy.ndarray, optional
        (n, 2, 3) change of the calibrated linear acceleration of each GRS, CRF [m s^-2].
    datt : numpy.ndarray, optional
        (n, 3) change of the star-tracker attitude (small angle, body) [rad].
    dtorque : numpy.ndarray, optional
        (n, 3) change of the torque channel itself (true angular acceleration not predicted by the
        commanded torque) [rad s^-2].
    dacc : numpy.ndarray, optional
        (n, 3) spacecraft acceleration not in the nominal model (common to both GRS), CRF [m s^-2].

    Returns
    -------
    numpy.ndarray
        (n, 15) channel change (wrap samples zero).
    """
    n = lin.m.shape[0]
    out = np.zeros((n, 15), order="F")  # channel-major: each channel's writes and DFT contiguous
    common = None
    diff = None
    if dg is not None:
        dm = 0.5 * (dg[:, 0] + dg[:, 1])
        out[1:, ST] -= 0.5 * (dm[1:] + dm[:-1])
        out[:, TORQUE] += dm
        out[:, ANG_DIFF] += dg[:, 0] - dg[:, 1]
        common = -cross(dm, lin.d_mean)
        diff = -cross(dm, lin.d_diff)
    if dl is not None:
        extra_common = 0.5 * (dl[:, 0] + dl[:, 1])
        common = extra_common if common is None else common + extra_common
        extra_diff = dl[:, 0] - dl[:, 1]
        diff = extra_diff if diff is None else diff + extra_diff
    if dacc is not None:
        common = dacc if common is None else common + dacc
    if datt is not None:
        dt2 = model.dt_s ** 2
        out[2:, ST] += (datt[2:] - 2.0 * datt[1:-1] + datt[:-2]) / dt2
    if dtorque is not None:
        out[:, TORQUE] += dtorque
    if common is not None:
        out[:, LIN_COMMON] = _prewhiten_common(common, model.srp_decay)
    if diff is not None:
        out[:, LIN_DIFF] = diff
    zero_wrap(out, lin.torque_edges)
    return out


def startup_function(order: int, n: int, dt_s: float) -> np.ndarray:
    """(n,) the Laguerre function ``exp(-t / 2a) L_order(t / a)`` of the time t since the first sample.

    A GRS readout's free response from its initial state (the readout electronics settling after
    switch-on, a test mass re-centred by its suspension loop at the start of the record) is a sum of
    damped exponentials of its own time constants. The first :data:`STARTUP_ORDER` functions span
    such settling for time constants from ~3 s to ~60 s (a = :data:`STARTUP_TIME_SCALE_S`: of an
    exponential of 3 s / 10 s / 30 s / 60 s, 5e-5 / 2e-15 / 2e-5 / 5e-3 of its power lies outside
    the span), whose power lies at 0.003-0.05 Hz, and fall below 1e-3 of their peak within ~4 min
    (zero after :data:`STARTUP_SUPPORT_S`). Slower settling is mostly absorbed by the channel
    trends; a lightly damped oscillation lasting minutes is only partly absorbed and stays visible.
    Few functions on a short support, because they cost information: an onset scanned inside the
    first minutes of a record shares it with them.
    """
    support = min(n, math.ceil(STARTUP_SUPPORT_S / dt_s))
    out = np.zeros(n)
    scaled = np.arange(support) * dt_s / STARTUP_TIME_SCALE_S
    out[:support] = np.exp(-0.5 * scaled) * eval_laguerre(order, scaled)
    return out


def nuisance_names() -> list[str]:
    """Names of the nuisance columns (see :func:`nuisance_column`)."""
    names = [f"G.{grs}.{axis}" for grs in (1, 2) for axis in ("phi", "theta", "psi")]
    names += [f"d.{grs}.{axis}" for grs in (1, 2) for axis in "xyz"]
    names += [f"trend.{channel}" for channel in CHANNELS]
    for group, count in WRAP_SAMPLES.items():
        start = GROUPS.index(group) * 3
        names += [f"wrap.{CHANNELS[start + axis]}.{j}" for axis in range(3) for j in range(count)]
    names += [f"startup.{grs}.{axis}.{j}" for grs in (1, 2) for axis in ("phi", "theta", "psi")
              for j in range(STARTUP_ORDER)]
    return names


def nuisance_column(lin: Linearization, model: NominalModel, name: str) -> np.ndarray:
    """One column of the calibration parameters of the nominal model or of a nuisance term.

    - ``G.<grs>.<phi|theta|psi>``: relative change of an angular scale factor (the linear one of
      the same electrode pair follows: the tied conversion); coefficient = relative update.
    - ``d.<grs>.<x|y|z>``: change of d_i [m]; coefficient = update.
    - ``trend.<channel>``: linear trend of a channel (GRS bias drift; the constant is the dropped
      DC bin).
    - ``wrap.<channel>.<j>``: impulse at a leading sample of a channel with memory.
    - ``startup.<grs>.<phi|theta|psi>.<j>``: start-up transient of a GRS angular readout, the j-th
      function of :func:`startup_function` added to that readout [rad s^-2]: a record from another
      source starts where the readout chain or the test mass is still settling from its initial
      state (e.g. a warm-up of the readout bias), which the stationary noise model cannot describe.
      Only the readout: the spacecraft does not move with it, so it shows in ``ang_diff`` and, via
      ``m x d``, in the linear channels.

    Parameters
    ----------
    lin : Linearization
        Linearization point.
    model : NominalModel
        Nominal model.
    name : str
        A name of :func:`nuisance_names`.

    Returns
    -------
    numpy.ndarray
        (n, 15); sign such that the fitted coefficient is the parameter update.
    """
    kind, *rest = name.split(".")
    n = lin.m.shape[0]
    column = np.zeros((n, 15), order="F")
    if kind == "G":
        grs = int(rest[0]) - 1
        axis = ("phi", "theta", "psi").index(rest[1])
        p_crf = model.p_crf
        dg = np.zeros((n, 2, 3))
        dl = np.zeros((n, 2, 3))
        dg[:, grs] = np.outer(lin.ghat_pred[:, grs, axis], p_crf[grs][:, axis])
        linear = ANGULAR_TO_LINEAR[axis]
        dl[:, grs] = np.outer(lin.lhat_pred[:, grs, linear], p_crf[grs][:, linear])
        # scaling G by (1 + x) raises the data side by x * P: the fit of y ~ -x P returns x
        return -perturbation_channels(lin, model, dg=dg, dl=dl)
    if kind == "d":
        grs = int(rest[0]) - 1
        unit = np.zeros(3)
        unit["xyz".index(rest[1])] = 1.0
        coupling = _coupling(lin.acc_pred, lin.w_mid, unit)
        column[:, LIN_COMMON] = _prewhiten_common(0.5 * coupling, model.srp_decay)
        column[:, LIN_DIFF] = coupling if grs == 0 else -coupling
        zero_wrap(column, lin.torque_edges)
        return column
    if kind == "trend":
        index = CHANNELS.index(rest[0])
        column[:, index] = (np.arange(n) - 0.5 * (n - 1)) / max(n, 1)
        zero_wrap(column, lin.torque_edges)
        return column
    if kind == "wrap":
        column[int(rest[1]), CHANNELS.index(rest[0])] = 1.0
        return column
    if kind == "startup":
        grs = int(rest[0]) - 1
        axis = ("phi", "theta", "psi").index(rest[1])
        basis = startup_function(int(rest[2]), n, model.dt_s)
        # built on the function's support only (+1 sample for the filters with memory): 10x cheaper at
        # 3 h; the torque channel's zeroed tail lies beyond it unless the record is that short
        head, tail = lin.torque_edges
        rows = min(n, math.ceil(STARTUP_SUPPORT_S / model.dt_s) + 1)
        short = rows + tail < n
        if short:
            lin = replace(lin, m=lin.m[:rows], torque_edges=(head, 0))
            basis = basis[:rows]
        dg = np.zeros((basis.shape[0], 2, 3))
        dg[:, grs] = np.outer(basis, model.p_crf[grs][:, axis])
        block = perturbation_channels(lin, model, dg=dg)
        if not short:
            return block
        column[:rows] = block
        return column
    raise ValueError(f"unknown nuisance column {name!r}")
