"""The c.m.-offset gate's spans (core/gate_span.py): one solve per span of data, the estimate of the data
before the span, outliers gated anywhere in a span, and a resumed run gating as an uninterrupted one."""

import json

import numpy as np
import pytest

from taiji2_estimator_pkg.core.com_offset import ComOffsetEstimator
from taiji2_estimator_pkg.core.com_offset.model import ComOffsetOptions
from taiji2_estimator_pkg.core.gate_span import GateSpan
from taiji2_estimator_pkg.core.instrument import InstrumentModel

from estimator_support import simulate, truth

SPAN_EPOCHS = 10  # gate_refresh_s 1.0 at 10 Hz


def _record(seed):
    config, out = simulate("type1", 600.0, seed)
    instrument = InstrumentModel.from_layout(config)
    g_true, _ = truth(config)
    return instrument, out, (g_true, np.diag((5e-4 * g_true) ** 2))


def _nis(co, out, scale_factors, rows, volts=None):
    volts = out.voltages_v if volts is None else volts
    return np.array([co.update(out.t_s[k], {1: volts[k, 0], 2: volts[k, 1]}, out.truth.omega_rad_s[k],
                               scale_factors).nis for k in rows])


def test_the_gate_solves_once_per_span_with_the_data_before_it(monkeypatch):
    instrument, out, scale_factors = _record(31)
    spanned = ComOffsetEstimator(instrument)
    every = ComOffsetEstimator(instrument, options=ComOffsetOptions(gate_refresh_s=0.0))
    solves = []
    solve = ComOffsetEstimator._gate_estimate
    monkeypatch.setattr(ComOffsetEstimator, "_gate_estimate",
                        lambda self, g, info: solves.append(self is spanned) or solve(self, g, info))
    rows = range(len(out))
    nis_spanned, nis_every = _nis(spanned, out, scale_factors, rows), _nis(every, out, scale_factors, rows)
    # one solve per span with data before it (the first span has none), against one per epoch
    assert solves.count(True) == len(out) // SPAN_EPOCHS - 1
    assert solves.count(False) == len(out) - 1
    # at a span's first epoch both test against the data before that epoch: the same NIS (to rounding; the
    # paths are the same algebra on the same numbers)
    first = np.isfinite(nis_every) & (np.arange(len(out)) % SPAN_EPOCHS == 0)
    assert np.count_nonzero(first) > 40
    np.testing.assert_allclose(nis_spanned[first], nis_every[first], rtol=1e-9)
    # elsewhere they differ (an older estimate), yet make the same chi-square test: mean NIS per dof 1
    # (6 dof; ~2,700 gated epochs here: the standard error of the mean per dof is ~0.013, the bound ~8 of them)
    gated = np.isfinite(nis_spanned) & np.isfinite(nis_every)
    assert np.count_nonzero(gated) > 2000
    assert not np.allclose(nis_spanned[gated], nis_every[gated], rtol=1e-9)
    assert 0.9 < np.mean(nis_spanned[gated]) / 6.0 < 1.1


@pytest.mark.parametrize("position", [0, 5, 9])
def test_a_gross_outlier_is_gated_anywhere_in_a_span(position):
    instrument, out, scale_factors = _record(32)
    volts = out.voltages_v.copy()
    k = 4000 + position
    volts[k, 0, 2] += 2.0  # one electrode of GRS1 [V]: far beyond its noise, below saturation
    co = ComOffsetEstimator(instrument)
    _nis(co, out, scale_factors, range(k), volts)
    report = co.update(out.t_s[k], {1: volts[k, 0], 2: volts[k, 1]}, out.truth.omega_rad_s[k], scale_factors)
    assert not report.accepted and ("epoch", "gated") in report.rejections
    nis_after = _nis(co, out, scale_factors, range(k + 1, len(out)), volts)
    assert co.filter.n_rejected == 1 and np.all(nis_after < co.gate)


def test_a_run_resumed_mid_span_gates_as_the_uninterrupted_run():
    instrument, out, scale_factors = _record(33)
    full = ComOffsetEstimator(instrument)
    nis_full = _nis(full, out, scale_factors, range(len(out)))
    first = ComOffsetEstimator(instrument)
    _nis(first, out, scale_factors, range(4005))  # the checkpoint falls inside a span, the gate at work
    resumed = ComOffsetEstimator.from_state_dict(instrument, json.loads(json.dumps(first.state_dict())))
    nis_resumed = _nis(resumed, out, scale_factors, range(4005, len(out)))
    np.testing.assert_allclose(nis_resumed, nis_full[4005:], rtol=1e-9)
    assert np.all(np.isfinite(nis_resumed))


def test_spans_follow_the_grid_and_a_new_segment():
    span = GateSpan(10)
    assert span.starts(0, 1) and not span.starts(9, 1)
    assert span.starts(10, 1) and not span.starts(15, 1)
    assert span.starts(15, 2)  # a new filter segment: a new snapshot at once
    assert span.starts(37, 2) and not span.starts(39, 2)
    with pytest.raises(ValueError, match="at least 1 epoch"):
        GateSpan(0)
    with pytest.raises(ValueError, match="gate_refresh_s"):
        ComOffsetOptions(gate_refresh_s=float("nan"))
