"""A stack of one family's variants completed for the final scan (issue 39: a full cross-talk of one GRS).

Selection takes at most ``max_effects`` physical variants, so a cross-talk of one GRS in all six of its terms is
selected as four, and the final scan of the four-term model finds what the other two leave: blind seed 17, set
80, a full cross-talk of GRS2 from 2,614 s, read "unexplained gap at lin_diff_z 0.003-0.01 Hz; also found:
cross_coupling" although the family as one candidate stood (naming rule 3, ``stages.naming._families``).

Where three or more variants of one family (or of one physics of it, :func:`.standing.subfamily_group`) are
accepted and the variants the stack lacks gain more than their BIC penalty beside it (the test by which the
family stands as one candidate), the final scan's residual is that of the model with the whole family. The
missing variants start at the median of the stack's onsets where every variant of the stack has one (each is
profiled on its own), from the start otherwise.
The final fit, the effect reports and the family's own fit keep their columns; only the scan, and so the
verdict, sees the completed family.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, NoiseCandidate
from taiji2_estimator_pkg.diagnosis.record import Record
from taiji2_estimator_pkg.diagnosis.standing import family_group, rule3_stacks

__all__ = ["complete_families"]


def complete_families(full: Record, candidates: Sequence[Candidate], accepted: Sequence[Candidate | NoiseCandidate],
                      current: Sequence[str], log_n: float) -> dict[str, list[str]]:
    """The families whose stack the final scan completes, and their missing variants.

    Parameters
    ----------
    full : Record
        The whole run's record; a completed family's missing variants get the stack's common onset there.
    candidates : sequence of Candidate
        Every variant.
    accepted : sequence of Candidate or NoiseCandidate
        The selected variants.
    current : sequence of str
        The final model's columns.
    log_n : float
        ``ln N`` of the BIC penalty.

    Returns
    -------
    dict of str to list of str
        Family group -> the keys of the variants it adds (in the candidates' order).
    """
    completed: dict[str, list[str]] = {}
    columns = list(current)
    chi2_current = full.chi2(columns)
    for grouping, group, members in rule3_stacks(accepted):  # the whole family, then its parts of one physics
        if any(family_group(members[0].name, members[0].variant) == done for done in completed):
            continue
        missing = [c for c in candidates if grouping(c.name, c.variant) == group and c not in members]
        if not missing:
            continue
        onsets = [full.onsets.get(c.key) for c in members]
        # each member's onset is profiled on its own (1,793-1,821 s for one cross-talk from 1,800 s)
        onset = float(np.median(onsets)) if None not in onsets else None
        previous = {c.key: full.onsets.get(c.key) for c in missing}
        for candidate in missing:
            full.set_onset(candidate, onset)
        extra = [name for c in missing for name in c.column_names()]
        chi2_completed = full.chi2(columns + extra)
        penalty = sum(c.n_params_at(onset) for c in missing) * log_n
        if chi2_current - chi2_completed > penalty:
            completed[group] = [c.key for c in missing]
            columns += extra
            chi2_current = chi2_completed
        else:
            for candidate in missing:
                full.set_onset(candidate, previous[candidate.key])
    return completed
