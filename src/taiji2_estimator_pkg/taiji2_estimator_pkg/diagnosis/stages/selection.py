"""Stage 3, selection (which): forward selection over the candidate variants (:mod:`..candidates`).

Every variant not yet accepted is added to the calibrated model and refitted jointly with G, d and
the nuisance terms; its likelihood gain is ``delta chi^2`` (``2 delta log L`` for the noise
candidate), its score ``delta chi^2 - p ln N`` (BIC). The variants of one physics of one family not yet
accepted (at least two) are also scored as one candidate (:mod:`..family_candidates`); taken, all are
accepted. The best variant is accepted while its score is positive and its gain passes a Bonferroni floor
over the candidates; at most
``options.max_effects`` physical effects (timing effects, each timing family at most once, do not
count). Of the two delay families (an actuation delay, a GRS stamp offset) one at most is accepted
from the start. A thruster lag beside an accepted delay (or a delay beside an accepted lag) is scored by
their joint exact fit (:mod:`..joint_timing`). An accepted effect's second-order signature is
relinearised at its fitted magnitude, and
its onset is modelled when the profile likelihood over the onset says it starts mid-run
(:mod:`..onset`). At each step the leading variants are also tried from a few onsets on
(:mod:`.late_start`): an effect that starts mid-run reads weak from the start, and drifts fit it
better there than its own from-start signature. Once a variant of a family starts mid-run, the family's
other variants are scored from that onset as well (its gain the better of the two; no onset of their own
to pay for: a family's effect starts at once, :func:`_family_onsets`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from taiji2_estimator_pkg.diagnosis.candidates import TIMING_FAMILIES, Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.family_candidates import FamilyCandidate
from taiji2_estimator_pkg.diagnosis.joint_timing import (
    DELAY_FAMILIES,
    JointTiming,
    apply_joint_timing,
    fit_joint_timing,
    joint_partner,
    score_joint_timing,
)
from taiji2_estimator_pkg.diagnosis.onset import onset_posterior
from taiji2_estimator_pkg.diagnosis.options import DiagnosisOptions, Progress
from taiji2_estimator_pkg.diagnosis.record import Record
from taiji2_estimator_pkg.diagnosis.stages.late_start import late_start
from taiji2_estimator_pkg.diagnosis.stages.nominal import Nominal
from taiji2_estimator_pkg.diagnosis.standing import family_group

__all__ = ["Selection", "select_effects"]


@dataclass(frozen=True)
class Selection:
    """Stage 3's result.

    Attributes
    ----------
    accepted : list of Candidate or NoiseCandidate
        Accepted variants, in their order.
    onsets : dict
        Variant key -> onset estimate (:func:`..onset.onset_posterior`, with ``modelled``).
    noise_fit : dict
        ``kappa``, ``gain``, ``sigma`` of an accepted noise candidate (empty otherwise).
    current : list of str
        Columns of the selected model (nuisance, then each accepted variant's).
    steps : list of dict
        Forward-selection trace.
    """

    accepted: list[Candidate | NoiseCandidate]
    onsets: dict[str, dict[str, Any]]
    noise_fit: dict[str, float]
    current: list[str]
    steps: list[dict[str, Any]]


def _physical_count(accepted: list[Candidate | NoiseCandidate]) -> int:
    return sum(not (isinstance(c, Candidate) and c.is_timing) for c in accepted)


def _family_onsets(accepted: list[Candidate | NoiseCandidate], full: Record) -> dict[str, float]:
    """The onset [s] of each family (:func:`.standing.family_group`) with an accepted variant that starts mid-run
    (the first such variant's). A cross-talk of GRS2 from 4,060 s (blind seed 16, set 160): its imbalance about x
    was taken from 4,042 s, but its misalignment, scored from the start, gained less than GRS1's imbalance
    about y from a late onset of its own (a wrong GRS taken, later refused), and the set read "unexplained"."""
    out: dict[str, float] = {}
    for candidate in accepted:
        if isinstance(candidate, Candidate) and candidate.variant and candidate.key in full.onsets:
            out.setdefault(family_group(candidate.name, candidate.variant), full.onsets[candidate.key])
    return out


def _beside(family: FamilyCandidate, member: Candidate) -> list[str]:
    """The columns of a family's other members."""
    return [name for other in family.members if other is not member for name in other.column_names()]


def _onset(full: Record, candidate: Candidate | FamilyCandidate, others: list[str], options: DiagnosisOptions,
           log_n: float, say: Progress) -> dict[str, Any]:
    """The accepted candidate's onset (profile likelihood, :mod:`..onset`; a family's, of all its members at
    once), set in ``full`` (and relinearised there) where the GLR passes ``options.onset_penalty ln N``."""
    info = onset_posterior(full, candidate, others)
    info["modelled"] = bool(info["delta_chi2"] > options.onset_penalty * log_n)
    if info["modelled"]:
        members = candidate.members if isinstance(candidate, FamilyCandidate) else (candidate,)
        for member in members:
            full.set_onset(member, info["value"])
        for member in members:
            full.refine(member, others + (_beside(candidate, member) if isinstance(candidate, FamilyCandidate)
                                          else []))
        say(f"  {candidate.key} starts at {info['value']:.0f} +- {info['sigma']:.0f} s "
            f"({info['kind']}; GLR delta chi2 {info['delta_chi2']:.1f})")
    return info


def select_effects(nominal: Nominal, options: DiagnosisOptions, say: Progress) -> Selection:
    """Forward selection; relinearises, sets onsets and the noise model in ``nominal.full``."""
    full, candidates, noise, log_n, floor = (nominal.full, nominal.candidates, nominal.noise, nominal.log_n,
                                            nominal.floor)
    say(f"forward selection over {nominal.n_candidates} candidates (which)")
    accepted: list[Candidate | NoiseCandidate] = []
    onsets: dict[str, dict[str, Any]] = {}
    noise_fit: dict[str, float] = {}
    current = list(nominal.nuisance)
    _, _, chi2_current = full.fit(current)
    steps: list[dict[str, Any]] = []
    joint_fits: dict[str, JointTiming] = {}  # per candidate: its pair's joint fit
    late_columns: dict = {}  # the late-start look's column DFTs, built once per selection (.late_start)
    for step in range(options.max_effects + len(TIMING_FAMILIES)):
        evaluations: list[tuple[float, float, Candidate | FamilyCandidate | NoiseCandidate]] = []
        joints: dict[str, JointTiming] = {}
        physical_full = _physical_count(accepted) >= options.max_effects
        # a delay accepted from the start: the other delay family would add to it only the star tracker's
        # offset (a GRS stamp offset is a delay with the star tracker stamped early, .candidates), which
        # time_offset is, and its delay part stacked linearly on the first fights the joint timing fit
        delay_from_start = any(isinstance(c, Candidate) and c.name in DELAY_FAMILIES and c.key not in full.onsets
                               for c in accepted)
        started = _family_onsets(accepted, full)
        for candidate in candidates:
            if candidate in accepted or (physical_full and not candidate.is_timing) or \
                    (candidate.name in DELAY_FAMILIES and delay_from_start):
                continue
            pair = joint_partner(candidate, accepted, full)
            if pair is not None:  # a lag beside an accepted delay, or the reverse: their joint exact gain,
                # fitted at the first step the pair meets, rescored at that fit after (the effects joining
                # later move the pair little; a simplex per step cost 3-5 s)
                if candidate.key not in joint_fits or joint_fits[candidate.key].delay is not pair[0]:
                    joint_fits[candidate.key] = fit_joint_timing(full, *pair, current)
                    joints[candidate.key] = joint_fits[candidate.key]
                else:
                    joints[candidate.key] = score_joint_timing(full, joint_fits[candidate.key], current)
                chi2_new = joints[candidate.key].chi2
            elif candidate.series is not None:  # polynomial signature: its exact (series) gain
                _, chi2_new = full.series_fit(candidate, current)
            else:
                chi2_new = full.chi2(current + candidate.column_names())
                onset = started.get(family_group(candidate.name, candidate.variant)) if candidate.variant else None
                if onset is not None:  # a family's effect starts at once: its other variants from its onset too
                    chi2_new = min(chi2_new, float(full.onset_profile(candidate, current, [onset])[0][0]))
            gain = chi2_current - chi2_new
            evaluations.append((gain - candidate.n_params * log_n, gain, candidate))
        free_slots = options.max_effects - _physical_count(accepted)
        for family in nominal.families:  # one physics of one family as one candidate (..family_candidates)
            group = family.remaining(accepted)
            if group is not None and len(group.members) <= free_slots:
                gain = chi2_current - full.chi2(current + group.column_names())
                evaluations.append((gain - group.n_params * log_n, gain, group))
        noise_step = None
        if noise is not None and noise not in accepted and not physical_full:
            theta_cur, _, _ = full.fit(current)
            noise_step = full.noise_gain(full.residual_fft(current, theta_cur))
            evaluations.append((noise_step[1] - log_n, noise_step[1], noise))
        evaluations.sort(key=lambda item: -item[0])
        top = [{"candidate": item[2].key, "delta_chi2": round(item[1], 2), "score": round(item[0], 2)}
               for item in evaluations[:5]]
        passing = [item for item in evaluations if item[0] > 0 and item[1] > floor[item[2].n_params]]
        late = None
        if options.onsets and not physical_full:  # the second look: an effect that starts mid-run (.late_start)
            ranked = [(item[1], item[2]) for item in sorted(evaluations, key=lambda item: -item[1])
                      if isinstance(item[2], Candidate)]
            late = late_start(full, ranked, current, chi2_current, nominal.n_candidates, options.alpha_candidates,
                              log_n, options.onset_penalty, late_columns)
            late_score = -float("inf") if late is None else late.gain - (late.candidate.n_params_from_onset + 1) * log_n
            if late is not None and (not passing or late_score > passing[0][0]):
                passing = [(late_score, late.gain, late.candidate)]
            else:
                late = None
        if not passing:
            steps.append({"step": step + 1, "accepted": None, "top": top})
            break
        score, gain, best = passing[0]
        if not isinstance(best, FamilyCandidate):  # a family adds its members (below)
            accepted.append(best)
        steps.append({"step": step + 1, "accepted": best.key, "delta_chi2": round(gain, 2), "score": round(score, 2),
                      "top": top})
        if late is not None:
            steps[-1]["late_start"] = {"trial_onset_s": late.onset_s, "delta_chi2_from_start": round(
                late.gain_from_start, 2), "floor": round(late.floor, 2)}
        say(f"step {step + 1}: accepted {best.key} (delta chi2 {gain:.1f}, score {score:.1f}"
            + (f", from {late.onset_s:.0f} s on: {late.gain_from_start:.1f} from the start" if late else "") + ")")
        if isinstance(best, NoiseCandidate) and noise_step is not None:
            noise_fit = {"kappa": noise_step[0], "gain": noise_step[1], "sigma": noise_step[2]}
            full.rebuild(noise_step[0])
        elif isinstance(best, FamilyCandidate):  # every member accepted, each relinearised beside the others
            accepted.extend(best.members)
            steps[-1]["variants"] = [member.key for member in best.members]
            for member in best.members:
                full.refine(member, current + _beside(best, member))
            if options.onsets:  # one onset of the whole family
                info = _onset(full, best, current, options, log_n, say)
                onsets.update({member.key: info for member in best.members})
                steps[-1]["onset_s"] = {"value": info["value"], "sigma": info["sigma"], "modelled": info["modelled"]}
            current = current + best.column_names()
        elif isinstance(best, Candidate):
            if best.key in joints:  # both columns become exact secants at the jointly fitted pair
                apply_joint_timing(full, joints[best.key])
            else:  # second-order signatures: relinearise at the fitted magnitude
                full.refine(best, current)
            if options.onsets:  # does it start mid-run? (profile likelihood over its onset, .onset)
                info = _onset(full, best, current, options, log_n, say)
                onsets[best.key] = info
                steps[-1]["onset_s"] = {"value": info["value"], "sigma": info["sigma"], "modelled": info["modelled"]}
            current = current + best.column_names()
        _, _, chi2_current = full.fit(current)
    return Selection(accepted, onsets, noise_fit, current, steps)
