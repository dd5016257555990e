"""report.json, report.md and PNGs of a maneuver design (design beside the paper's preset)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from taiji2_apps.design.evaluate import PARAMETER_NAMES

__all__ = ["summary", "write_report"]


def summary(problem: Any, maneuver: Any, duration_s: float, usage: Any, result: Any, ratios: np.ndarray) -> dict:
    """One object of report.json: ratios, bounds, usage, duration meeting each requirement, maneuver."""
    from taiji2_model.maneuver_families import maneuver_spec

    g_rel = result.scale_factor_relative_sigma
    d = result.com_offset_sigma
    crlb_values = {}
    for i, g in enumerate((1, 2)):
        for k, n in enumerate(("G_Pphi", "G_Ptheta", "G_Ppsi")):
            crlb_values[f"grs{g}.{n}"] = float(g_rel[3 * i + k])
        for k, n in enumerate(("d_x", "d_y", "d_z")):
            crlb_values[f"grs{g}.{n}"] = float(d[3 * i + k])
    return {
        "duration_s": duration_s,
        "crlb_over_requirement": dict(zip(PARAMETER_NAMES, (float(r) for r in ratios), strict=True)),
        "crlb": crlb_values,
        "crlb_units": "G: relative (sigma / G); d: m",
        "max_crlb_over_requirement": float(np.max(ratios)),
        "binding_parameter": PARAMETER_NAMES[int(np.argmax(ratios))],
        "duration_meeting_requirement_s": dict(zip(PARAMETER_NAMES, (float(duration_s * r * r) for r in ratios),
                                                   strict=True)),
        "shortest_duration_all_met_s": float(duration_s * np.max(ratios) ** 2),
        "usage": usage.to_dict(),
        "thrust_fraction_of_max": (np.asarray(usage.thrust_n) / problem.max_thrust_n).tolist(),
        "maneuver": maneuver_spec(maneuver),
    }


def _plots(out: Path, report: dict) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(PARAMETER_NAMES)
    files = []
    fig, ax = plt.subplots(figsize=(10, 4))
    x = np.arange(len(names))
    for k, (key, label) in enumerate((("paper", "paper preset"), ("design", "design"))):
        values = [report[key]["crlb_over_requirement"][n] for n in names]
        ax.bar(x + (k - 0.5) * 0.4, values, 0.4, label=f"{label} ({report[key]['duration_s']:.0f} s)")
    ax.axhline(1.0, color="k", lw=1, ls="--", label="requirement")
    ax.set_xticks(x, names, rotation=45, ha="right")
    ax.set_ylabel("CRLB / requirement (1 sigma)")
    ax.set_title(f"{report['layout']}: CRLB vs requirement")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "crlb_vs_requirement.png", dpi=100)
    plt.close(fig)
    files.append("crlb_vs_requirement.png")
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.5))
    labels = [f"GRS{g} {a}" for g in (1, 2) for a in "xyz"]
    for k, key in enumerate(("paper", "design")):
        u = report[key]["usage"]
        axes[0].bar(np.arange(6) + (k - 0.5) * 0.4, np.ravel(u["range_fraction"]), 0.4, label=key)
        axes[1].bar(np.arange(3) + (k - 0.5) * 0.4, np.asarray(u["thrust_peak_n"]) * 1e6, 0.4, label=key)
        axes[2].bar(np.arange(3) + (k - 0.5) * 0.4, np.asarray(u["attitude_peak_rad"]) * 1e3, 0.4, label=key)
    axes[0].axhline(report["constraints"]["range_margin"], color="k", ls="--")
    axes[0].set_xticks(np.arange(6), labels, rotation=45)
    axes[0].set_ylabel("peak maneuver |a| / range")
    axes[1].axhline(report["constraints"]["max_thrust_n"] * 1e6, color="k", ls="--")
    axes[1].set_xticks(np.arange(3), list("XYZ"))
    axes[1].set_ylabel("peak thrust [uN]")
    axes[2].axhline(report["constraints"]["max_attitude_rad"] * 1e3, color="k", ls="--")
    axes[2].set_xticks(np.arange(3), list("XYZ"))
    axes[2].set_ylabel("peak attitude [mrad]")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(out / "usage.png", dpi=100)
    plt.close(fig)
    files.append("usage.png")
    return files


def _search_line(report: dict) -> str:
    search = report.get("search")
    if not search:
        return ""
    size = (f"{search['evaluations']} of at most {search['max_evaluations']} evaluations, "
            f"{search['generations']} of {search['max_generations']} generations of the global search, then the polish")
    if search["truncated"]:
        return (f"Search: **truncated** by the wall-clock cap of {search['wall_cap_s'] or 0:.0f} s after {size}: "
                f"this design depends on the machine's speed; another run with seed {report['seed']} may differ "
                f"(raise --budget-s / --time-limit-s or lower --max-evaluations).")
    return (f"Search: complete, {size} ({search['wall_s']:.0f} s): bounded by evaluations, the same design for "
            f"seed {report['seed']} on any machine load.")


def write_report(out: Path, report: dict, plots: bool = True) -> None:
    """Write report.json, report.md and the PNGs into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    report["plots"] = _plots(out, report) if plots else []
    (out / "report.json").write_text(json.dumps(report, indent=2))
    d, p = report["design"], report["paper"]
    c = report["constraints"]
    lines = [f"# Maneuver design: {report['layout']}, family {report['family']}", "",
             f"Objective: the largest CRLB / requirement over the 12 parameters (G 0.3 %, d 100 um, 1 sigma), "
             f"full Cramer-Rao bound of G and d jointly from every channel (core/crlb.py). Constraints: noise-free "
             f"maneuver peak + {c.get('range_sigmas', 0.0):g} sigma of the readout noise (every source) within "
             f"{report['constraints']['range_margin']:.0%} of +-{report['constraints']['range_m_s2']:.1e} m/s^2 "
             f"on every TM axis, "
             f"thrust {c['min_thrust_n'] * 1e6:.3g}-{c['max_thrust_n'] * 1e6:.3g}"
             f" uN at lever arm {report['constraints']['lever_arm_m']:g} m, attitude <= "
             f"{report['constraints']['max_attitude_rad']:g} rad. Binding constraint of the design: "
             f"**{report['binding_constraint']}**. Seed {report['seed']}, {report['evaluations']} evaluations, "
             f"{report['wall_s']:.0f} s.", "", _search_line(report), "",
             f"Maneuver file: `{report['maneuver_file']}` (maneuver_commander `maneuver`).", "",
             "| parameter | paper CRLB/req | design CRLB/req | paper: T met [h] | design: T met [h] |",
             "|---|---|---|---|---|"]
    for n in PARAMETER_NAMES:
        lines.append(f"| {n} | {p['crlb_over_requirement'][n]:.3f} | {d['crlb_over_requirement'][n]:.3f} | "
                     f"{p['duration_meeting_requirement_s'][n] / 3600:.2f} | "
                     f"{d['duration_meeting_requirement_s'][n] / 3600:.2f} |")
    lines += ["", f"At {report['reference_duration_s']:.0f} s: paper max ratio "
                  f"{report['at_reference']['paper_max']:.3f} ({report['at_reference']['paper_binding']}), design "
                  f"{report['at_reference']['design_max']:.3f} ({report['at_reference']['design_binding']}): "
                  f"reduction {report['at_reference']['reduction']:.1%}.",
              f"Shortest duration with every requirement met at 1 sigma: paper "
              f"{p['shortest_duration_all_met_s'] / 3600:.2f} h (1/sqrt(T) scaling), design "
              f"{report['shortest_duration_s'] / 3600:.2f} h"
              f"{' (verified on the whole-duration simulation and bound)' if report.get('shortest_verified') else ''}"
              ".", "",
              "## Usage (peak over the duration)", "",
              "| | range fraction GRS1 x y z | GRS2 x y z | thrust X Y Z [uN] | attitude X Y Z [mrad] |",
              "|---|---|---|---|---|"]
    for key in ("paper", "design"):
        u = report[key]["usage"]
        rf = np.round(u["range_fraction"], 3).tolist()
        lines.append(f"| {key} | {rf[0]} | {rf[1]} | {np.round(np.asarray(u['thrust_peak_n']) * 1e6, 3).tolist()} | "
                     f"{np.round(np.asarray(u['attitude_peak_rad']) * 1e3, 3).tolist()} |")
    lines += ["", *[f"![{f}]({f})" for f in report["plots"]], ""]
    (out / "report.md").write_text("\n".join(lines))
