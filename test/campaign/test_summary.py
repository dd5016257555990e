"""Campaign summaries: bootstrap intervals from few seeds are flagged in the table (and the plot's title)."""

from __future__ import annotations

import numpy as np

from taiji2_apps.campaign.summary import (
    BOOTSTRAP_MIN_SEEDS,
    _summary,
    few_seeds_note,
    format_summary,
    requirement_summaries,
)


def _one(n: int):
    rng = np.random.default_rng(5)
    err = rng.normal(size=n)
    return _summary("g", "gls", "grs1.G_Pphi", "%", err, np.ones(n), 1.0, np.random.default_rng(1))


def test_few_seeds_are_flagged_and_enough_seeds_are_not():
    few, enough = _one(4), _one(BOOTSTRAP_MIN_SEEDS)
    assert "note: only 4 seeds" in format_summary([few])
    assert "note:" not in format_summary([enough])
    assert few_seeds_note(BOOTSTRAP_MIN_SEEDS - 1) is not None and few_seeds_note(BOOTSTRAP_MIN_SEEDS) is None


def test_the_fraction_of_seeds_meeting_every_requirement_counts_sigma_and_error():
    import pyarrow as pa

    rows = []
    for seed, (d_sigma, d_error) in enumerate([(50e-6, 10e-6), (50e-6, 150e-6), (150e-6, 10e-6), (float("nan"), 0.0)]):
        for grs in (1, 2):
            for name in ("G_Pphi", "G_Ptheta", "G_Ppsi"):
                rows.append(("g", "gls", seed, f"grs{grs}.{name}", "ok", 1e-4, 1e-4, 0.1))  # 0.1 % of G
            for axis in "xyz":
                rows.append(("g", "gls", seed, f"grs{grs}.d_{axis}", "ok", d_error, d_sigma, 0.0))
        rows.append(("g", "gls", seed, "diff.d_x", "ok", 1.0, 1.0, 0.0))  # not a requirement
    names = ("group", "method", "seed", "parameter", "status", "error", "sigma", "truth")
    table = pa.table({n: [r[i] for r in rows] for i, n in enumerate(names)})
    (summary,) = requirement_summaries(table)
    assert (summary.seeds, summary.all_met) == (4, 1)  # an error, a sigma or an undetermined d beyond 100 um fails
    assert "1 of 4 seeds (25.0 %)" in format_summary([], [summary])
