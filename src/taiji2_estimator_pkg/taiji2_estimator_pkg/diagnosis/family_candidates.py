"""One physics of one family as a single candidate of forward selection (issue 39: multi-parameter effects).

An effect with several parameters (the misalignment of one GRS about three axes, a c.m. drift in three
axes, an inertia error of three moments) is selected variant by variant, and the variant that best fits
it alone need not be one of its own: a misalignment of GRS1 about x, y and z (blind seed 17, set 83,
reference fidelity, each axis 5-8 sigma) was taken as GRS2's misalignment about y alone (delta chi2 41.6
against 34.1 for GRS1's x); once that was in, GRS1's own axes no longer cleared the floor, and the set read
"unexplained" with the wrong GRS named. As one candidate, GRS1's three axes gain 76.7 (score 43.5 with
three ``ln N``) and GRS2's 60.5: the family is told apart where its single variants are not.

:func:`family_candidates` groups the physical variants by :func:`.standing.subfamily_group` (the parts of
one physics). At each selection step the variants of a group not yet accepted (at least two) are scored
together, with their whole parameter count in the BIC penalty and the floor. The groups are not counted among
the tests of the floor's level: their BIC penalty (``p ln N``, at least 22 for two variants) holds each to a
false-alarm probability ten times below the level per variant. A single effect is taken as its group only
where the other variants gain more than ``ln N`` each beside it: with no effect of theirs they add noise alone
(a chi-square of their count).

A group taken is profiled over one onset of all its members (a family's effect starts at once): member by
member, a misalignment about y of a full cross-talk of GRS2 from 2,600 s (blind seed 17, set 80) had no onset
of its own beside the others' (GLR 1.0), stayed from the start, explained 31 % of its gap and was refused,
leaving that gap "unexplained".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from taiji2_estimator_pkg.diagnosis.candidates import Candidate
from taiji2_estimator_pkg.diagnosis.standing import subfamily_group

__all__ = ["FamilyCandidate", "family_candidates"]


@dataclass(frozen=True)
class FamilyCandidate:
    """The variants of one physics of one family, scored as one candidate.

    Attributes
    ----------
    key : str
        The group (``cross_coupling[grs1.misalign]``, ``com_drift[both]``, ``inertia_error``).
    members : tuple of Candidate
        Its variants (all of them, or those not yet accepted: :meth:`remaining`).
    """

    key: str
    members: tuple[Candidate, ...]
    is_timing = False

    @property
    def n_params(self) -> int:
        """The parameters of every member."""
        return sum(member.n_params for member in self.members)

    @property
    def onset_kind(self) -> str:
        """How the family starts mid-run (its members', one kind per family: :mod:`.candidates`)."""
        return self.members[0].onset_kind

    def column_names(self) -> list[str]:
        """The members' design columns, in their order."""
        return [name for member in self.members for name in member.column_names()]

    def remaining(self, accepted: Sequence[object]) -> FamilyCandidate | None:
        """The group of the members not in ``accepted``; None where fewer than two remain."""
        members = tuple(member for member in self.members if member not in accepted)
        return FamilyCandidate(self.key, members) if len(members) >= 2 else None


def family_candidates(candidates: Sequence[Candidate]) -> list[FamilyCandidate]:
    """The groups of two or more physical variants of one physics (:func:`.standing.subfamily_group`), in the
    candidates' order."""
    groups: dict[str, list[Candidate]] = {}
    for candidate in candidates:
        if candidate.variant and not candidate.is_timing:
            groups.setdefault(subfamily_group(candidate.name, candidate.variant), []).append(candidate)
    return [FamilyCandidate(key, tuple(members)) for key, members in groups.items() if len(members) >= 2]
