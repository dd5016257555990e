"""Figures like the paper's, from a simulated experiment (truth known), saved as PNG.

1. ``angular_acceleration_fit.png``: star-tracker angular acceleration (Savitzky-Golay smoothing
   derivative, the paper's processing) against the calibrated GRS angular acceleration with the
   same smoothing, per CRF axis, over a 1000-s segment (paper: "fit results of GRS1 and ST").
2. ``scale_factors_vs_time.png`` / ``com_offsets_vs_time.png``: running estimates of the default
   method with their 1-sigma band, the truth and the requirement band (0.3 % for G, 100 um for d).
3. ``error_vs_crlb.png``: |error| and reported sigma over time against the Cramer-Rao bound.
No middleware; matplotlib with the Agg backend.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from taiji2_apps.layout_bound import crlb_for_layout
from taiji2_estimator_pkg.core.attitude import SmoothingDerivative, integrate_attitude
from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator
from taiji2_estimator_pkg.core.instrument import InstrumentModel, angular_differences
from taiji2_estimator_pkg.core.scale_factor import ScaleFactorEstimator
from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL

G_NAMES = (r"$G_{P\phi}$", r"$G_{P\theta}$", r"$G_{P\psi}$")


def _flown(label: str) -> str:
    """The second title line naming what was flown (every figure says which maneuver it shows)."""
    return f"\nflown: {label}" if label else ""


def running_estimates(t_s: np.ndarray, quat_xyzw: np.ndarray, voltages_v: np.ndarray, instrument: InstrumentModel,
                      every_s: float = 30.0, progress: Callable[[int, int], None] | None = None,
                      ) -> dict[str, np.ndarray]:
    """Per-sample default-method estimates recorded every ``every_s`` of data (as the nodes publish them).

    ``progress(k, n)`` is called after every recorded estimate (k samples of n done).
    """
    sf, co = ScaleFactorEstimator(instrument, (1, 2)), ComOffsetEstimator(instrument, (1, 2))
    step = max(1, round(every_s * instrument.sample_rate_hz))
    times, g, g_sig, d, d_sig = [], [], [], [], []
    for k in range(t_s.size):
        if progress is not None and k % step == 0:
            progress(k, t_s.size)
        volts = {1: voltages_v[k, 0], 2: voltages_v[k, 1]}
        sf.update(t_s[k], quat_xyzw[k], volts)
        co.update(t_s[k], volts)
        if (k + 1) % step == 0:
            estimate = sf.estimate()
            if not estimate.determined:
                continue
            offsets = co.estimate(estimate)
            times.append(t_s[k])
            g.append(estimate.values)
            g_sig.append(estimate.sigma)
            d.append(offsets.values)
            d_sig.append(offsets.sigma)
    return {"t_s": np.array(times), "g": np.array(g), "g_sigma": np.array(g_sig), "d": np.array(d),
            "d_sigma": np.array(d_sig)}


def plot_angular_acceleration_fit(path: Path, t_s: np.ndarray, quat_xyzw: np.ndarray, voltages_v: np.ndarray,
                                  instrument: InstrumentModel, g: np.ndarray, segment_s: float = 1000.0,
                                  flown: str = "") -> None:
    """Star-tracker vs calibrated-GRS1 angular acceleration (same smoothing on both sides), CRF."""
    smoother = SmoothingDerivative(601, 2, instrument.dt_s)
    _, st_accel = smoother.apply_attitude(integrate_attitude(quat_xyzw))
    u = angular_differences(voltages_v[:, 0])
    grs_crf = (instrument.c(1).T @ (u * g[:3]).T).T
    grs_accel = smoother.apply_grs(grs_crf)
    start = np.flatnonzero(np.isfinite(st_accel[:, 0]))
    k0 = int(start[0]) if start.size else 0
    window = slice(k0, k0 + round(segment_s * instrument.sample_rate_hz))
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for axis, ax in enumerate(axes):
        ax.plot(t_s[window], st_accel[window, axis] * 1e9, lw=0.8, label="star tracker (SIM)")
        ax.plot(t_s[window], grs_accel[window, axis] * 1e9, lw=1.2, label="GRS1 x calibrated G (fit)")
        ax.set_ylabel(f"{'XYZ'[axis]} [nrad s$^{{-2}}$]")
    axes[0].legend(loc="upper right")
    axes[-1].set_xlabel("time [s]")
    fig.suptitle("Angular acceleration in CRF: star tracker vs calibrated GRS1 (same smoothing)" + _flown(flown))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_estimates(directory: Path, history: dict[str, np.ndarray], g_true: np.ndarray, d_true: np.ndarray,
                   flown: str = "") -> None:
    """Running estimates with 1-sigma bands, the truth and the requirement bands."""
    t = history["t_s"]
    fig, axes = plt.subplots(3, 2, figsize=(11, 7), sharex=True)
    for j in range(6):
        ax = axes[j % 3, j // 3]
        rel = (history["g"][:, j] / g_true[j] - 1.0) * 100
        sig = history["g_sigma"][:, j] / g_true[j] * 100
        ax.axhspan(-SCALE_FACTOR_REQUIREMENT_REL * 100, SCALE_FACTOR_REQUIREMENT_REL * 100, color="tab:blue",
                   alpha=0.12, label="requirement 0.3 %")
        ax.fill_between(t, rel - sig, rel + sig, color="tab:orange", alpha=0.3, label="estimate +-1 sigma")
        ax.plot(t, rel, color="tab:orange", lw=1.0)
        ax.axhline(0.0, color="tab:red", ls="--", lw=1.0, label="truth")
        ax.set_ylabel(f"GRS{j // 3 + 1} {G_NAMES[j % 3]} error [%]")
        ax.set_ylim(-0.5, 0.5)
    axes[0, 0].legend(loc="upper right", fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle("Scale factors: running estimate (default method) against truth and requirement" + _flown(flown))
    fig.tight_layout()
    fig.savefig(directory / "scale_factors_vs_time.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(3, 2, figsize=(11, 7), sharex=True)
    for j in range(6):
        ax = axes[j % 3, j // 3]
        err = (history["d"][:, j] - d_true[j]) * 1e6
        sig = history["d_sigma"][:, j] * 1e6
        req = COM_OFFSET_REQUIREMENT_M * 1e6
        ax.axhspan(-req, req, color="tab:blue", alpha=0.12, label="requirement 100 um")
        ax.fill_between(t, err - sig, err + sig, color="tab:orange", alpha=0.3, label="estimate +-1 sigma")
        ax.plot(t, err, color="tab:orange", lw=1.0)
        ax.axhline(0.0, color="tab:red", ls="--", lw=1.0, label="truth")
        ax.set_ylabel(f"GRS{j // 3 + 1} d{'xyz'[j % 3]} error [um]")
        ax.set_ylim(-4 * req, 4 * req)
    axes[0, 0].legend(loc="upper right", fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle("c.m. offsets (CRF): running estimate (default method) against truth and requirement"
                 + _flown(flown))
    fig.tight_layout()
    fig.savefig(directory / "com_offsets_vs_time.png", dpi=110)
    plt.close(fig)


def plot_error_vs_crlb(path: Path, history: dict[str, np.ndarray], g_true: np.ndarray, d_true: np.ndarray,
                       layout: Any, overrides: dict[str, Any], maneuver: Any = None, flown: str = "") -> None:
    """|error| and reported sigma over time against the CRLB at the same durations (both GRS)."""
    t = history["t_s"]
    marks = np.unique(np.linspace(t[0], t[-1], 8).round(-1))
    bounds = [crlb_for_layout(layout, float(m), overrides=overrides, maneuver=maneuver) for m in marks]
    crlb_g = np.array([b.scale_factor_relative_sigma for b in bounds]) * 100
    crlb_d = np.array([b.com_offset_sigma for b in bounds]) * 1e6
    fig, axes = plt.subplots(4, 3, figsize=(12, 11), sharex=True)
    for j in range(6):  # GRS1 then GRS2: a row of G and a row of d each
        grs, axis = j // 3 + 1, j % 3
        ax = axes[2 * (grs - 1), axis]
        ax.semilogy(t, np.abs(history["g"][:, j] / g_true[j] - 1) * 100, lw=0.8, label="|error|")
        ax.semilogy(t, history["g_sigma"][:, j] / g_true[j] * 100, lw=1.2, label="reported sigma")
        ax.semilogy(marks, crlb_g[:, j], "k--o", ms=3, label="CRLB")
        ax.set_title(f"GRS{grs} {G_NAMES[axis]} [%]")
        ax = axes[2 * (grs - 1) + 1, axis]
        ax.semilogy(t, np.abs(history["d"][:, j] - d_true[j]) * 1e6, lw=0.8, label="|error|")
        ax.semilogy(t, history["d_sigma"][:, j] * 1e6, lw=1.2, label="reported sigma")
        ax.semilogy(marks, crlb_d[:, j], "k--o", ms=3, label="CRLB")
        ax.set_title(f"GRS{grs} d{'xyz'[axis]} [um]")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Error and reported sigma against the Cramer-Rao bound" + _flown(flown))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
