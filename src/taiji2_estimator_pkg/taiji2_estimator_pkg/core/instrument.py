"""Instrument model the estimators need: geometry, nominal parameters, noise budget, conversions.

Nothing here needs the simulator: the model is read from a plain mapping in the layout-file format
(``taiji2_model/config/type1.yaml``), from a YAML file of that format, or from any object with a
``to_dict()`` returning that mapping (e.g. ``taiji2_model.config.SimConfig``).

Conventions (physics.md, interfaces.md):

- a CRF vector v reads ``C_i v`` in TMRF_i, ``C_1`` as printed in the paper, ``C_2 = C_1^T``;
- voltage channels ``vx1, vx2, vy1, vy2, vz1, vz2``;
- angular readout ``(G_Pphi (vy1 - vy2), G_Ptheta (vz1 - vz2), G_Ppsi (vx1 - vx2)) = C_i omega_dot``;
- linear readout ``(G_Px (vx1 + vx2), G_Py (vy1 + vy2), G_Pz (vz1 + vz2))``, with
  ``(G_Px, G_Py, G_Pz) = r (G_Ppsi, G_Pphi, G_Ptheta)``, ``r = a^2 / (6 l)``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike

from taiji2_estimator_pkg.core.noise_model import NoiseBudget, _get
from taiji2_model.frames import crf_to_tmrf

__all__ = [
    "InstrumentModel",
    "angular_differences",
    "crf_to_tmrf",
    "linear_scale_factors",
    "linear_sums",
    "load_layout_mapping",
]

LINEAR_FROM_ANGULAR = (2, 0, 1)
"""Index of the angular scale factor behind each linear one: G_Px ~ G_Ppsi, G_Py ~ G_Pphi, G_Pz ~ G_Ptheta."""


#: order of :func:`angular_differences` among the (vx, vy, vz) differences
_ANGULAR_ORDER = np.array([1, 2, 0])


def angular_differences(voltages_v: ArrayLike) -> np.ndarray:
    """The paper's U~ diagonal: ``(vy1 - vy2, vz1 - vz2, vx1 - vx2)`` [V], shape (..., 3)."""
    v = np.asarray(voltages_v, dtype=np.float64)
    # (vx, vy, vz) differences in one subtraction, reordered to (vy, vz, vx): no np.stack (the per-epoch
    # path calls this for every readout)
    return (v[..., 0::2] - v[..., 1::2])[..., _ANGULAR_ORDER]


def linear_sums(voltages_v: ArrayLike) -> np.ndarray:
    """Voltage sums ``(vx1 + vx2, vy1 + vy2, vz1 + vz2)`` [V], shape (..., 3)."""
    v = np.asarray(voltages_v, dtype=np.float64)
    return v[..., 0::2] + v[..., 1::2]


def linear_scale_factors(angular_scale_factors: ArrayLike, ratio_m: float) -> np.ndarray:
    """``(G_Px, G_Py, G_Pz) = r (G_Ppsi, G_Pphi, G_Ptheta)`` [m s^-2 V^-1], shape (..., 3)."""
    return ratio_m * np.asarray(angular_scale_factors, dtype=np.float64)[..., list(LINEAR_FROM_ANGULAR)]


def load_layout_mapping(source: str | os.PathLike[str] | Mapping[str, Any] | Any) -> dict[str, Any]:
    """Layout mapping from a mapping, a YAML path, a built-in layout name or a ``to_dict()`` object.

    Built-in names (``"type1"``, ``"type2"``) are resolved through ``taiji2_sim_pkg`` when it is
    installed (a convenience only: real-data use passes a file or a mapping).
    """
    if isinstance(source, Mapping):
        return dict(source)
    if hasattr(source, "to_dict"):
        return dict(source.to_dict())
    path = Path(source)
    if not path.exists():
        try:  # optional convenience: built-in layouts of the simulator package
            from taiji2_model.config import builtin_layouts
        except ImportError as error:  # pragma: no cover - depends on the installation
            raise ValueError(f"layout {str(source)!r}: no such file") from error
        layouts = builtin_layouts()
        if str(source) not in layouts:
            raise ValueError(f"layout {str(source)!r}: no such file or built-in layout")
        path = layouts[str(source)]
    with open(path, encoding="utf-8") as stream:
        raw = yaml.load(stream, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml where built
    if not isinstance(raw, dict):
        raise ValueError(f"layout {str(path)!r}: not a mapping")
    return raw


@dataclass(frozen=True)
class InstrumentModel:
    """Geometry, nominal parameters and noise budget of the two GRS and the star tracker.

    Attributes
    ----------
    sample_rate_hz : float
        fs [Hz].
    alpha_rad : float
        Telescope angle [rad].
    linear_ratio_m : float
        r = a^2 / (6 l) [m].
    range_m_s2 : float
        GRS linear range in the experiment [m s^-2].
    nominal_scale_factors : dict of int to numpy.ndarray
        Per GRS id, (G_Pphi, G_Ptheta, G_Ppsi) [rad s^-2 V^-1]: the prior/design value (paper
        filter initial state, weights of the scale-factor bias correction).
    nominal_com_offsets : dict of int to numpy.ndarray
        Per GRS id, design d_i in CRF [m] (only its size enters: the errors-in-variables term of
        the c.m.-offset noise model).
    noise : NoiseBudget
        Noise budget.
    """

    sample_rate_hz: float
    alpha_rad: float
    linear_ratio_m: float
    range_m_s2: float
    nominal_scale_factors: dict[int, np.ndarray]
    nominal_com_offsets: dict[int, np.ndarray]
    noise: NoiseBudget
    _c: dict[int, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_layout(cls, source: str | os.PathLike[str] | Mapping[str, Any] | Any,
                    overrides: Mapping[str, Any] | None = None) -> InstrumentModel:
        """Build from a layout (see :func:`load_layout_mapping`).

        Parameters
        ----------
        source : mapping, path, built-in name or object with ``to_dict()``
            The layout.
        overrides : mapping of str to object, optional
            Dotted keys set after loading, e.g. ``{"noise.thruster_force.enabled": False}``
            (list elements by index, ``grs.sensors.0.com_offset_m``).

        Returns
        -------
        InstrumentModel
        """
        layout = load_layout_mapping(source)
        for key, value in (overrides or {}).items():
            node: Any = layout
            parts = key.split(".")
            for part in parts[:-1]:
                node = node[int(part)] if isinstance(node, list) else node.setdefault(part, {})
            if isinstance(node, list):
                node[int(parts[-1])] = value
            else:
                node[parts[-1]] = value
        sensors = _get(layout, "grs.sensors", None) or [
            {"grs_id": 1, "com_offset_m": [1e-4, 0.18, 2e-4], "angular_scale_factors": [5.524e-8, 5.524e-8, 7.365e-8]},
            {"grs_id": 2, "com_offset_m": [1e-4, -0.18, 2e-4], "angular_scale_factors": [5.524e-8, 5.524e-8, 7.365e-8]},
        ]
        scale = {int(s["grs_id"]): np.asarray(s["angular_scale_factors"], dtype=np.float64) for s in sensors}
        offsets = {int(s["grs_id"]): np.asarray(s["com_offset_m"], dtype=np.float64) for s in sensors}
        budget = NoiseBudget.from_layout(layout)
        return cls(
            sample_rate_hz=float(_get(layout, "sample_rate_hz", 10.0)),
            alpha_rad=math.radians(float(_get(layout, "grs.alpha_deg", 60.0))),
            linear_ratio_m=budget.linear_ratio_m,
            range_m_s2=float(_get(layout, "grs.range_m_s2", 1e-9)),
            nominal_scale_factors=scale,
            nominal_com_offsets=offsets,
            noise=budget,
        )

    @property
    def dt_s(self) -> float:
        """Sample interval [s]."""
        return 1.0 / self.sample_rate_hz

    def c(self, grs_id: int) -> np.ndarray:
        """C_i, CRF to TMRF_i (3, 3)."""
        if grs_id not in self._c:
            self._c[grs_id] = crf_to_tmrf(grs_id, self.alpha_rad)
        return self._c[grs_id]

    def angular_noise_crf(self, grs_id: int) -> np.ndarray:
        """(3, 3) per-sample covariance of ``C_i^T n`` (angular readout noise mapped to CRF) [rad^2 s^-4]."""
        c = self.c(grs_id)
        return c.T @ np.diag(self.noise.angular_readout_variance()) @ c

    def linear_noise_crf(self, grs_id: int) -> np.ndarray:
        """(3, 3) per-sample covariance of the linear readout noise mapped to CRF [m^2 s^-4]."""
        c = self.c(grs_id)
        return c.T @ np.diag(self.noise.linear_readout_variance()) @ c

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (provenance, checkpoints)."""
        return {
            "sample_rate_hz": self.sample_rate_hz,
            "alpha_rad": self.alpha_rad,
            "linear_ratio_m": self.linear_ratio_m,
            "range_m_s2": self.range_m_s2,
            "nominal_scale_factors": {str(k): v.tolist() for k, v in self.nominal_scale_factors.items()},
            "nominal_com_offsets": {str(k): v.tolist() for k, v in self.nominal_com_offsets.items()},
            "noise": self.noise.to_dict(),
        }
