"""The ground's Yamcs parameters (mcs/ground_parameters.py): every value set is a declared parameter, and the
link statistics per stream come from the reception record's counts."""

from __future__ import annotations

import math

import pytest

from taiji2_ground_pkg.mcs.ground_parameters import (
    MISSING_CRITICAL,
    MISSING_WARNING,
    parameter_specs,
    reception_values,
    verdict_values,
)
from taiji2_runtime.packets.definition import STREAMS


def _counts(received, missing, duplicate=0, out_of_order=0, held=0):
    return {"received": received, "released": received - duplicate - held, "duplicate": duplicate,
            "out_of_order": out_of_order, "missing": missing, "held": held}


def test_reception_values_per_stream_and_in_total():
    counts = {"star_tracker": _counts(980, 20, duplicate=3, out_of_order=7), "grs1": _counts(1000, 0, held=2),
              "grs2": _counts(0, 0), "unknown_stream": _counts(5, 5)}
    record = {"counts": counts, "released_through_s": {"star_tracker": 99.9, "grs1": 98.0, "grs2": None},
              "ground_time_s": 1234.5}
    values = reception_values(record)
    declared = {s.name for s in parameter_specs()}
    assert set(values) <= declared  # nothing Yamcs would refuse (an unknown stream is not a parameter)
    assert not any(k.startswith("link_unknown_stream") for k in values)
    st = counts["star_tracker"]
    assert values["link_star_tracker_missing_fraction"] == 20 / (20 + st["released"])
    assert (values["link_star_tracker_duplicate"], values["link_star_tracker_out_of_order"]) == (3.0, 7.0)
    assert values["link_grs1_held"] == 2.0 and values["link_grs1_missing_fraction"] == 0.0
    assert "link_grs2_missing_fraction" not in values  # nothing expected yet: undetermined, not 0
    released = sum(c["released"] for c in counts.values())
    assert values["ground_missing_fraction"] == pytest.approx(25 / (25 + released), rel=1e-15)
    assert values["ground_released_through_s"] == 98.0 and values["ground_time_s"] == 1234.5
    assert verdict_values(3, 4) == {"verdict_requirements_met": 3.0, "verdict_requirements_not_met": 1.0}


def test_every_stream_has_its_link_parameters_with_the_missing_fraction_alarm():
    specs = {s.name: s for s in parameter_specs()}
    for stream in STREAMS:
        alarm = specs[f"link_{stream.name}_missing_fraction"]
        assert (alarm.warning_high, alarm.critical_high) == (MISSING_WARNING, MISSING_CRITICAL)
        for k in ("received", "duplicate", "out_of_order", "missing", "held"):
            assert specs[f"link_{stream.name}_{k}"].warning_high is None
    assert len(specs) == len(parameter_specs())  # names unique
    assert all(math.isfinite(s.warning_high) for s in specs.values() if s.warning_high is not None)
