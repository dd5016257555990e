"""A readout nonlinearity from an onset against a plain step of its readout (naming rule 4, :mod:`.standing`).

The GRS readouts under a square-wave maneuver are nearly square waves, m = m0 + A s(t) with s = +-1, so the
nonlinearity's change k m^2 = k (m0^2 + A^2) + 2 k m0 A s(t) is mostly a constant. Present from the start, that
constant is the readout's free offset; from an onset it is a step of the readout's bias: what a test-mass charge
event, a patch-potential change or an electronics offset jump does, none of which the catalog holds. Blind seed
16, set 49: a 1.5e-12 m s^-2 bias step of a GRS linear readout at 5,400 s was named a nonlinearity of GRS1 x at
-10.6 sigma from 5,427 s; its held-out part (expected z 0.77) could not refuse it.

So a nonlinearity from an onset is named only where it gains beyond a step of its readout at that onset: the
step is added beside it in the final model, and the nonlinearity's drop-one gain there must pass the selection
floor of one parameter. A step is no catalog effect, so where it does not, the nonlinearity is refused and its
gap is unexplained.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from taiji2_estimator_pkg.diagnosis.candidates import Candidate, CandidateContext, NoiseCandidate, readout_change
from taiji2_estimator_pkg.diagnosis.record import Record
from taiji2_model.effect_catalog import ANGULAR_READOUTS

__all__ = ["StepRival", "readout_step", "step_rivals"]


@dataclass(frozen=True)
class StepRival:
    """A nonlinearity from an onset that a step of its readout explains as well.

    Attributes
    ----------
    variant : str
        The readout, e.g. ``"grs1.x"``.
    onset_s : float
        The nonlinearity's (and the step's) onset [s].
    gain : float
        The nonlinearity's drop-one delta chi^2 beside the step.
    floor : float
        The selection floor of one parameter it does not pass.
    """

    variant: str
    onset_s: float
    gain: float
    floor: float

    @property
    def step(self) -> str:
        """The step in words."""
        return f"a step of the {self.variant} readout at {self.onset_s:.0f} s (no catalog effect)"

    @property
    def reason(self) -> str:
        """Why the nonlinearity is not named."""
        return (f"{self.step} explains it as well: beside that step it gains delta chi2 {self.gain:.1f}, below the "
                f"floor {self.floor:.1f}")


def readout_step(grs: int, readout: str) -> Candidate:
    """A bias step of GRS ``grs``'s (0 or 1) ``readout`` (its size ``b`` in m s^-2 or rad s^-2), from the onset
    the record sets for it; no catalog effect (it has no injection)."""
    def build(ctx: CandidateContext) -> list[np.ndarray]:
        return [readout_change(ctx, grs, readout, np.ones(ctx.lin.lhat.shape[0]))]

    def inject(theta: np.ndarray, model: object) -> dict:
        raise ValueError("readout_step is a rival of the naming rule, not a catalog effect: it has no injection")

    unit = "rad s^-2" if readout in ANGULAR_READOUTS else "m s^-2"
    return Candidate("readout_step", f"grs{grs + 1}.{readout}", ("b",), unit, build, inject)


def step_rivals(full: Record, accepted: Sequence[Candidate | NoiseCandidate], current: Sequence[str],
                floor_one: float) -> dict[str, StepRival]:
    """The accepted nonlinearities from an onset that a step of their readout at that onset explains as well.

    Parameters
    ----------
    full : Record
        The whole run's record, with the final model's onsets and linearisation.
    accepted : sequence of Candidate or NoiseCandidate
        The selected variants.
    current : sequence of str
        The final model's columns.
    floor_one : float
        The selection floor of one parameter (delta chi^2).

    Returns
    -------
    dict of str to StepRival
        Variant key of each such nonlinearity -> its rival step.
    """
    refused = {}
    for candidate in accepted:
        if not isinstance(candidate, Candidate) or candidate.name != "readout_nonlinearity" \
                or candidate.key not in full.onsets:
            continue
        grs, readout = candidate.variant.split(".")
        rival = readout_step(int(grs[3:]) - 1, readout)
        onset_s = full.onsets[candidate.key]
        if rival.key not in full.candidates:
            full.onsets[rival.key] = onset_s
            full.add_candidate(rival)
        elif full.onsets.get(rival.key) != onset_s:
            full.set_onset(rival, onset_s)
        own = candidate.column_names()
        with_step = [*current, *rival.column_names()]
        gain = full.chi2([name for name in with_step if name not in own]) - full.chi2(with_step)
        if gain < floor_one:
            refused[candidate.key] = StepRival(candidate.variant, onset_s, float(gain), floor_one)
    return refused
