"""Offline calibration of a whole recorded experiment: the estimator cores run in bulk on arrays.

``align_streams`` assigns the star tracker and both GRS to epochs by the one rule of
:mod:`taiji2_estimator_pkg.epochs` (the GRS instants are the epochs; each stream keeps its own
constant time offset, which the scale-factor model takes into account; epochs without a sample of a
stream are NaN rows, which the cores treat as missing); ``calibrate`` runs the scale-factor and
c.m.-offset cores in bulk and returns an :class:`~taiji2_estimator_pkg.report.EstimateTable` with the
counts of samples used and rejected, per stream and reason. A result the data cannot determine raises
:class:`~taiji2_estimator_pkg.epochs.UndeterminedError`. No middleware: arrays in, numbers out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.pipeline import calibrate as pipeline_calibrate
from taiji2_estimator_pkg.epochs import UndeterminedError, grid_streams
from taiji2_estimator_pkg.report import EstimateTable, GrsResult

GRS_IDS = (1, 2)
STREAMS = ("star_tracker", *(f"grs{g}" for g in GRS_IDS))


@dataclass
class AlignedRecord:
    """Star tracker and both GRS assigned to the epochs (NaN rows: missing).

    Attributes
    ----------
    t_s : numpy.ndarray
        (n,) epoch instants (the GRS sampling instants) [s].
    quat_xyzw : numpy.ndarray
        (n, 4) star-tracker readout assigned to each epoch (taken ``star_tracker_offset_s`` after it).
    voltages_v : numpy.ndarray
        (n, 2, 6) GRS voltages [V].
    rejected : dict
        Stream -> reason -> samples refused.
    missing : dict
        Stream -> epochs without a sample of it (NaN rows: missing, not rejected).
    offsets_s : dict
        Stream -> its constant time offset after the GRS instants (the rule's slot) [s].
    phase_s : dict
        Stream -> median of its stamps' offsets from their epochs [s] (the robust phase, reported).
    """

    t_s: np.ndarray
    quat_xyzw: np.ndarray
    voltages_v: np.ndarray
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    #: stream -> grid rows without a sample of it (NaN rows: missing, not rejected)
    missing: dict[str, int] = field(default_factory=dict)
    offsets_s: dict[str, float] = field(default_factory=dict)
    phase_s: dict[str, float] = field(default_factory=dict)

    @property
    def star_tracker_offset_s(self) -> float:
        """Time of each star-tracker readout after its epoch's GRS instant [s] (constant)."""
        return float(self.offsets_s.get("star_tracker", 0.0))

    def count(self, stream: str, reason: str, n: int) -> None:
        if n:
            inner = self.rejected.setdefault(stream, {})
            inner[reason] = inner.get(reason, 0) + int(n)


def align_streams(star_t_ns: np.ndarray, quat_xyzw: np.ndarray, grs: Mapping[int, tuple[np.ndarray, np.ndarray]],
                  sample_rate_hz: float) -> AlignedRecord:
    """Assign the streams to epochs by the one rule (:func:`taiji2_estimator_pkg.epochs.grid_streams`).

    Parameters
    ----------
    star_t_ns : numpy.ndarray
        (n,) star-tracker stamps [ns].
    quat_xyzw : numpy.ndarray
        (n, 4) star-tracker quaternions.
    grs : mapping
        GRS id -> ((m,) stamps [ns], (m, 6) voltages [V]).
    sample_rate_hz : float
        fs [Hz].

    Returns
    -------
    AlignedRecord
        Refused samples counted per stream and reason (:data:`taiji2_estimator_pkg.epochs.REASONS`),
        epochs without a sample of a stream counted as missing.

    Raises
    ------
    UndeterminedError
        If no stream has any sample.
    """
    streams = {"star_tracker": (star_t_ns, np.asarray(quat_xyzw, dtype=np.float64).reshape(-1, 4))}
    for gid, (t_ns, volts) in grs.items():
        streams[f"grs{gid}"] = (t_ns, np.asarray(volts, dtype=np.float64).reshape(-1, 6))
    gridded = grid_streams(streams, 1.0 / sample_rate_hz)
    if gridded.n == 0:
        raise UndeterminedError("star_tracker, grs1, grs2", "no sample on any raw topic")
    voltages = np.full((gridded.n, len(GRS_IDS), 6), np.nan)
    for gid in grs:
        voltages[:, GRS_IDS.index(int(gid))] = gridded.on_grid(f"grs{gid}")
    missing = gridded.missing()
    for name in STREAMS:
        missing.setdefault(name, gridded.n)
    return AlignedRecord(t_s=gridded.t_ns / 1e9, quat_xyzw=gridded.on_grid("star_tracker"), voltages_v=voltages,
                         rejected={k: dict(v) for k, v in gridded.refused.items()}, missing=missing,
                         offsets_s={s: gridded.offset_s(s) for s in gridded.slot_ns},
                         phase_s={s: v / 1e9 for s, v in gridded.phase_ns.items()})


def require_streams(record: AlignedRecord) -> None:
    """Raise :class:`UndeterminedError` naming the first stream without a single sample on an epoch.

    The reason names what became of its samples (refused, by reason) or that it had none.
    """
    for name in STREAMS:
        if record.missing.get(name, 0) >= record.t_s.size:
            refused = record.rejected.get(name, {})
            why = ("every sample refused (" + ", ".join(f"{r} {n}" for r, n in refused.items()) + ")"
                   if refused else "no sample")
            raise UndeterminedError(name, why)


def _merge(*counts: Mapping[str, Mapping[str, int]]) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for table in counts:
        for stream, reasons in table.items():
            for reason, n in reasons.items():
                out.setdefault(stream, {})[reason] = out.setdefault(stream, {}).get(reason, 0) + int(n)
    return out


def _estimator_rejections(record: AlignedRecord, *stages: Mapping[str, Mapping[str, int]]) -> dict[str, dict[str, int]]:
    """The rejections of the estimator stages, each sample counted once.

    Both stages check the same record with the same input rules, so an input rejection is counted
    by each: per stream and reason the larger count is kept (gating, which each stage does to its
    own residuals, is summed). The NaN rows that :func:`align_streams` leaves where a stream has no
    sample are missing data, not rejected samples: they are taken off ``nan_or_inf``.
    """
    out: dict[str, dict[str, int]] = {}
    for stage in stages:
        for stream, reasons in stage.items():
            for reason, n in reasons.items():
                seen = out.setdefault(stream, {}).get(reason, 0)
                out[stream][reason] = seen + int(n) if reason == "gated" else max(seen, int(n))
    for stream, missing in record.missing.items():
        reasons = out.get(stream, {})
        if "nan_or_inf" in reasons:
            reasons["nan_or_inf"] -= min(missing, reasons["nan_or_inf"])
            if not reasons["nan_or_inf"]:
                del reasons["nan_or_inf"]
    return {stream: reasons for stream, reasons in out.items() if reasons}


def calibrate(record: AlignedRecord, instrument: InstrumentModel, method: str = "gls") -> EstimateTable:
    """Scale factors and c.m. offsets of both GRS from an aligned record (the core pipeline, in bulk).

    Parameters
    ----------
    record : AlignedRecord
        The data.
    instrument : InstrumentModel
        Nominal model (geometry, noise budget).
    method : str
        ``gls`` (default, honest covariance) or ``paper``.

    Returns
    -------
    EstimateTable
        With ``extra["rejected"]`` (stream -> reason -> count, each sample once), ``extra["missing"]``
        (stream -> grid samples without a message), ``extra["samples"]``, ``extra["determined"]``,
        ``extra["star_tracker_offset_s"]`` (the offset modelled) and ``extra["stream_phase_s"]``
        (each stream's median stamp offset from its epochs).

    Raises
    ------
    UndeterminedError
        A raw stream without a single sample on an epoch (none received, or every one refused).
    """
    if method not in ("gls", "paper"):
        raise ValueError(f"method: {method!r} is not one of gls, paper")
    require_streams(record)
    result = pipeline_calibrate(record.t_s, record.quat_xyzw, record.voltages_v, instrument, GRS_IDS, method,
                                star_tracker_offset_s=record.star_tracker_offset_s)
    g, d = result.scale_factors, result.com_offsets
    rejected = _merge(record.rejected, _estimator_rejections(record, g.rejected, d.rejected))
    results = []
    for gid in GRS_IDS:
        total_rejected = _rejected_for(rejected, gid)
        g_i, g_cov = g.of(gid)
        d_i, d_cov = d.of(gid)
        results.append(GrsResult(grs_id=gid, scale_factors=np.asarray(g_i), scale_factors_cov=np.asarray(g_cov),
                                 com_offset_m=np.asarray(d_i), com_offset_cov=np.asarray(d_cov),
                                 samples_used=int(g.n_samples), samples_rejected=total_rejected,
                                 nis_mean=float(g.nis_mean)))
    diff, diff_cov = d.difference()
    return EstimateTable(method=g.method, grs=results, difference_m=np.asarray(diff),
                         difference_cov=np.asarray(diff_cov),
                         extra={"rejected": rejected, "missing": {k: v for k, v in record.missing.items() if v},
                                "samples": {"epochs": int(record.t_s.size), "scale_factor_updates": int(g.n_samples),
                                            "com_offset_updates": int(d.n_samples)},
                                "determined": bool(g.determined and d.determined),
                                "star_tracker_offset_s": record.star_tracker_offset_s,
                                "stream_phase_s": dict(record.phase_s),
                                **_com_offset_extra(d)})


def _rejected_for(rejected: Mapping[str, Mapping[str, int]], grs_id: int) -> int:
    """The rejected samples of the streams GRS ``grs_id``'s estimates use: the star tracker and its own
    voltages (the command stream and the other GRS's voltages are counted under their own names)."""
    others = tuple(f"grs{g}" for g in GRS_IDS if g != grs_id)
    return sum(sum(reasons.values()) for stream, reasons in rejected.items()
               if "command" not in stream and not any(o in stream for o in others))


def _com_offset_extra(d: ComOffsetEstimate) -> dict[str, Any]:
    """The c.m.-offset stage's noise check and, for the joint estimator, G re-estimated with d."""
    out: dict[str, Any] = {"com_offset_noise": {"nis_mean": float(d.nis_mean), "nis_band": float(d.nis_band),
                                                "noise_adjusted": bool(d.noise_adjusted)}}
    if d.scale_factors_joint is not None:
        out["joint"] = {"scale_factors": d.scale_factors_joint.tolist(),
                        "scale_factors_cov": d.scale_factor_covariance_joint.tolist(),
                        "com_offset_scale_factors_cov": d.scale_factor_cross_covariance.tolist()}
    return out
