"""The scale-factor gates' spans (core/gate_span.py): one solve per span of data, the estimate of the data
before the span, a gross star-tracker outlier gated anywhere in a span, a resumed run gating as an
uninterrupted one, and no gate on an undetermined new segment."""

import json

import numpy as np
import pytest

from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.core.scale_factor import ScaleFactorEstimator, ScaleFactorOptions

from estimator_support import simulate

SPAN_EPOCHS = 10  # gate_refresh_s 1.0 at 10 Hz


def _record(seed):
    config, out = simulate("type1", 600.0, seed)
    return InstrumentModel.from_layout(config), out


def _reports(sf, out, rows, quats=None):
    quats = out.st_quat_xyzw if quats is None else quats
    return [sf.update(out.t_s[k], quats[k], {1: out.voltages_v[k, 0], 2: out.voltages_v[k, 1]}) for k in rows]


def _nis(reports):
    return np.array([r.nis for r in reports]), np.array([r.nis_grs for r in reports])


def test_the_gates_solve_once_per_span_with_the_data_before_it(monkeypatch):
    instrument, out = _record(41)
    spanned = ScaleFactorEstimator(instrument)
    every = ScaleFactorEstimator(instrument, options=ScaleFactorOptions(gate_refresh_s=0.0))
    solves = []
    solve = ScaleFactorEstimator._snapshot_estimate
    monkeypatch.setattr(ScaleFactorEstimator, "_snapshot_estimate",
                        staticmethod(lambda snapshot: solves.append(snapshot.shape) or solve(snapshot)))
    rows = range(len(out))
    st_spanned, pair_spanned = _nis(_reports(spanned, out, rows))
    n_spanned = len(solves)
    st_every, pair_every = _nis(_reports(every, out, rows))
    n_every = len(solves) - n_spanned
    gated = np.isfinite(st_spanned)
    first_gated = int(np.argmax(gated))
    # once determined: one solve per span (against one per epoch); none before (nothing to gate with)
    assert n_spanned == pytest.approx((len(out) - first_gated) / SPAN_EPOCHS, abs=2)
    assert n_every >= len(out) - first_gated  # every epoch from there (a few more: those without a star tracker)
    # at a span's first epoch both test against the data before that epoch: the same NIS (to rounding)
    first = gated & np.isfinite(st_every) & (np.arange(len(out)) % SPAN_EPOCHS == 0)
    assert np.count_nonzero(first) > 400
    np.testing.assert_allclose(st_spanned[first], st_every[first], rtol=1e-9)
    np.testing.assert_allclose(pair_spanned[first], pair_every[first], rtol=1e-9)
    # elsewhere they differ (an older estimate), yet make the same chi-square tests: mean NIS per dof 1
    # (3 dof each; ~4,900 gated epochs: the standard error of the mean per dof is ~0.012, the bounds ~8 of them)
    both = gated & np.isfinite(st_every)
    assert np.count_nonzero(both) > 4000
    assert not np.allclose(st_spanned[both], st_every[both], rtol=1e-9)
    assert 0.9 < np.mean(st_spanned[both]) / 3.0 < 1.1
    assert 0.9 < np.nanmean(pair_spanned[both]) / 3.0 < 1.1


@pytest.mark.parametrize("position", [0, 5, 9])
def test_a_gross_star_tracker_outlier_is_gated_anywhere_in_a_span(position):
    instrument, out = _record(42)
    quats = out.st_quat_xyzw.copy()
    k = 4000 + position
    tilt = 2e-5  # [rad] about x: ~100 sigma of the star tracker, well inside the attitude-jump check
    rotation = np.array([np.sin(tilt / 2), 0.0, 0.0, np.cos(tilt / 2)])
    x1, y1, z1, w1 = rotation
    x2, y2, z2, w2 = quats[k]
    quats[k] = (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)
    sf = ScaleFactorEstimator(instrument)
    _reports(sf, out, range(k), quats)
    report = _reports(sf, out, [k], quats)[0]
    assert not report.accepted and ("star_tracker", "gated") in report.rejections
    st_after, _ = _nis(_reports(sf, out, range(k + 1, len(out)), quats))
    assert sf.filter.n_rejected == 1 and np.all(st_after[np.isfinite(st_after)] < sf.gate)


def test_a_run_resumed_mid_span_gates_as_the_uninterrupted_run():
    instrument, out = _record(43)
    full = ScaleFactorEstimator(instrument)
    st_full, pair_full = _nis(_reports(full, out, range(len(out))))
    first = ScaleFactorEstimator(instrument)
    _reports(first, out, range(4005))  # the checkpoint falls inside a span, the gates at work
    resumed = ScaleFactorEstimator.from_state_dict(instrument, json.loads(json.dumps(first.state_dict())))
    st_resumed, pair_resumed = _nis(_reports(resumed, out, range(4005, len(out))))
    np.testing.assert_allclose(st_resumed, st_full[4005:], rtol=1e-9)
    np.testing.assert_allclose(pair_resumed, pair_full[4005:], rtol=1e-9)
    assert np.all(np.isfinite(st_resumed))


def test_a_new_segment_is_not_gated_with_the_old_segments_snapshot():
    instrument, out = _record(44)
    sf = ScaleFactorEstimator(instrument)
    _reports(sf, out, range(3000))
    segments = sf.filter.n_segments
    gap = round(2 * sf.options.max_bridged_gap_s * instrument.sample_rate_hz)  # beyond the bridged gap
    reports = _reports(sf, out, range(3000 + gap, len(out)))
    assert sf.filter.n_segments == segments + 1
    st, _ = _nis(reports)
    # the new segment's initial state is unknown at its first epoch: no gate until a snapshot determines it,
    # then gated again, and nothing rejected (a stale snapshot gated thousands of epochs)
    assert np.isnan(st[0]) and np.all(np.isfinite(st[SPAN_EPOCHS + 1:]))
    assert sf.filter.n_rejected == 0


def test_a_bad_refresh_is_refused():
    with pytest.raises(ValueError, match="gate_refresh_s"):
        ScaleFactorOptions(gate_refresh_s=-1.0)
    with pytest.raises(ValueError, match="gate_refresh_s"):
        ScaleFactorOptions(gate_refresh_s=float("inf"))
