"""Maneuver families beyond the paper's square wave, and the maneuver file that carries any of them.

Families (all torques about the CRF axes [N m], zero outside ``[start, start + duration)``):

- ``square``: :class:`~.maneuver.SquareWaveManeuver` (per-axis amplitude, common period, per-axis phase);
- ``multisine``: ``tau_k(t) = sum_j A_jk sin(2 pi f_j (t - start) + phi_jk)``;
- ``piecewise``: a periodic sequence of constant torques, each held ``step_s``:
  ``tau(t) = T[floor((t - start) / step) mod m]``.

A maneuver file is YAML (or JSON)::

    family: multisine
    start_s: 0.0
    duration_s: 10800.0
    multisine: {frequencies_hz: [0.004, 0.012], amplitude_n_m: [[...3...], [...3...]],
                phase_rad: [[...3...], [...3...]]}

with ``square: {period_s, amplitude_n_m, phase_s}`` or ``piecewise: {step_s, torque_n_m: [[x, y, z], ...]}``
for the other families. The maneuver_commander reads it (parameter ``maneuver``) and the
simulator core samples it with :func:`~.simulator.maneuver_torque_commands` (``maneuver=``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np
import yaml
from numpy.typing import ArrayLike

from taiji2_model.maneuver import AXIS_NAMES, ManeuverError, SquareWaveManeuver, thrust_per_thruster_n

__all__ = ["FAMILIES", "Maneuver", "MultisineManeuver", "PiecewiseManeuver", "builtin_maneuver_file", "check_thrust",
           "load_maneuver_file", "maneuver_from_spec", "maneuver_spec", "peak_torque_n_m", "save_maneuver_file"]

FAMILIES = ("square", "multisine", "piecewise")
"""Names of the maneuver families."""

_EDGE_TOLERANCE_S = 1e-9  # as in maneuver.py: an edge on a sample time counts as passed


class Maneuver(Protocol):
    """What every family provides."""

    start_s: float
    duration_s: float

    def torque_series(self, t_s: ArrayLike) -> np.ndarray: ...

    def torque_at(self, t_s: float) -> np.ndarray: ...


def _finite(name: str, value: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ManeuverError(name, f"must be numeric, got {value!r}") from None
    if shape is not None and array.shape != shape:
        raise ManeuverError(name, f"wrong shape {array.shape}, expected {shape}")
    if not np.all(np.isfinite(array)):
        raise ManeuverError(name, "must be finite")
    return array


class _Windowed:
    """Start, duration and the active mask shared by the families."""

    def __init__(self, start_s: float, duration_s: float) -> None:
        self.start_s = float(_finite("start_s", start_s, ()))
        self.duration_s = float(_finite("duration_s", duration_s, ()))
        if self.duration_s < 0.0:
            raise ManeuverError("duration_s", f"must be >= 0, got {duration_s!r}")

    @property
    def end_s(self) -> float:
        """End of the maneuver window [s] (exclusive)."""
        return self.start_s + self.duration_s

    def _active(self, t: np.ndarray) -> np.ndarray:
        return (t >= self.start_s - _EDGE_TOLERANCE_S) & (t < self.end_s - _EDGE_TOLERANCE_S)

    def torque_series(self, t_s: ArrayLike) -> np.ndarray:
        """(n, 3) commanded torque [N m] at the (n,) times t [s]."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        return np.where(self._active(t)[:, None], self._wave(t), 0.0)

    def torque_at(self, t_s: float) -> np.ndarray:
        """(3,) commanded torque [N m] at one time [s]."""
        return self.torque_series(np.array([t_s], dtype=np.float64))[0]

    def _wave(self, t: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class MultisineManeuver(_Windowed):
    """Sum of sines per CRF axis.

    Parameters
    ----------
    frequencies_hz : array_like
        (m,) frequencies f_j [Hz], > 0.
    amplitude_n_m : array_like
        (m, 3) amplitude A_jk of sine j on axis k [N m].
    phase_rad : array_like
        (m, 3) phase phi_jk [rad].
    start_s, duration_s : float
        Window [s].
    """

    def __init__(self, frequencies_hz: ArrayLike, amplitude_n_m: ArrayLike, phase_rad: ArrayLike,
                 start_s: float = 0.0, duration_s: float = 10800.0) -> None:
        super().__init__(start_s, duration_s)
        self.frequencies_hz = _finite("frequencies_hz", frequencies_hz).reshape(-1)
        m = self.frequencies_hz.size
        if m == 0 or np.any(self.frequencies_hz <= 0.0):
            raise ManeuverError("frequencies_hz", "must be one or more frequencies > 0")
        self.amplitude_n_m = _finite("amplitude_n_m", amplitude_n_m, (m, 3))
        self.phase_rad = _finite("phase_rad", phase_rad, (m, 3))

    def _wave(self, t: np.ndarray) -> np.ndarray:
        # tau_k(t) = sum_j A_jk sin(2 pi f_j (t - start) + phi_jk)
        elapsed = (t - self.start_s)[:, None, None]
        arg = 2.0 * np.pi * self.frequencies_hz[None, :, None] * elapsed + self.phase_rad[None]
        return np.sum(self.amplitude_n_m[None] * np.sin(arg), axis=1)


class PiecewiseManeuver(_Windowed):
    """Periodic sequence of constant torques.

    Parameters
    ----------
    step_s : float
        Hold time of each value [s], > 0.
    torque_n_m : array_like
        (m, 3) torque of each step [N m]; the sequence repeats with period ``m step``.
    start_s, duration_s : float
        Window [s].
    """

    def __init__(self, step_s: float, torque_n_m: ArrayLike, start_s: float = 0.0,
                 duration_s: float = 10800.0) -> None:
        super().__init__(start_s, duration_s)
        self.step_s = float(_finite("step_s", step_s, ()))
        if not self.step_s > 0.0:
            raise ManeuverError("step_s", f"must be > 0, got {step_s!r}")
        self.torque_n_m = _finite("torque_n_m", torque_n_m)
        if self.torque_n_m.ndim != 2 or self.torque_n_m.shape[1] != 3 or self.torque_n_m.shape[0] == 0:
            raise ManeuverError("torque_n_m", f"wrong shape {self.torque_n_m.shape}, expected (m, 3)")

    def _wave(self, t: np.ndarray) -> np.ndarray:
        # tau(t) = T[floor((t - start) / step) mod m]
        index = np.floor((t - self.start_s + _EDGE_TOLERANCE_S) / self.step_s).astype(np.int64)
        return self.torque_n_m[np.mod(index, self.torque_n_m.shape[0])]


def maneuver_from_spec(spec: Mapping[str, Any]) -> Any:
    """Maneuver of any family from its spec (the content of a maneuver file).

    Raises
    ------
    ManeuverError
        Naming the key (``family``, ``square.period_s``, ...) that is missing or wrong.
    """
    if not isinstance(spec, Mapping):
        raise ManeuverError("maneuver", "must be a mapping with 'family'")
    family = spec.get("family")
    if family not in FAMILIES:
        raise ManeuverError("family", f"must be one of {', '.join(FAMILIES)}, got {family!r}")
    body = spec.get(family)
    if not isinstance(body, Mapping):
        raise ManeuverError(family, f"section '{family}' missing or not a mapping")
    window = {"start_s": spec.get("start_s", 0.0), "duration_s": spec.get("duration_s", 10800.0)}
    keys = {"square": ("period_s", "amplitude_n_m", "phase_s"),
            "multisine": ("frequencies_hz", "amplitude_n_m", "phase_rad"),
            "piecewise": ("step_s", "torque_n_m")}[family]
    missing = [k for k in keys if k not in body]
    if missing:
        raise ManeuverError(f"{family}.{missing[0]}", "missing")
    unknown = sorted(set(body) - set(keys))
    if unknown:
        raise ManeuverError(f"{family}.{unknown[0]}", "unknown key")
    cls = {"square": SquareWaveManeuver, "multisine": MultisineManeuver, "piecewise": PiecewiseManeuver}[family]
    return cls(**{k: body[k] for k in keys}, **window)


def maneuver_spec(maneuver: Any) -> dict[str, Any]:
    """Spec (plain lists and floats) of a maneuver: the inverse of :func:`maneuver_from_spec`."""
    window = {"start_s": float(maneuver.start_s), "duration_s": float(maneuver.duration_s)}
    if isinstance(maneuver, SquareWaveManeuver):
        return {"family": "square", **window, "square": {
            "period_s": float(maneuver.period_s), "amplitude_n_m": maneuver.amplitude_n_m.tolist(),
            "phase_s": maneuver.phase_s.tolist()}}
    if isinstance(maneuver, MultisineManeuver):
        return {"family": "multisine", **window, "multisine": {
            "frequencies_hz": maneuver.frequencies_hz.tolist(), "amplitude_n_m": maneuver.amplitude_n_m.tolist(),
            "phase_rad": maneuver.phase_rad.tolist()}}
    if isinstance(maneuver, PiecewiseManeuver):
        return {"family": "piecewise", **window, "piecewise": {
            "step_s": float(maneuver.step_s), "torque_n_m": maneuver.torque_n_m.tolist()}}
    raise TypeError(f"not a maneuver: {maneuver!r}")


def load_maneuver_file(path: str | os.PathLike[str]) -> Any:
    """Maneuver from a YAML/JSON maneuver file; ManeuverError names the file and the problem."""
    try:
        with open(path, encoding="utf-8") as handle:
            spec = yaml.safe_load(handle)
    except (OSError, yaml.YAMLError) as exc:
        raise ManeuverError(f"maneuver file {os.fspath(path)}", f"cannot be read: {exc}") from None
    try:
        return maneuver_from_spec(spec)
    except ManeuverError as exc:
        raise ManeuverError(f"maneuver file {os.fspath(path)}", str(exc)) from None


def builtin_maneuver_file(layout: str) -> str | None:
    """The maneuver file shipped for a built-in layout (``config/maneuvers/<layout>.yaml``), or None.

    These are ``taiji2 design`` results (the header of each file says which command made it); they
    are the default maneuver of ``taiji2 experiment``. Found where the built-in layouts are: the
    source tree, or ``share/taiji2_model/config/maneuvers`` of a pip or colcon install.
    """
    from taiji2_model.config import _config_dirs  # the layout files' search path

    for directory in _config_dirs():
        path = directory / "maneuvers" / f"{layout}.yaml"
        if path.is_file():
            return str(path)
    return None


def save_maneuver_file(path: str | os.PathLike[str], maneuver: Any, comment: str = "") -> None:
    """Write a maneuver file (YAML; JSON-compatible values, full float precision)."""
    text = "".join(f"# {line}\n" for line in comment.splitlines())
    text += yaml.safe_dump(json.loads(json.dumps(maneuver_spec(maneuver))), sort_keys=False)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(text)


def peak_torque_n_m(maneuver: Any, dt_s: float = 0.1) -> np.ndarray:
    """(3,) peak |torque| per axis over the maneuver window [N m] (sampled at dt for multisines)."""
    if isinstance(maneuver, SquareWaveManeuver):
        return np.abs(maneuver.amplitude_n_m) * (maneuver.duration_s > 0.0)
    if isinstance(maneuver, PiecewiseManeuver):
        return np.max(np.abs(maneuver.torque_n_m), axis=0) * (maneuver.duration_s > 0.0)
    t = maneuver.start_s + np.arange(0.0, maneuver.duration_s, dt_s)
    return np.max(np.abs(maneuver.torque_series(t)), axis=0) if t.size else np.zeros(3)


def check_thrust(maneuver: Any, min_thrust_n: float, max_thrust_n: float, lever_arm_m: float) -> None:
    """Refuse a maneuver the micro-thrusters cannot deliver (any family).

    Every non-zero torque level (square amplitude, piecewise value, multisine peak) must map to a
    thrust ``|tau| / L`` inside ``[min_thrust_n, max_thrust_n]``; ManeuverError names the axis.
    """
    if isinstance(maneuver, SquareWaveManeuver):
        maneuver.check_thrust(min_thrust_n, max_thrust_n, lever_arm_m)
        return
    levels = (np.abs(maneuver.torque_n_m) if isinstance(maneuver, PiecewiseManeuver)
              else peak_torque_n_m(maneuver)[None, :])
    thrust = thrust_per_thruster_n(levels, lever_arm_m)
    bad = (levels != 0.0) & ((thrust < min_thrust_n) | (thrust > max_thrust_n))
    if np.any(bad):
        row, axis = (int(v[0]) for v in np.nonzero(bad))
        raise ManeuverError(f"torque[{AXIS_NAMES[axis]}]",
                            f"|{levels[row, axis]:.4g}| N m / {lever_arm_m:.4g} m needs {thrust[row, axis]:.4g} N "
                            f"per thruster, outside the thruster range [{min_thrust_n:.4g}, {max_thrust_n:.4g}] N")
