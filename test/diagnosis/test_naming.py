"""The naming rule's verdict (stages/naming.py): which refused variants leave an unexplained gap.

A variant refused for explaining too little of its gap, of a family whose other variant is named, and without
which the final model is better (drop-one BIC score < 0), is redundant: the final scan ran with it in the
model and found nothing left at its cells, and the named variant explains them. Blind benchmark seed 13, set
12: a nonlinearity of GRS1's z readout from an onset, taken first as GRS2's (the differential linear channel
sees both), then as GRS1's; GRS2's variant then explained 0 % and the verdict read "unexplained gap at
lin_diff_z" though nothing remained. Any other refusal still leaves its cells unexplained.
"""

from __future__ import annotations

from taiji2_estimator_pkg.diagnosis.readout_step import StepRival
from taiji2_estimator_pkg.diagnosis.results import EffectReport
from taiji2_estimator_pkg.diagnosis.stages.naming import _apply_naming_rule
from taiji2_estimator_pkg.diagnosis.standing import SHRINK_MIN

LEVEL = 1e-4  # the selection floor's level per candidate (alpha 1 % over 100 candidates)
CELL = {"channel": "lin_diff_z", "band_hz": [0.1, 0.3], "kind": "continuum", "bins": 40, "gap_before": 3.0,
        "gap_after": 1.0, "fraction_explained": 1.0}


def _report(variant: str, score: float, shrink: float, name: str = "readout_nonlinearity",
            expected_z: float | None = None, heldout_z: float = 3.0) -> EffectReport:
    return EffectReport(name=name, variant=variant, magnitude=1e7, sigma=1e6, unit="1/(m s^-2)", score=score,
                        delta_chi2=score + 11.0, n_params=1, accepted=True, shrink=shrink, heldout_z=heldout_z,
                        heldout_expected_z=expected_z, cells=[CELL])


def _verdict(names: list[str]) -> dict:
    return {"effects": names, "unexplained": False, "summary": "explained by " + ", ".join(names),
            "accepted_variants": [], "significant_locations_before": 3}


def test_a_variant_made_redundant_by_a_named_one_of_its_family_leaves_no_gap():
    named, redundant = _report("grs1.z", 200.0, 0.9), _report("grs2.z", -10.7, 0.003)
    verdict = _verdict(["readout_nonlinearity"])
    _apply_naming_rule(verdict, [redundant, named], [], LEVEL, {})
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
        _apply_naming_rule(verdict, [refused, named], [], LEVEL, {})
        assert verdict["unexplained"] and verdict["summary"].startswith("unexplained gap at lin_diff_z"), verdict


def test_an_effect_below_the_naming_level_is_a_fluctuation_not_a_gap():
    """Naming rule 2b (:mod:`.standing`): a drift at 3.9 sigma that the held-out part cannot confirm is not named,
    and leaves no unexplained gap beside the named effect (blind seed 16, set 14); alone, the record reads "no
    significant gap"."""
    named = _report("z", 500.0, 1.0, name="inertia_error")
    drift = _report("grs2.y", 15.2 - 11.0, 1.0, name="scale_factor_drift", expected_z=1.2, heldout_z=2.0)
    verdict = _verdict(["inertia_error", "scale_factor_drift"])
    _apply_naming_rule(verdict, [named, drift], [], LEVEL, {})
    assert verdict["summary"] == "explained by inertia_error" and not verdict["unexplained"], verdict
    assert verdict["rejected"]["scale_factor_drift[grs2.y]"].startswith("a fluctuation") and not drift.accepted
    drift = _report("grs2.y", 15.2 - 11.0, 1.0, name="scale_factor_drift", expected_z=1.2, heldout_z=2.0)
    verdict = _verdict(["scale_factor_drift"])
    _apply_naming_rule(verdict, [drift], [], LEVEL, {})
    assert verdict["summary"] == "no significant gap" and not verdict["unexplained"], verdict


def test_a_nonlinearity_that_a_readout_step_explains_as_well_leaves_its_gap_unexplained():
    """Naming rule 4 (:mod:`.readout_step`): the refused nonlinearity is not named and its cells are the gap."""
    nonlinearity = _report("grs1.x", 100.0, 1.0)
    verdict = _verdict(["readout_nonlinearity"])
    rival = StepRival("grs1.x", 5427.0, 6.3, 14.5)
    _apply_naming_rule(verdict, [nonlinearity], [], LEVEL, {nonlinearity.key: rival})
    assert verdict["unexplained"] and verdict["summary"] == (
        "unexplained gap at lin_diff_z 0.1-0.3 Hz (continuum); a step of the grs1.x readout at 5427 s (no catalog "
        "effect) fits it as well as a readout nonlinearity; no catalog effect explains it"), verdict
    assert verdict["rejected"] == {"readout_nonlinearity[grs1.x]": rival.reason} and not nonlinearity.accepted
    assert rival.reason.startswith("a step of the grs1.x readout at 5427 s (no catalog effect) explains it as well")
