"""Offline first-met data times (the reference of the link report's requirement times) against the bulk path.

``first_met_data_times`` runs the cores epoch by epoch; ``calibrate`` (the bulk path of ``taiji2 calibrate``) of
the record cut at a first-met epoch must meet that requirement, and of the record cut one estimate period
earlier must not. The two paths' covariances agree to 1.5e-13 relative on this record, so the bound is applied
with a 1e-9 relative allowance for rounding (the nearest margins here are 3e-4 relative)."""

from __future__ import annotations

import numpy as np
import pytest

from taiji2_estimator_pkg.calibration import AlignedRecord, align_streams, calibrate
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_estimator_pkg.first_met import first_met_data_times
from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

N = 5200  # 520 s at 10 Hz: every G requirement met (270-497 s for seed 3), no d requirement yet
ROUNDING = 1e-9


@pytest.fixture(scope="module")
def record():
    config = load_config("type1", overrides={"maneuver.duration_s": N / 10})
    out = simulate_batch(config, 3, maneuver_torque_commands(config, N))
    stamps = np.rint(out.t_s * 1e9).astype(np.int64)
    instrument = InstrumentModel.from_layout("type1")
    return instrument, align_streams(stamps, out.st_quat_xyzw, {1: (stamps, out.voltages_v[:, 0]),
                                                                2: (stamps, out.voltages_v[:, 1])},
                                     instrument.sample_rate_hz)


@pytest.fixture(scope="module")
def rows(record):
    instrument, rec = record
    return first_met_data_times(rec, instrument)


def _through(rec: AlignedRecord, k: int) -> AlignedRecord:
    return AlignedRecord(rec.t_s[:k + 1], rec.quat_xyzw[:k + 1], rec.voltages_v[:k + 1])


def _margin(table: dict, row: dict) -> float:
    """sigma / bound of the requirement of ``row`` in a calibrate result (<= 1: met)."""
    grs = table[f"grs{row['grs']}"]
    if row["parameter"].startswith("G_"):
        i = ("G_Pphi", "G_Ptheta", "G_Ppsi").index(row["parameter"])
        sigma = np.sqrt(np.array(grs["scale_factors_cov"])[i, i])
        return float(sigma / (SCALE_FACTOR_REQUIREMENT_REL * abs(grs["scale_factors"][i])))
    i = "xyz".index(row["parameter"][-1])
    return float(np.sqrt(np.array(grs["com_offset_cov"])[i, i]) / COM_OFFSET_REQUIREMENT_M)


def test_first_met_times_agree_with_the_bulk_path_within_one_estimate_period(record, rows):
    instrument, rec = record
    assert [(r["grs"], r["parameter"]) for r in rows] == [
        (g, p) for g in (1, 2) for p in ("G_Pphi", "G_Ptheta", "G_Ppsi", "d_x", "d_y", "d_z")]
    met = [r for r in rows if r["onboard_time_s"] is not None]
    assert {r["parameter"] for r in met} == {"G_Pphi", "G_Ptheta", "G_Ppsi"}
    for row in met:
        k = int(np.searchsorted(rec.t_s, row["onboard_time_s"]))
        assert rec.t_s[k] == row["onboard_time_s"]
        before = int(np.searchsorted(rec.t_s, row["onboard_time_s"] - 1.0))  # the estimate a period earlier
        assert _margin(calibrate(_through(rec, k), instrument).to_dict(), row) <= 1 + ROUNDING, row
        assert _margin(calibrate(_through(rec, before), instrument).to_dict(), row) > 1 - ROUNDING, row
    whole = calibrate(rec, instrument).to_dict()
    for row in rows:
        if row["onboard_time_s"] is None:  # not met by the end: nor by the bulk path on the whole record
            assert _margin(whole, row) > 1 - ROUNDING, row


def test_until_s_stops_the_run(record, rows):
    instrument, rec = record
    cut = first_met_data_times(rec, instrument, until_s=400.0)
    times = {r["parameter"]: r["onboard_time_s"] for r in cut if r["grs"] == 1}
    full = {r["parameter"]: r["onboard_time_s"] for r in rows if r["grs"] == 1}
    for name, t in full.items():
        assert times[name] == (t if t is not None and t <= 400.0 else None), name
    with pytest.raises(ValueError, match="estimate_period_s"):
        first_met_data_times(rec, instrument, estimate_period_s=0.0)
