"""The naming rule's verdict (stages/naming.py): which refused variants leave an unexplained gap.

A variant refused for explaining too little of its gap, of a family whose other variant is named, and without
which the final model is better (drop-one BIC score < 0), is redundant: the final scan ran with it in the
model and found nothing left at its cells, and the named variant explains them. Blind benchmark seed 13, set
12: a nonlinearity of GRS1's z readout from an onset, taken first as GRS2's (the differential linear channel
sees both), then as GRS1's; GRS2's variant then explained 0 % and the verdict read "unexplained gap at
lin_diff_z" though nothing remained. Any other refusal still leaves its cells unexplained.
"""

from __future__ import annotations

from taiji2_estimator_pkg.diagnosis.results import EffectReport
from taiji2_estimator_pkg.diagnosis.stages.naming import _apply_naming_rule
from taiji2_estimator_pkg.diagnosis.standing import SHRINK_MIN

CELL = {"channel": "lin_diff_z", "band_hz": [0.1, 0.3], "kind": "continuum", "bins": 40, "gap_before": 3.0,
        "gap_after": 1.0, "fraction_explained": 1.0}


def _report(variant: str, score: float, shrink: float, name: str = "readout_nonlinearity") -> EffectReport:
    return EffectReport(name=name, variant=variant, magnitude=1e7, sigma=1e6, unit="1/(m s^-2)", score=score,
                        delta_chi2=score + 11.0, n_params=1, accepted=True, shrink=shrink, heldout_z=3.0,
                        cells=[CELL])


def _verdict(names: list[str]) -> dict:
    return {"effects": names, "unexplained": False, "summary": "explained by " + ", ".join(names),
            "accepted_variants": [], "significant_locations_before": 3}


def test_a_variant_made_redundant_by_a_named_one_of_its_family_leaves_no_gap():
    named, redundant = _report("grs1.z", 200.0, 0.9), _report("grs2.z", -10.7, 0.003)
    verdict = _verdict(["readout_nonlinearity"])
    _apply_naming_rule(verdict, [redundant, named], [])
    assert verdict["summary"] == "explained by readout_nonlinearity" and not verdict["unexplained"], verdict
    assert verdict["accepted_variants"] == ["readout_nonlinearity[grs1.z]"]
    assert verdict["rejected"]["readout_nonlinearity[grs2.z]"].startswith(
        "redundant beside the named readout_nonlinearity[grs1.z]") and not redundant.accepted


def test_a_refused_variant_that_is_not_redundant_leaves_its_gap_unexplained():
    cases = [
        (_report("grs1.z", 200.0, 0.9), _report("grs2.z", 2.0, 0.003)),  # the model is better with it
        # of another family than the named one
        (_report("grs1.z", 200.0, 0.9), _report("grs2.z", -10.7, SHRINK_MIN - 0.2, name="tm_stiffness")),
    ]
    for named, refused in cases:
        verdict = _verdict(["readout_nonlinearity", refused.name])
        _apply_naming_rule(verdict, [refused, named], [])
        assert verdict["unexplained"] and verdict["summary"].startswith("unexplained gap at lin_diff_z"), verdict
