"""PNG plots of a campaign: normalised errors against N(0, 1), and std / CRLB per parameter."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from taiji2_apps.campaign.summary import ParameterSummary, few_seeds_note


def plot_campaign(table: object, summaries: Sequence[ParameterSummary], out_dir: Path) -> list[Path]:
    """Save ``errors_over_sigma.png`` and ``std_over_crlb.png`` in ``out_dir``; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = table.to_pydict()
    ok = np.array([s == "ok" for s in columns["status"]])
    z = np.array(columns["error"], dtype=float)[ok] / np.array(columns["sigma"], dtype=float)[ok]
    method = np.array(columns["method"], dtype=object)[ok]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    grid = np.linspace(-5, 5, 401)
    for m in sorted(set(method)):
        values = z[(method == m) & np.isfinite(z)]
        ax.hist(np.clip(values, -5, 5), bins=50, range=(-5, 5), density=True, histtype="step",
                label=f"{m}: {values.size} estimates")
    ax.plot(grid, np.exp(-grid**2 / 2) / np.sqrt(2 * np.pi), "k--", label="N(0, 1)")
    ax.set_xlabel("error / reported sigma (clipped to +-5)")
    ax.set_ylabel("density")
    ax.set_title("Campaign: error / reported sigma of every estimate against N(0, 1)")
    ax.legend()
    fig.tight_layout()
    paths = [out_dir / "errors_over_sigma.png"]
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(max(7, 0.45 * len(summaries)), 4.5))
    x = np.arange(len(summaries))
    ratio = np.array([s.std_over_crlb for s in summaries])
    lo = np.array([s.std_over_crlb_lo for s in summaries])
    hi = np.array([s.std_over_crlb_hi for s in summaries])
    ax.errorbar(x, ratio, yerr=[ratio - lo, hi - ratio], fmt="o", capsize=3)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhspan(0.8, 1.25, color="g", alpha=0.1, label="[0.8, 1.25]")
    ax.set_xticks(x, [f"{s.parameter} ({s.method})" for s in summaries], rotation=70, fontsize=7)
    ax.set_ylabel("error std / CRLB (95 % bootstrap)")
    seeds = min((s.n for s in summaries), default=0)
    note = few_seeds_note(seeds)
    ax.set_title("Campaign: error std over seeds / Cramer-Rao bound, per parameter "
                 f"({seeds} seeds, 95 % bootstrap over seeds)" + (f"\n{note}" if note else ""), fontsize=9)
    ax.legend()
    fig.tight_layout()
    paths.append(out_dir / "std_over_crlb.png")
    fig.savefig(paths[1], dpi=110)
    plt.close(fig)
    return paths
