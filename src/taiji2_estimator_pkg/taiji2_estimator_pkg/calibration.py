"""Offline calibration of a whole recorded experiment: the estimator cores run in bulk on arrays.

``align_streams`` puts the star tracker and both GRS on one regular 1/fs grid (missing samples are
NaN rows, which the cores treat as missing); ``calibrate`` runs the scale-factor and c.m.-offset
cores in bulk and returns an :class:`~taiji2_estimator_pkg.report.EstimateTable` with the counts of
samples used and rejected, per stream and reason. No middleware: arrays in, numbers out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taiji2_estimator_pkg.core.com_offset.estimate import ComOffsetEstimate
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.pipeline import calibrate as pipeline_calibrate
from taiji2_estimator_pkg.report import EstimateTable, GrsResult

GRS_IDS = (1, 2)
#: A stamp further than this fraction of a sample period from the grid is not on the 1/fs grid.
GRID_TOLERANCE = 0.25


@dataclass
class AlignedRecord:
    """Star tracker and both GRS on one regular grid (NaN rows: missing)."""

    t_s: np.ndarray
    quat_xyzw: np.ndarray
    voltages_v: np.ndarray
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    #: stream -> grid rows without a sample of it (NaN rows: missing, not rejected)
    missing: dict[str, int] = field(default_factory=dict)

    def count(self, stream: str, reason: str, n: int) -> None:
        if n:
            inner = self.rejected.setdefault(stream, {})
            inner[reason] = inner.get(reason, 0) + int(n)


def align_streams(star_t_ns: np.ndarray, quat_xyzw: np.ndarray, grs: Mapping[int, tuple[np.ndarray, np.ndarray]],
                  sample_rate_hz: float) -> AlignedRecord:
    """Put the streams on the 1/fs grid that starts at the earliest stamp.

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
        Duplicate stamps (first kept) and stamps off the grid are counted as rejected; grid rows
        without a sample of a stream are counted as missing.

    Raises
    ------
    ValueError
        If no stream has any sample.
    """
    dt_ns = round(1e9 / sample_rate_hz)
    streams = {"star_tracker": (np.asarray(star_t_ns, dtype=np.int64), np.asarray(quat_xyzw, dtype=np.float64))}
    for gid, (t_ns, volts) in grs.items():
        streams[f"grs{gid}"] = (np.asarray(t_ns, dtype=np.int64), np.asarray(volts, dtype=np.float64))
    starts = [t.min() for t, _ in streams.values() if t.size]
    if not starts:
        raise ValueError("no samples on any raw topic")
    t0 = int(min(starts))
    ends = [t.max() for t, _ in streams.values() if t.size]
    n = round((max(ends) - t0) / dt_ns) + 1
    record = AlignedRecord(t_s=(t0 + np.arange(n, dtype=np.int64) * dt_ns) / 1e9,
                           quat_xyzw=np.full((n, 4), np.nan), voltages_v=np.full((n, len(GRS_IDS), 6), np.nan))
    for name, (t_ns, values) in streams.items():
        record.missing[name] = n
        if not t_ns.size:
            continue
        position = (t_ns - t0) / dt_ns
        index = np.rint(position).astype(np.int64)
        on_grid = np.abs(position - index) <= GRID_TOLERANCE
        record.count(name, "off_grid_stamp", int(np.count_nonzero(~on_grid)))
        index, rows = index[on_grid], values[on_grid]
        order = np.argsort(index, kind="stable")
        index, rows = index[order], rows[order]
        first = np.ones(index.size, dtype=bool)
        first[1:] = index[1:] != index[:-1]
        record.count(name, "duplicate_stamp", int(np.count_nonzero(~first)))
        index, rows = index[first], rows[first]
        record.missing[name] = n - int(index.size)
        if name == "star_tracker":
            record.quat_xyzw[index] = rows
        else:
            record.voltages_v[index, GRS_IDS.index(int(name[3:]))] = rows
    return record


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
        (stream -> grid samples without a message) and ``extra["samples"]``.
    """
    if method not in ("gls", "paper"):
        raise ValueError(f"method: {method!r} is not one of gls, paper")
    result = pipeline_calibrate(record.t_s, record.quat_xyzw, record.voltages_v, instrument, GRS_IDS, method)
    g, d = result.scale_factors, result.com_offsets
    rejected = _merge(record.rejected, _estimator_rejections(record, g.rejected, d.rejected))
    total_rejected = sum(sum(v.values()) for v in rejected.values())
    results = []
    for gid in GRS_IDS:
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
                                **_com_offset_extra(d)})


def _com_offset_extra(d: ComOffsetEstimate) -> dict[str, Any]:
    """The c.m.-offset stage's noise check and, for the joint estimator, G re-estimated with d."""
    out: dict[str, Any] = {"com_offset_noise": {"nis_mean": float(d.nis_mean), "nis_band": float(d.nis_band),
                                                "noise_adjusted": bool(d.noise_adjusted)}}
    if d.scale_factors_joint is not None:
        out["joint"] = {"scale_factors": d.scale_factors_joint.tolist(),
                        "scale_factors_cov": d.scale_factor_covariance_joint.tolist(),
                        "com_offset_scale_factors_cov": d.scale_factor_cross_covariance.tolist()}
    return out
