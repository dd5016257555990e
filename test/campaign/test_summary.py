"""Campaign summaries: bootstrap intervals from few seeds are flagged in the table (and the plot's title)."""

from __future__ import annotations

import numpy as np

from taiji2_apps.campaign.summary import BOOTSTRAP_MIN_SEEDS, _summary, few_seeds_note, format_summary


def _one(n: int):
    rng = np.random.default_rng(5)
    err = rng.normal(size=n)
    return _summary("g", "gls", "grs1.G_Pphi", "%", err, np.ones(n), 1.0, np.random.default_rng(1))


def test_few_seeds_are_flagged_and_enough_seeds_are_not():
    few, enough = _one(4), _one(BOOTSTRAP_MIN_SEEDS)
    assert "note: only 4 seeds" in format_summary([few])
    assert "note:" not in format_summary([enough])
    assert few_seeds_note(BOOTSTRAP_MIN_SEEDS - 1) is not None and few_seeds_note(BOOTSTRAP_MIN_SEEDS) is None
