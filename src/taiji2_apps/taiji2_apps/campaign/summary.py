"""Per-parameter statistics of a campaign, with bootstrap 95 % intervals over seeds.

For each (group, method, parameter): the number of seeds, mean error, error std, mean reported
sigma, the CRLB, and the ratios std / CRLB (efficiency) and std / mean sigma (honesty of the
reported covariance). Scale factors are expressed relative to truth in %, offsets in um.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from taiji2_apps.campaign.case import PARAMETERS

#: Bootstrap resamples and seed (the intervals are reproducible).
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 20261124
#: Fewer seeds than this: the percentile bootstrap of a standard deviation is rough (with n seeds there are
#: at most n**n resamples, the smallest of which repeat one seed and have std 0, and the interval
#: undercovers), so the table and the plot say so.
BOOTSTRAP_MIN_SEEDS = 20


def few_seeds_note(n: int) -> str | None:
    """A warning for intervals from ``n`` seeds, or None when there are enough."""
    if n >= BOOTSTRAP_MIN_SEEDS:
        return None
    return (f"only {n} seeds: the 95 % bootstrap intervals are rough below {BOOTSTRAP_MIN_SEEDS} seeds "
            "(run more seeds for intervals to rely on)")


@dataclass
class ParameterSummary:
    """Statistics of one parameter over the seeds of one group and method."""

    group: str
    method: str
    parameter: str
    unit: str
    n: int
    mean_error: float
    error_std: float
    mean_sigma: float
    crlb: float
    std_over_crlb: float
    std_over_crlb_lo: float
    std_over_crlb_hi: float
    std_over_sigma: float
    std_over_sigma_lo: float
    std_over_sigma_hi: float


def summarize_table(table: object) -> list[ParameterSummary]:
    """Summaries of the ``status == "ok"`` rows of a campaign table (pyarrow.Table)."""
    columns = table.to_pydict()
    ok = np.array([s == "ok" for s in columns["status"]])
    # groups and methods in order of appearance, parameters in the order the cases write them
    keys = list(dict.fromkeys((g, m, p) for g, m, p, good in zip(columns["group"], columns["method"],
                                                                 columns["parameter"], ok, strict=True) if good))
    keys.sort(key=lambda k: (k[0], k[1], PARAMETERS.index(k[2]) if k[2] in PARAMETERS else len(PARAMETERS)))
    group = np.array(columns["group"], dtype=object)
    method = np.array(columns["method"], dtype=object)
    parameter = np.array(columns["parameter"], dtype=object)
    arrays = {k: np.array(columns[k], dtype=float) for k in ("error", "sigma", "truth", "crlb")}
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    out = []
    for g, m, p in keys:
        sel = ok & (group == g) & (method == m) & (parameter == p)
        scale, unit = (100.0 / np.abs(arrays["truth"][sel]), "%") if ".G_" in p else (np.full(sel.sum(), 1e6), "um")
        err = arrays["error"][sel] * scale
        sig = arrays["sigma"][sel] * scale
        crlb = float(np.mean(arrays["crlb"][sel] * scale))
        out.append(_summary(g, m, p, unit, err, sig, crlb, rng))
    return out


def _summary(group: str, method: str, parameter: str, unit: str, err: np.ndarray, sig: np.ndarray, crlb: float,
             rng: np.random.Generator) -> ParameterSummary:
    n = err.size
    std = float(err.std(ddof=1)) if n > 1 else float("nan")
    mean_sig = float(sig.mean())
    if n > 1:
        # bootstrap over seeds: resample (error, sigma) pairs together
        idx = rng.integers(0, n, size=(BOOTSTRAP_RESAMPLES, n))
        boot_std = err[idx].std(axis=1, ddof=1)
        boot_sig = sig[idx].mean(axis=1)
        crlb_lo, crlb_hi = np.percentile(boot_std / crlb, [2.5, 97.5])
        sig_lo, sig_hi = np.percentile(boot_std / boot_sig, [2.5, 97.5])
    else:
        crlb_lo = crlb_hi = sig_lo = sig_hi = float("nan")
    return ParameterSummary(group, method, parameter, unit, n, float(err.mean()), std, mean_sig, crlb,
                            std / crlb, float(crlb_lo), float(crlb_hi), std / mean_sig, float(sig_lo), float(sig_hi))


@dataclass
class RequirementSummary:
    """How many seeds of one group and method met every requirement (G to 0.3 %, d to 100 um, both GRS)."""

    group: str
    method: str
    seeds: int
    all_met: int

    @property
    def fraction(self) -> float:
        """Fraction of the seeds meeting every requirement."""
        return self.all_met / self.seeds if self.seeds else float("nan")


def requirement_summaries(table: object) -> list[RequirementSummary]:
    """Per group and method: the seeds whose every G and d met its requirement, as the verdict judges a run
    (1-sigma within the requirement and, the truth being known, the error within it too)."""
    from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL

    columns = table.to_pydict()
    met: dict[tuple[str, str], dict[int, bool]] = {}
    for g, m, seed, p, status, err, sig, truth in zip(columns["group"], columns["method"], columns["seed"],
                                                      columns["parameter"], columns["status"], columns["error"],
                                                      columns["sigma"], columns["truth"], strict=True):
        if status != "ok" or not p.startswith("grs"):
            continue
        limit = SCALE_FACTOR_REQUIREMENT_REL * abs(truth) if ".G_" in p else COM_OFFSET_REQUIREMENT_M
        ok = bool(sig <= limit and abs(err) <= limit)  # NaN (undetermined) is not met
        seeds = met.setdefault((g, m), {})
        seeds[seed] = seeds.get(seed, True) and ok
    return [RequirementSummary(g, m, len(seeds), sum(seeds.values())) for (g, m), seeds in met.items()]


def format_summary(summaries: Sequence[ParameterSummary],
                   requirements: Sequence[RequirementSummary] = ()) -> str:
    """A plain-text table, one block per group and method."""
    lines: list[str] = []
    current = None
    for s in summaries:
        if (s.group, s.method) != current:
            current = (s.group, s.method)
            note = few_seeds_note(s.n)
            lines += ["", f"== {s.group} | method {s.method} | {s.n} seeds ==", *([f"  note: {note}"] if note else []),
                      f"  {'parameter':14} {'unit':>4} {'mean err':>10} {'err std':>10} {'mean sig':>10} "
                      f"{'CRLB':>10} {'std/CRLB [95% CI]':>22} {'std/sig [95% CI]':>22}"]
        lines.append(f"  {s.parameter:14} {s.unit:>4} {s.mean_error:10.4g} {s.error_std:10.4g} {s.mean_sigma:10.4g} "
                     f"{s.crlb:10.4g} {s.std_over_crlb:6.2f} [{s.std_over_crlb_lo:5.2f}, {s.std_over_crlb_hi:5.2f}]"
                     f"   {s.std_over_sigma:6.2f} [{s.std_over_sigma_lo:5.2f}, {s.std_over_sigma_hi:5.2f}]")
    if requirements:
        lines += ["", "every requirement met (G to 0.3 %, d to 100 um, 1 sigma and error, both GRS):"]
        lines += [f"  {r.group} | method {r.method}: {r.all_met} of {r.seeds} seeds ({100 * r.fraction:.1f} %)"
                  for r in requirements]
    return "\n".join(lines).lstrip("\n")


def save_summary(summaries: Sequence[ParameterSummary], out_dir: Path,
                 requirements: Sequence[RequirementSummary] = ()) -> list[Path]:
    """``summary.csv`` and ``summary.txt`` in ``out_dir``."""
    import csv

    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out_dir / "summary.csv"
    with open(csv_path, "w", newline="", encoding="utf-8") as stream:
        fields = list(ParameterSummary.__dataclass_fields__)
        writer = csv.DictWriter(stream, fieldnames=fields)
        writer.writeheader()
        writer.writerows(asdict(s) for s in summaries)
    txt_path = out_dir / "summary.txt"
    txt_path.write_text(format_summary(summaries, requirements) + "\n", encoding="utf-8")
    return [csv_path, txt_path]
