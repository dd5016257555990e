"""Stage 6, held out: each reported effect fitted on the first part of the run (2/3 by default) and
applied, fixed, to the rest, recalibrated there: the shrink and the gain on the held-out part.

An effect that starts mid-run is held out within its own span: the training part is the first part
after the latest modelled onset (and all before it), the rest is held out. An effect present from the
start is held out on the plain split of the whole run where every modelled onset lies at least a
maneuver period before it (each effect with an onset then has data on both sides): held out after
the latest onset too, a star-tracker noise drawn at 9.4 sigma beside a scale-factor drift from 5,950 s
was tested on the last 1,650 s, where a 1-3 mHz excess has a handful of bins, and refused (blind seed
15, set 7); on the last 3,600 s it is named.

The accepted effects of second-order signature enter both parts as secants at their magnitudes in the whole
run, as in its fit: at first order, a readout nonlinearity of GRS2's psi readout of delta chi2 64,000 left a
residual that a 8.6-sigma scale-factor drift of GRS1 (pair x, whose cells share ang_diff_z with it) absorbed
differently on the two parts; the drift read held-out z = -0.4 where 5.8 +- 1.1 was expected, was refused, and
left its signal as an unexplained gap (blind seed 17, set 46, reference fidelity). With the secant the drift's
held-out power is what a drift's last third holds (expected z 1.3, read 0.3), and the set is explained.

A stack of more than ``FAMILY_VARIANTS_MAX`` accepted variants of one family (:mod:`..standing` rule 3) is also
held out as one (:func:`..evaluation.held_out_group`), its magnitudes trained together: where the family
stands, a member its own check refuses is judged by the family's (:func:`..standing.standing_verdict`). Of the
three misalignment axes of GRS1 of blind seed 17, set 83 (re-run on the reference fidelity without its timing
conventions), x and y were confirmed and z was not (held-out z 0.9 where 3.4 +- 1.2 was expected); refused, it
left its own signal as an unexplained gap. Of three members at 4-7 sigma, one falls short of z = 1 in several
per cent of runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.evaluation import held_out_deterministic, held_out_group, held_out_noise
from taiji2_estimator_pkg.diagnosis.inputs import DiagnosisInput
from taiji2_estimator_pkg.diagnosis.model import NominalModel
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.record import Record, RecordSettings
from taiji2_estimator_pkg.diagnosis.results import EffectReport
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal
from taiji2_estimator_pkg.diagnosis.stages.selection import Selection
from taiji2_estimator_pkg.diagnosis.standing import rule3_stacks

__all__ = ["check_held_out", "held_out_splits"]


def check_held_out(inp: DiagnosisInput, nominal: Nominal, selection: Selection, reports: Sequence[EffectReport],
                   options: DiagnosisOptions, say: Progress) -> list[EffectReport]:
    """The reports with their held-out entries (unchanged when either part is shorter than a maneuver period)."""
    full, model, accepted = nominal.full, nominal.start.model, selection.accepted
    reports = [replace(report, family_heldout=dict(report.family_heldout)) for report in reports]
    starts = [int(np.searchsorted(inp.t_s, full.onsets[c.key])) for c in accepted if c.key in full.onsets]
    split, plain = held_out_splits(inp.n, starts, options.train_fraction, round(model.maneuver_period_s / model.dt_s))
    groups = [(split, reports)] if plain == split else [(plain, [r for r in reports if r.key not in full.onsets]),
                                                         (split, [r for r in reports if r.key in full.onsets])]
    for at, group in groups:
        if group and min(at, inp.n - at) * model.dt_s >= model.maneuver_period_s:
            say(f"held-out check: fit on the first {at * model.dt_s:.0f} s, apply to the last "
                f"{(inp.n - at) * model.dt_s:.0f} s ({', '.join(r.key for r in group)})")
            _held_out(inp, at, model, nominal.g, nominal.d, nominal.start.settings, options, nominal.candidates,
                      nominal.noise, accepted, selection.noise_fit, group, nominal.start.t_mid, nominal.floor[1],
                      full.onsets, nominal.start.fixed, full.secant)
    for group, members in _stacks(accepted).items():  # the family's in-sample gain, for naming rule 2b
        keys = {member.key for member in members}
        names = [name for member in members for name in member.column_names()]
        others = list(full.nuisance) + [name for c in accepted if isinstance(c, Candidate) and c.key not in keys
                                        for name in c.column_names()]
        gain = {"delta_chi2": full.chi2(others) - full.chi2(others + names),
                "n_params": sum(member.n_params for member in members)}
        for report in reports:
            if group in report.family_heldout:
                report.family_heldout[group].update(gain)
    return reports


def _stacks(accepted: Sequence[Candidate | NoiseCandidate]) -> dict[str, list[Candidate]]:
    """The stacks of naming rule 3: more than ``FAMILY_VARIANTS_MAX`` accepted variants of one family or of one
    physics of it (:func:`..standing.family_group`, :func:`..standing.subfamily_group`)."""
    return {group: members for _, group, members in rule3_stacks(accepted)}


def held_out_splits(n: int, onsets: Sequence[int], train_fraction: float, period: int) -> tuple[int, int]:
    """The first held-out sample of the effects with an onset and of those present from the start.

    ``onsets``: the sample indices of the modelled onsets; ``period``: a maneuver period in samples. The
    effects with an onset are held out within the span after the latest one; those present from the start
    on the whole run's split, where every onset lies at least a period before it (else as the others)."""
    start = max(onsets, default=0)
    split = start + round(train_fraction * (n - start))
    plain = round(train_fraction * n)
    return split, (plain if onsets and start + period <= plain else split)


def _held_out(inp: DiagnosisInput, split: int, model: NominalModel, g: np.ndarray, d: np.ndarray,
              settings: RecordSettings, options: DiagnosisOptions, candidates: Sequence[Candidate],
              noise: NoiseCandidate | None, accepted: Sequence[Candidate | NoiseCandidate],
              noise_fit: dict[str, float], reports: list[EffectReport], t_mid: float, floor: float,
              onsets: dict[str, float] | None = None, fixed: Sequence[Any] = (),
              secants: dict[str, float] | None = None) -> None:
    """Fit every reported effect on the training part and apply it to the held-out part. ``secants``: the
    accepted second-order signatures' magnitudes in the whole run, at which both parts take them (their
    columns there the secants, as in the whole run's fit)."""
    wanted = {r.key for r in reports}
    chosen = [c for c in candidates if c.key in wanted or c in accepted]
    train = Record(inp.slice(0, split), model, g, d, settings, chosen, t_mid, onsets, fixed)
    test = Record(inp.slice(split, inp.n), model, g, d, settings, chosen, t_mid, onsets, fixed)
    accepted_det = [c for c in accepted if isinstance(c, Candidate)]
    for candidate in accepted_det:
        value = (secants or {}).get(candidate.key)
        if value:
            train.relinearise(candidate, np.array([value]))
            test.relinearise(candidate, np.array([value]))
    edges, period, halfwidth = options.band_edges_hz, model.maneuver_period_s, options.harmonic_halfwidth
    base = list(train.nuisance) + [name for c in accepted_det for name in c.column_names()]
    by_key = {c.key: c for c in chosen}
    noise_report = next((r for r in reports if noise is not None and r.name == noise.name), None)
    if noise_report is not None:  # both parts whitened without the noise under test
        data = held_out_noise(train, test, base, edges, period, halfwidth, floor)
        for key, value in data.items():
            setattr(noise_report, key, value)
    kappa = noise_fit.get("kappa", 0.0)
    if kappa > 0:
        train.rebuild(kappa)
        test.rebuild(kappa)
    for report in reports:
        candidate = by_key.get(report.key)
        if candidate is None:
            continue
        group = {candidate.key, *report.partners}  # judged with its partners left out (.partners)
        others = list(train.nuisance) + [name for c in accepted_det if c.key not in group
                                         for name in c.column_names()]
        data = held_out_deterministic(train, test, candidate, others, edges, period, halfwidth, floor)
        for key, value in data.items():
            setattr(report, key, value)
    for group, members in _stacks(accepted_det).items():  # a stack held out as one, where all of it is here
        keys = {member.key for member in members}
        if not keys <= wanted:
            continue
        others = list(train.nuisance) + [name for c in accepted_det if c.key not in keys for name in c.column_names()]
        data = held_out_group(train, test, [name for member in members for name in member.column_names()], others)
        for report in reports:
            if report.key in keys and data:
                report.family_heldout[group] = dict(data)
