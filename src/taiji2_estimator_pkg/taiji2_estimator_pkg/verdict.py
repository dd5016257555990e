"""The verdict of a calibration experiment: which requirements are met, which cannot be, and why.

A requirement (G to 0.3 %, d to 100 um, 1 sigma, each of the 12 parameters of both GRS) is *met*
when the reported 1-sigma is within it and the Cramer-Rao bound of the flown maneuver and duration
is within it (where known). A 1-sigma requirement is a property of the estimate's distribution, not
of one draw: at a 1-sigma equal to the requirement the error of one run lies beyond it in 32 % of
runs. So the same data give the same verdict with or without the truth (``taiji2 experiment`` and
``taiji2 calibrate`` of its recording), and where the truth is known (simulation) the error is a
consistency check of the estimate and its 1-sigma (beyond 3 sigma: named as an estimator warning),
not a requirement. A parameter that is not met is put in the first of these classes that applies:

* ``cannot``: its bound is beyond the requirement. No estimator reaches it with this maneuver and
  duration; the remedy is a longer run (the bound falls as 1/sqrt(T)) or a designed maneuver
  (``taiji2 design``).
* ``estimator``: the bound is within, the reported 1-sigma is not.

The GRS linear range is a requirement too (the paper: the linear acceleration of the calibration
experiment combined with the background noise must fall within the measurable range of the GRS):
where the simulator's range check is known (:class:`RangeCheck`), it is met when on every GRS and
TMRF axis at most :data:`RANGE_FRACTION_LIMIT` of the samples of the linear readout, signal plus
every noise source, lie beyond the range. Beyond it the readout saturates (the simulator clips it
there unless ``grs.readout_saturation`` is off); a violation is an unmet requirement like any other.

Plain data (no middleware): built from an :class:`~taiji2_estimator_pkg.report.EstimateTable`, the
bound (:func:`taiji2_estimator_pkg.core.crlb.crlb`) and the simulator's diagnostics.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL, EstimateTable

__all__ = ["RANGE_FRACTION_LIMIT", "ParameterCheck", "RangeCheck", "Verdict", "judge", "range_warning"]

_G_NAMES = ("G_Pphi", "G_Ptheta", "G_Ppsi")
_D_NAMES = ("d_x", "d_y", "d_z")
#: reported 1-sigma / bound outside this interval is named (the estimators reach the bound within ~15 %)
_SIGMA_OVER_BOUND = (0.8, 1.25)
#: |error| / 1-sigma beyond this is named as inconsistent
_ERROR_SIGMAS = 3.0
RANGE_FRACTION_LIMIT = 1e-3
"""Largest fraction of the samples of one GRS TMRF axis whose linear readout (signal + every noise)
may lie beyond the range for the range requirement to be met (0.1 %)."""


@dataclass(frozen=True)
class ParameterCheck:
    """One of the 12 parameters, every value as a fraction of its requirement (NaN: unknown).

    Attributes
    ----------
    name : str
        ``grs1.G_Pphi`` ... ``grs2.d_z`` (the order of ``design.evaluate.PARAMETER_NAMES``).
    sigma, bound, error : float
        Reported 1-sigma, Cramer-Rao bound and error against truth, each / requirement.
    unit_value : float
        The requirement in display units (0.3 for G [%], 100 for d [um]).
    unit : str
        ``"%"`` or ``"um"``.
    """

    name: str
    sigma: float
    bound: float
    error: float
    unit_value: float
    unit: str

    @property
    def status(self) -> str:
        """``met``, ``cannot`` or ``estimator`` (see the module doc; an undetermined 1-sigma, NaN, is
        ``estimator`` unless the bound says ``cannot``). The error does not enter (a consistency check)."""
        if self.bound > 1.0 or (np.isnan(self.bound) and self.sigma > 1.0):
            return "cannot"
        if not self.sigma <= 1.0:  # above the requirement, or NaN: not determined by the data
            return "estimator"
        return "met"

    def amount(self, fraction: float) -> str:
        """A fraction of the requirement in display units (``148 um``, ``0.061 %``)."""
        value = fraction * self.unit_value
        return f"{value:.0f} um" if self.unit == "um" else f"{value:.3f} %"


@dataclass(frozen=True)
class RangeCheck:
    """The GRS linear range requirement, from the simulator's range check.

    Attributes
    ----------
    range_m_s2 : float
        The range, +-range [m s^-2].
    samples : int
        Samples checked.
    samples_outside : numpy.ndarray
        (2, 3) per GRS and TMRF axis: samples whose linear readout (signal + every noise) is beyond.
    total_peak : numpy.ndarray
        (2, 3) peak |linear readout| / range.
    maneuver_peak : numpy.ndarray
        (2, 3) peak |rotation-induced part| / range (with the torque noise's rotation).
    design_peak : float, optional
        Peak of the noise-free maneuver part / range (the design's figure).
    saturation : bool, optional
        The simulator clipped the readout at the range (``grs.readout_saturation``); None: unknown.
    limit : float
        Largest allowed fraction of the samples beyond, per axis.
    """

    range_m_s2: float
    samples: int
    samples_outside: np.ndarray
    total_peak: np.ndarray
    maneuver_peak: np.ndarray
    design_peak: float | None = None
    saturation: bool | None = None
    limit: float = RANGE_FRACTION_LIMIT

    @classmethod
    def from_values(cls, values: Mapping[str, Any], design_peak: float | None = None,
                    saturation: bool | None = None, limit: float = RANGE_FRACTION_LIMIT) -> RangeCheck:
        """From the simulator's ``GRS linear range`` diagnostic values (see :func:`range_warning`)."""
        total = np.asarray(values["total_peak_fraction_of_range"], dtype=float)
        return cls(float(values["range_m_s2"]), int(values.get("samples", 0)),
                   np.asarray(values.get("total_samples_outside", np.zeros_like(total)), dtype=float), total,
                   np.asarray(values["maneuver_peak_fraction_of_range"], dtype=float), design_peak, saturation,
                   float(limit))

    @property
    def fraction(self) -> np.ndarray:
        """(2, 3) fraction of the samples beyond the range per GRS and TMRF axis."""
        return np.asarray(self.samples_outside, dtype=float) / max(self.samples, 1)

    @property
    def met(self) -> bool:
        """At most ``limit`` of the samples of every axis beyond the range."""
        return bool(np.max(self.fraction) <= self.limit)

    def summary(self) -> str:
        """``0.02 % of the samples beyond +-1e-09 m/s^2 (GRS1 z), peak 104 % (GRS1 z)``."""
        worst, worst_at = _where(self.fraction)
        peak, peak_at = _where(self.total_peak)
        return (f"{worst:.2%} of the samples beyond +-{self.range_m_s2:.0e} m/s^2 ({worst_at}), peak {peak:.0%} "
                f"({peak_at})")

    def line(self) -> str:
        """The reason line of an unmet range requirement."""
        text = range_warning({"range_m_s2": self.range_m_s2, "samples": self.samples,
                              "maneuver_peak_fraction_of_range": self.maneuver_peak,
                              "total_peak_fraction_of_range": self.total_peak,
                              "total_samples_outside": self.samples_outside}, self.design_peak, self.saturation)
        return (f"GRS linear range not met (at most {self.limit:.1%} of the samples of each TM axis beyond it): "
                + (text or self.summary()).removeprefix("simulator: "))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"met": self.met, "range_m_s2": self.range_m_s2, "samples": self.samples,
                "limit_fraction_outside": self.limit, "fraction_outside": self.fraction.tolist(),
                "total_peak_fraction_of_range": np.asarray(self.total_peak).tolist(),
                "maneuver_peak_fraction_of_range": np.asarray(self.maneuver_peak).tolist(),
                "design_peak_fraction_of_range": self.design_peak, "saturation": self.saturation}


@dataclass
class Verdict:
    """The verdict of one experiment (see the module doc)."""

    checks: list[ParameterCheck]
    duration_s: float
    maneuver: str
    remedy: str = ""
    maneuver_covers_run: bool = True
    warnings: list[str] = field(default_factory=list)
    range_check: RangeCheck | None = None
    range_remedy: str = ""

    @property
    def all_met(self) -> bool:
        """Every requirement met: the 12 parameters and, where known, the GRS linear range."""
        return all(c.status == "met" for c in self.checks) and (self.range_check is None or self.range_check.met)

    @property
    def _requirements(self) -> str:
        text = "G to 0.3 %, d to 100 um, 1 sigma, both GRS"
        if self.range_check is not None:
            text += f"; GRS linear range, <= {self.range_check.limit:.1%} of the samples beyond"
        return text

    def _named(self, status: str) -> list[ParameterCheck]:
        return [c for c in self.checks if c.status == status]

    def _inconsistent(self) -> list[ParameterCheck]:
        """Parameters whose error (where the truth is known) is beyond 3 of their reported 1-sigma."""
        return [c for c in self.checks if c.sigma > 0 and abs(c.error) / c.sigma > _ERROR_SIGMAS]

    def requirement_counts(self) -> tuple[int, int]:
        """``(met, total)``: the requirements met and judged (12 parameters, and the range where known)."""
        n, met = len(self.checks), len(self._named("met"))
        if self.range_check is not None:
            n, met = n + 1, met + int(self.range_check.met)
        return met, n

    def lines(self) -> list[str]:
        """Human-readable: the verdict line, one line per reason, then the warnings."""
        hours = f"{self.duration_s / 3600:.2f} h"
        met, n = self.requirement_counts()
        out = []
        if self.all_met:
            worst = max(self.checks, key=lambda c: c.sigma)
            text = (f"verdict: all {n} requirements met ({self._requirements}) with "
                    f"{self.maneuver} in {hours}: largest 1-sigma {worst.name} {worst.amount(worst.sigma)} = "
                    f"{worst.sigma:.2f} of its requirement")
            if not np.isnan(worst.bound):
                text += f" (the Cramer-Rao bound: {worst.bound:.2f})"
            errors = [c for c in self.checks if not np.isnan(c.error)]
            if errors:
                largest = max(errors, key=lambda c: abs(c.error))
                text += f"; largest error {largest.name} {largest.amount(abs(largest.error))}"
            if self.range_check is not None:
                text += f"; GRS range: {self.range_check.summary()}"
            out.append(text)
        else:
            missed = [c.name for c in self.checks if c.status != "met"]
            if self.range_check is not None and not self.range_check.met:
                missed.append("GRS linear range")
            out.append(f"verdict: {met} of {n} requirements met ({self._requirements}) with "
                       f"{self.maneuver} in {hours}" + (f"; not met: {', '.join(missed)}" if len(missed) <= 4 else ""))
        if self.range_check is not None and not self.range_check.met:
            out.append(f"  {self.range_check.line()}")
            if self.range_remedy:
                out.append(f"  what to do about the range: {self.range_remedy}")
        cannot = self._named("cannot")
        if cannot:
            worst = max(cannot, key=lambda c: c.bound if not np.isnan(c.bound) else c.sigma)
            ratio = worst.bound if not np.isnan(worst.bound) else worst.sigma
            what = ", ".join(f"{c.name} {c.bound if not np.isnan(c.bound) else c.sigma:.2f}x" for c in cannot)
            if any(not np.isnan(c.bound) for c in cannot):
                text = (f"  cannot be met with this maneuver in {hours}: {what} (Cramer-Rao bound / requirement; "
                        f"{worst.name}: {worst.amount(ratio)} against {worst.amount(1.0)}), so no estimator reaches "
                        "them")
            else:  # no bound of the flown maneuver here (a recording): the estimate's own 1-sigma says it
                text = (f"  not met by the data of this run ({hours}): {what} (1-sigma / requirement; "
                        f"{worst.name}: {worst.amount(ratio)} against {worst.amount(1.0)})")
            if self.maneuver_covers_run:
                falls = "the bound" if not np.isnan(worst.bound) else "the 1-sigma"
                text += (f"; this maneuver needs about {self.duration_s * ratio ** 2 / 3600:.2f} h ({falls} falls "
                         "as 1/sqrt(T))")
            out.append(text + ".")
            if self.remedy:
                out.append(f"  what to do: {self.remedy}")
        for c in self._named("estimator"):
            if np.isnan(c.sigma):
                out.append(f"  {c.name}: not determined by the data (NaN), though the bound ({c.amount(c.bound)}) is "
                           "within the requirement")
            else:
                out.append(f"  {c.name}: the reported 1-sigma {c.amount(c.sigma)} exceeds the requirement though the "
                           f"bound ({c.amount(c.bound)}) is within it: the estimator does not reach the bound")
        low = [c for c in self.checks if not np.isnan(c.bound) and c.bound > 0 and c.sigma / c.bound
               < _SIGMA_OVER_BOUND[0]]
        high = [c for c in self.checks if not np.isnan(c.bound) and c.bound > 0 and c.sigma / c.bound
                > _SIGMA_OVER_BOUND[1]]
        if low:
            out.append(f"  estimator: reported 1-sigma below the Cramer-Rao bound (overconfident) on "
                       f"{', '.join(f'{c.name} {c.sigma / c.bound:.2f}x' for c in low)}")
        if high:
            out.append(f"  estimator: reported 1-sigma above the Cramer-Rao bound on "
                       f"{', '.join(f'{c.name} {c.sigma / c.bound:.2f}x' for c in high)}")
        wild = self._inconsistent()
        if wild:
            out.append(f"  estimator: error beyond {_ERROR_SIGMAS:g} sigma on "
                       f"{', '.join(f'{c.name} {abs(c.error) / c.sigma:.1f}' for c in wild)}: "
                       "the estimate or its 1-sigma is off")
        out.extend(f"  {w}" for w in self.warnings)
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``all_met``, ``met`` / ``cannot`` / ``estimator`` (names), ``inconsistent`` (names whose
        error is beyond 3 sigma), per parameter ``sigma``, ``bound``, ``error`` as fractions of the requirement,
        and ``warnings``."""
        def num(x: float) -> float | None:
            return None if np.isnan(x) else float(x)

        return {"all_met": self.all_met, "duration_s": self.duration_s, "maneuver": self.maneuver,
                **{s: [c.name for c in self._named(s)] for s in ("met", "cannot", "estimator")},
                "inconsistent": [c.name for c in self._inconsistent()],
                "over_requirement": {c.name: {"sigma": num(c.sigma), "bound": num(c.bound), "error": num(c.error)}
                                     for c in self.checks},
                "remedy": self.remedy, "warnings": list(self.warnings),
                "range": None if self.range_check is None else self.range_check.to_dict()}


def _sigma(cov: np.ndarray) -> np.ndarray:
    return np.sqrt(np.clip(np.diag(np.asarray(cov, dtype=float)), 0.0, None))


def judge(table: EstimateTable, bound: Sequence[float] | None, duration_s: float, maneuver: str, *,
          remedy: str = "", maneuver_covers_run: bool = True, warnings: Sequence[str] = (),
          range_check: RangeCheck | None = None, range_remedy: str = "") -> Verdict:
    """The verdict of ``table``.

    Parameters
    ----------
    table : EstimateTable
        Final estimates of both GRS (truth where known).
    bound : sequence of float, optional
        (12,) Cramer-Rao bound / requirement of the flown maneuver and duration, in the order
        ``grs1.G_Pphi .. grs1.d_z, grs2.G_Pphi .. grs2.d_z``
        (``design.evaluate.requirement_ratios``); None: unknown.
    duration_s : float
        Length of the run [s].
    maneuver : str
        What was flown, for the text (``"the paper's preset"``).
    remedy : str
        What to do about requirements that cannot be met (a command line).
    maneuver_covers_run : bool
        The maneuver lasts the whole run (then a longer run of it lowers the bound as 1/sqrt(T)).
    warnings : sequence of str
        Lines to append (the simulator's warnings).
    range_check : RangeCheck, optional
        The simulator's range check: the GRS linear range requirement (None: unknown, not judged).
    range_remedy : str
        What to do about an unmet range requirement.
    """
    bound_arr = np.full(12, np.nan) if bound is None else np.asarray(bound, dtype=float)
    checks = []
    for i, r in enumerate(table.grs):
        g, d = np.asarray(r.scale_factors, dtype=float), np.asarray(r.com_offset_m, dtype=float)
        g_ref = np.abs(r.scale_factors_truth if r.scale_factors_truth is not None else g)
        g_sig = _sigma(r.scale_factors_cov) / g_ref / SCALE_FACTOR_REQUIREMENT_REL
        d_sig = _sigma(r.com_offset_cov) / COM_OFFSET_REQUIREMENT_M
        g_err = (np.full(3, np.nan) if r.scale_factors_truth is None
                 else (g - r.scale_factors_truth) / g_ref / SCALE_FACTOR_REQUIREMENT_REL)
        d_err = (np.full(3, np.nan) if r.com_offset_truth_m is None
                 else (d - r.com_offset_truth_m) / COM_OFFSET_REQUIREMENT_M)
        for k in range(3):
            checks.append(ParameterCheck(f"grs{r.grs_id}.{_G_NAMES[k]}", float(g_sig[k]), float(bound_arr[6 * i + k]),
                                         float(g_err[k]), 100 * SCALE_FACTOR_REQUIREMENT_REL, "%"))
        for k in range(3):
            checks.append(ParameterCheck(f"grs{r.grs_id}.{_D_NAMES[k]}", float(d_sig[k]),
                                         float(bound_arr[6 * i + 3 + k]), float(d_err[k]),
                                         COM_OFFSET_REQUIREMENT_M * 1e6, "um"))
    return Verdict(checks, float(duration_s), maneuver, remedy, maneuver_covers_run, list(warnings), range_check,
                   range_remedy)


def _where(fractions: np.ndarray) -> tuple[float, str]:
    g, axis = np.unravel_index(int(np.argmax(fractions)), fractions.shape)
    return float(fractions[g, axis]), f"GRS{g + 1} {'xyz'[axis]}"


def range_warning(values: Mapping[str, Any], design_peak: float | None = None,
                  saturation: bool | None = None) -> str | None:
    """One line from the simulator's ``GRS linear range`` diagnostic values; None: inside the range.

    Parameters
    ----------
    values : mapping
        ``range_m_s2``, ``samples``, ``maneuver_peak_fraction_of_range`` (2x3),
        ``total_peak_fraction_of_range`` (2x3), ``total_samples_outside`` (2x3) as the simulator
        publishes them.
    design_peak : float, optional
        Peak of the noise-free maneuver part / range (the design's figure).
    saturation : bool, optional
        Whether the simulator clipped the readout at the range (None: unknown).
    """
    total = np.asarray(values["total_peak_fraction_of_range"], dtype=float)
    rotation = np.asarray(values["maneuver_peak_fraction_of_range"], dtype=float)
    outside = np.asarray(values.get("total_samples_outside", np.zeros_like(total)), dtype=float)
    total_peak, total_at = _where(total)
    rot_peak, rot_at = _where(rotation)
    if total_peak <= 1.0 and rot_peak <= 1.0:
        return None
    samples = max(int(values.get("samples", 0)), 1)
    worst, worst_at = _where(outside)
    text = (f"simulator: the GRS linear readout was beyond its +-{float(values['range_m_s2']):.0e} m/s^2 range in "
            f"{worst / samples:.1%} of the samples ({worst_at}; {int(np.count_nonzero(outside))} of the 6 TM axes), "
            f"peak {total_peak:.0%} ({total_at})")
    if rot_peak > 1.0 and (design_peak is None or design_peak > 1.0):
        return text + (f": the maneuver itself drives it out (rotation part {rot_peak:.0%}, {rot_at}); lower its "
                       "amplitude, or let taiji2 design choose one inside the range")
    alone = "" if design_peak is None else f"{design_peak:.0%} noise-free, "
    clipped = ("clipped there in the simulation, as a real GRS saturates" if saturation else
               "not clipped in the simulation (grs.readout_saturation: false), a real GRS would saturate there"
               if saturation is False else "a real GRS saturates there")
    return text + (f": noise (thruster force noise) on top of the maneuver, which peaks at {alone}{rot_peak:.0%} with "
                   f"the torque noise; {clipped} (docs/physics_model.md section 8). Room for the noise: taiji2 design, "
                   "whose default keeps the maneuver's peak + 3.29 sigma of the noise inside the range (a longer run)")
