"""Where the gap lies: residual power against the nominal noise, per channel, band and segment.

For a channel c the normalised periodogram ``p_k = |Y_c(k)|^2 / S_cc(k)`` of the residual is,
under the nominal model, a sequence of independent unit exponentials (the channel spectra of
:mod:`.spectral` are exact); so is that of the channel's *innovation* given the other channels
(``view = "conditional"``, :meth:`.spectral.NoiseSpectrum.normalised`), which is far more
sensitive where channels share a noise. A *location* is a view, a channel, a frequency band, a bin
kind (the bins within one bin of a maneuver harmonic, or the continuum between them) and a time
segment:

- whole run: gap ``R = mean_k p_k`` over the K bins; ``K R ~ Gamma(K, 1)``;
- segment (a third of the run): the band-limited whitened series ``x_t`` (inverse DFT of
  ``Y_c / sqrt(S_cc)`` on the band) has the power ``R = mean_t x_t^2 / E[x^2]`` on the segment,
  approximately ``chi^2_nu / nu`` with ``nu = 2 K L / n`` degrees of freedom (L samples).

Significance = ``-log10 p`` of the upper tail (power excess). A location is significant when its
p-value is below ``alpha / (number of tested locations)`` (Bonferroni).

Missing samples. The epochs that hold an estimate (bridged across a lost sample, or a command lost where
it changed: ``DiagnosisInput.filled``) are not data: their residual carries no noise of its own, and the
relations between channels that the conditional view relies on (the GRS's common noise seen by the star
tracker and the torque channel) do not hold there, so a burst of a few such epochs reads as a strong local
gap. The scan treats them as missing (:func:`scan_keep`, :func:`masked_views`): the whitened series of
each view is set to zero on those epochs and the epochs next to them (the channels' stencil: the
whitened residual of a sample's error lies within one epoch of it, measured on the type1 spectra; the
AR(1) prewhitening of ``lin_common`` leaves 14 % of it further), and each location's expectation and
degrees of freedom count the L epochs kept only: a whole-run ``R = mean_k |Y'_k|^2 / (L / n)`` with
``2 K L / n`` degrees of freedom (conservative: the mask correlates neighbouring bins, which reduces the
effective degrees of freedom by at most that factor), a segment's with its own L.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincc

from taiji2_estimator_pkg.diagnosis.channels import CHANNELS

__all__ = ["Location", "LocationGrid", "log10_tail", "masked_views", "scan_keep", "scan_locations", "time_window"]

_MIN_DOF = 4.0  # fewest degrees of freedom of a tested location (a Gamma tail is meaningless below)
#: epochs before and after an estimated one left out of the scan (the channels' stencil after whitening)
MASK_BEFORE, MASK_AFTER = 1, 2


def scan_keep(filled: np.ndarray | None, n: int) -> np.ndarray | None:
    """(n,) float, 1 on the epochs the location scan uses, 0 on the estimated ones and their neighbours
    (``MASK_BEFORE`` before, ``MASK_AFTER`` after); None when every epoch holds received data."""
    if filled is None or not np.any(filled):
        return None
    estimated = np.asarray(filled, dtype=bool)
    dropped = estimated.copy()
    for shift in range(1, MASK_AFTER + 1):
        dropped[shift:] |= estimated[:-shift]
    for shift in range(1, MASK_BEFORE + 1):
        dropped[:-shift] |= estimated[shift:]
    return (~dropped).astype(np.float64)


def masked_views(views: dict[str, np.ndarray], keep: np.ndarray | None) -> dict[str, np.ndarray]:
    """The views with the epochs left out of the scan set to zero in their whitened series.

    Parameters
    ----------
    views : dict of str to numpy.ndarray
        (K, c) unit-variance residual DFTs (bins 1..K, K = (n-1)//2).
    keep : numpy.ndarray or None
        (n,) :func:`scan_keep`; None returns ``views`` unchanged.

    Returns
    -------
    dict of str to numpy.ndarray
        (K, c) DFTs of the masked whitened series (expectation ``L / n`` per bin, L the epochs kept).
    """
    if keep is None:
        return views
    n = keep.shape[0]
    out = {}
    for name, view in views.items():
        spectrum = np.zeros((n // 2 + 1, *view.shape[1:]), dtype=np.complex128)
        spectrum[1:1 + view.shape[0]] = view
        series = np.fft.irfft(spectrum, n=n, axis=0) * np.sqrt(n)
        series *= keep.reshape(-1, *([1] * (series.ndim - 1)))
        out[name] = np.fft.rfft(series, axis=0)[1:1 + view.shape[0]] / np.sqrt(n)
    return out


def log10_tail(shape: np.ndarray | float, value: np.ndarray | float) -> np.ndarray:
    """``-log10 P(Gamma(shape, 1) >= value)``, robust far in the tail.

    Parameters
    ----------
    shape : array_like
        Gamma shape (number of complex bins, or half the chi-square degrees of freedom).
    value : array_like
        Observed sum of unit-mean exponentials.

    Returns
    -------
    numpy.ndarray
        Significance, >= 0.
    """
    a = np.asarray(shape, dtype=np.float64)
    x = np.asarray(value, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = gammaincc(a, x)
        direct = -np.log10(np.where(p > 0, p, 1.0))
        # far tail: log Q(a, x) ~ (a - 1) log x - x - lgamma(a) + log(1 + (a-1)/x + ...)
        from scipy.special import gammaln

        asymptotic = -((a - 1.0) * np.log(np.maximum(x, 1e-300)) - x - gammaln(a)
                       + np.log1p(np.maximum(a - 1.0, 0.0) / np.maximum(x, 1e-300))) / np.log(10.0)
    return np.where(p > 1e-280, np.maximum(direct, 0.0), np.maximum(asymptotic, 0.0))


@dataclass(frozen=True)
class Location:
    """One tested location.

    Attributes
    ----------
    channel : str
        Channel name (:data:`.channels.CHANNELS`).
    view : str
        ``"marginal"`` (the channel against its own nominal spectrum) or ``"conditional"`` (its
        innovation given the other channels).
    band_hz : tuple of float
        [lo, hi) [Hz].
    kind : str
        ``"harmonics"`` (bins within one bin of a maneuver harmonic) or ``"continuum"``.
    segment_s : tuple of float
        [t0, t1] of the time segment [s].
    segment : str
        ``"all"``, ``"early"``, ``"middle"``, ``"late"``.
    gap : float
        Residual power / nominal power (1 under the nominal model).
    dof : float
        Degrees of freedom of the test (2 per complex bin).
    significance : float
        ``-log10 p`` of the excess.
    significant : bool
        Below the Bonferroni-corrected level.
    """

    channel: str
    view: str
    band_hz: tuple[float, float]
    kind: str
    segment_s: tuple[float, float]
    segment: str
    gap: float
    dof: float
    significance: float
    significant: bool = False
    window_s: tuple[float, float] | None = None
    window_resolution_s: float | None = None

    def to_dict(self) -> dict[str, object]:
        """JSON form."""
        out: dict[str, object] = {
            "channel": self.channel, "view": self.view, "band_hz": [float(self.band_hz[0]), float(self.band_hz[1])],
            "kind": self.kind, "segment": self.segment,
            "segment_s": [float(self.segment_s[0]), float(self.segment_s[1])],
            "gap": float(self.gap), "dof": float(self.dof), "significance": float(self.significance),
            "significant": bool(self.significant)}
        if self.window_s is not None:
            out["window_s"] = [float(self.window_s[0]), float(self.window_s[1])]
            out["window_resolution_s"] = float(self.window_resolution_s or 0.0)
        return out


@dataclass(frozen=True)
class LocationGrid:
    """Bands and bin kinds of a record.

    Parameters
    ----------
    n : int
        Record length.
    sample_rate_hz : float
        fs [Hz].
    band_edges_hz : sequence of float
        Band edges [Hz]; the first band starts at the first bin, the last ends below Nyquist.
    maneuver_period_s : float
        Square-wave period [s] (harmonics at h / P).
    harmonic_halfwidth : int
        Bins on either side of a harmonic that count as "harmonics".
    """

    n: int
    sample_rate_hz: float
    band_edges_hz: tuple[float, ...]
    maneuver_period_s: float
    harmonic_halfwidth: int = 1

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Frequencies of the bins 1 .. (n-1)//2 [Hz]."""
        return np.arange(1, (self.n - 1) // 2 + 1) * self.sample_rate_hz / self.n

    def harmonic_mask(self) -> np.ndarray:
        """(K,) True on bins within ``harmonic_halfwidth`` of a maneuver harmonic."""
        bins = np.arange(1, (self.n - 1) // 2 + 1)
        spacing = self.n / (self.sample_rate_hz * self.maneuver_period_s)  # bins per harmonic
        if not np.isfinite(spacing) or spacing <= 0:
            return np.zeros(bins.shape, dtype=bool)
        nearest = np.maximum(np.rint(bins / spacing), 1.0) * spacing
        return np.abs(bins - nearest) <= self.harmonic_halfwidth + 0.5

    def cells(self) -> list[tuple[tuple[float, float], str, np.ndarray]]:
        """(band, kind, bin mask) of every band and kind with enough bins."""
        freq = self.frequencies_hz
        harmonic = self.harmonic_mask()
        edges = list(self.band_edges_hz)
        out = []
        for lo, hi in itertools.pairwise(edges):
            in_band = (freq >= lo) & (freq < hi)
            for kind, mask in (("harmonics", in_band & harmonic), ("continuum", in_band & ~harmonic)):
                if 2.0 * np.count_nonzero(mask) >= _MIN_DOF:
                    out.append(((lo, hi), kind, mask))
        return out


def scan_locations(views: dict[str, np.ndarray], grid: LocationGrid, t_s: np.ndarray, segments: int = 3,
                   alpha: float = 0.01, channels: Sequence[int] | None = None, keep: np.ndarray | None = None
                   ) -> tuple[list[Location], int, float]:
    """Test every location of a residual.

    Parameters
    ----------
    views : dict of str to numpy.ndarray
        ``{"marginal": ..., "conditional": ...}``: (K, 15) residual DFTs normalised to unit variance
        under the nominal model (bins 1..K = (n-1)//2).
    grid : LocationGrid
        Bands and kinds.
    t_s : numpy.ndarray
        (n,) sample times [s] (segment bounds).
    segments : int
        Number of equal time segments tested besides the whole run (0: whole run only).
    alpha : float
        Family-wise level of the Bonferroni threshold.
    channels : sequence of int, optional
        Channels to scan (default all).
    keep : numpy.ndarray, optional
        (n,) epochs used (:func:`scan_keep`), the views already masked (:func:`masked_views`): each
        location's expectation and degrees of freedom count the kept epochs only. Default: all.

    Returns
    -------
    locations : list of Location
        Sorted by decreasing significance.
    n_tests : int
        Number of tested locations.
    threshold : float
        Significance threshold ``-log10(alpha / n_tests)``.
    """
    n = grid.n
    names = ("early", "middle", "late") if segments == 3 else tuple(f"part{i + 1}" for i in range(segments))
    bounds = np.linspace(0, n, segments + 1).astype(int) if segments else np.array([0, n])
    chosen = range(len(CHANNELS)) if channels is None else channels
    kept = np.ones(n) if keep is None else np.asarray(keep, dtype=np.float64)
    share = float(np.sum(kept)) / n  # L / n
    kept_in = np.concatenate(([0.0], np.cumsum(kept)))
    records = []
    cells = grid.cells()
    for view, normalised_all in views.items():
        power = np.abs(normalised_all) ** 2
        for c in chosen:
            for band, kind, mask in cells:
                count = int(np.count_nonzero(mask))
                shape = count * share  # half the degrees of freedom
                ratio = float(np.mean(power[mask, c])) / share if share > 0 else 0.0
                records.append((CHANNELS[c], view, band, kind, (float(t_s[0]), float(t_s[-1])), "all", ratio,
                                2.0 * shape, float(log10_tail(shape, shape * ratio))))
                if not segments:
                    continue
                spectrum = np.zeros(n // 2 + 1, dtype=np.complex128)
                spectrum[1:1 + mask.shape[0]][mask] = normalised_all[mask, c]
                series = np.fft.irfft(spectrum, n=n) * np.sqrt(n)
                expected = 2.0 * count / n  # E[x_t^2] for unit-variance complex bins
                for name, start, stop in zip(names, bounds[:-1], bounds[1:], strict=True):
                    used = kept_in[stop] - kept_in[start]
                    dof = 2.0 * count * used / n
                    if dof < _MIN_DOF:
                        continue
                    ratio_seg = float(np.sum(series[start:stop] ** 2) / (expected * used))
                    records.append((CHANNELS[c], view, band, kind, (float(t_s[start]), float(t_s[stop - 1])), name,
                                    ratio_seg, dof, float(log10_tail(0.5 * dof, 0.5 * dof * ratio_seg))))
    n_tests = len(records)
    threshold = float(-np.log10(alpha / max(n_tests, 1)))
    locations = [Location(ch, view, band, kind, seg, name, gap, dof, sig, sig >= threshold)
                 for ch, view, band, kind, seg, name, gap, dof, sig in records]
    locations.sort(key=lambda loc: -loc.significance)
    return locations, n_tests, threshold


def time_window(normalised: np.ndarray, mask: np.ndarray, t_s: np.ndarray) -> tuple[tuple[float, float], float]:
    """Where in time a location's excess lies: the half-maximum interval of its local gap.

    The band-limited whitened series of the location (as in :func:`scan_locations`) gives the local
    gap ``x_t^2 / E[x^2]``, smoothed over three correlation times (``n dt / K`` for the K bins of
    the location: the resolution, over which a transient is smeared); the window is the contiguous
    interval around its maximum where its excess over 1 stays above half the maximum's. A transient
    gives a window of its duration plus the resolution; an effect that starts mid-run, the span from
    its onset on; a gap spread over the run, the whole run.

    Parameters
    ----------
    normalised : numpy.ndarray
        (K,) unit-variance residual DFT of the channel (bins 1..K).
    mask : numpy.ndarray
        (K,) bins of the location.
    t_s : numpy.ndarray
        (n,) sample times [s].

    Returns
    -------
    window : tuple of float
        (start, end) [s].
    resolution : float
        [s].
    """
    n = t_s.shape[0]
    count = max(int(np.count_nonzero(mask)), 1)
    spectrum = np.zeros(n // 2 + 1, dtype=np.complex128)
    spectrum[1:1 + mask.shape[0]][mask] = normalised[mask]
    series = np.fft.irfft(spectrum, n=n) * np.sqrt(n)
    excess = series ** 2 / (2.0 * count / n) - 1.0
    dt = float(t_s[1] - t_s[0]) if n > 1 else 0.0
    resolution = n * dt / count
    width = int(min(max(3.0 * n / count, 1.0), max(n // 4, 1)))
    cumulative = np.concatenate(([0.0], np.cumsum(excess)))
    half = width // 2
    lo = np.clip(np.arange(n) - half, 0, n)
    hi = np.clip(np.arange(n) - half + width, 0, n)
    level = (cumulative[hi] - cumulative[lo]) / np.maximum(hi - lo, 1)
    peak = int(np.argmax(level))
    above = level >= 0.5 * level[peak]
    below = np.flatnonzero(~above)
    before, after = below[below < peak], below[below > peak]
    start = int(before[-1]) + 1 if before.size else 0
    end = int(after[0]) - 1 if after.size else n - 1
    return (float(t_s[start]), float(t_s[end])), resolution
