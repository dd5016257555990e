"""Report writer: ``report.md``, ``report.json`` and PNG plots (matplotlib Agg, no pyplot state).

Plots:

- ``psd_overlay.png``: per channel, the amplitude spectral density of the residual with the
  nominal model (before) and with the accepted effects (after), against the nominal noise model
  (log bands);
- ``gap_map.png``: channel x band map of the location significance (-log10 p; largest over kinds
  and segments), nominal model and final model side by side, the Bonferroni threshold marked.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from taiji2_estimator_pkg.diagnosis.channels import CHANNELS
from taiji2_estimator_pkg.diagnosis.results import DiagnosisResult

__all__ = ["write_report"]

_UNITS = {"st": "rad s^-2", "torque": "rad s^-2", "ang_diff": "rad s^-2", "lin_common": "m s^-2 (prewhitened)",
          "lin_diff": "m s^-2"}


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.floating | np.integer):
        return value.item()
    if isinstance(value, np.bool_):
        return bool(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _fmt(value: float | None, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}g}"


def _choice_lines(choice: dict[str, Any]) -> list[str]:
    """The report section saying which calibration to use, the two side by side."""
    head = "**Use `taiji2 calibrate`'s result** (the star-tracker method)"
    if choice["use"] == "calibrate --config":
        head = "**Use `taiji2 calibrate --config FILE`'s result** (the star-tracker method, the named effects removed)"
    lines = ["## Which calibration to use", "", f"{head}. " + choice["why"], "",
             "| GRS | parameter | `taiji2 calibrate` | 1-sigma | torque channel (trusts the nominal inertia) | 1-sigma "
             "| difference [combined sigma] | corrected (named effects modelled) | 1-sigma |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in choice["rows"]:
        diff = "-" if r["difference_sigma"] is None else f"{r['difference_sigma']:+.2f}"
        lines.append(f"| {r['grs']} | {r['parameter']} | {r['calibrate']:.6g} | {r['calibrate_sigma']:.3g} | "
                     f"{r['torque_channel']:.6g} | {r['torque_channel_sigma']:.3g} | {diff} | "
                     f"{_fmt(r.get('corrected'), 6)} | {_fmt(r.get('corrected_sigma'))} |")
    lines += [""] + [f"- {caveat}" for caveat in choice.get("caveats", [])]
    return [*lines, ""]


def _impulse_lines(impulses: dict[str, Any]) -> list[str]:
    """The impulsive events section (docs/diagnosis.md, section 6b)."""
    if not impulses:
        return []
    lines = ["", "## Impulsive events", "",
             f"Matched filter in the torque-response residual, {impulses['samples_searched']} samples searched, "
             f"threshold SNR {impulses['threshold_snr']:.2f} (a {impulses['false_alarm_per_record']:.0%} chance of "
             "one in pure noise). Each event is fitted in the final model and left out of the calibration.", ""]
    if impulses["abandoned"]:
        lines += ["The search stopped at its limit: the residual is not a few impulses in Gaussian noise.", ""]
    if not impulses["events"]:
        return [*lines, "None found."]
    lines += ["| time [s] | SNR | L [N m s] (x, y, z) | sigma L | p [N s] (x, y, z) | sigma p |",
              "|---|---|---|---|---|---|"]
    for e in impulses["events"]:
        vector = lambda v: ", ".join(f"{x:.3g}" for x in v)  # noqa: E731
        lines.append(f"| {e['time_s']:.2f} +- {e['time_sigma_s']:.2f} | {e['snr']:.1f} | "
                     f"{vector(e['angular_momentum_n_m_s'])} | {vector(e['angular_momentum_sigma_n_m_s'])} | "
                     f"{vector(e['linear_impulse_n_s'])} | {vector(e['linear_impulse_sigma_n_s'])} |")
    return lines


def _blind_spot_lines(spots: list[dict[str, Any]]) -> list[str]:
    """The blind spots section (docs/diagnosis.md, section 6c): families that move G or d by 1 sigma or more."""
    shown = [spot for spot in spots if spot["bias_sigma"] >= 1.0]
    lines = ["", "## Blind spots", "",
             "How far an effect of each family, at the detection threshold of this record (named about half the "
             "time), moves the torque-channel calibration without being named, in its sigma (first order; "
             "report.json `blind_spots`). \"No significant gap\" does not rule these out."]
    if not shown:
        return [*lines, "", "None above 1 sigma."]
    lines += ["", "| family | worst variant | moves | by [sigma] | magnitude at threshold |", "|---|---|---|---|---|"]
    for spot in shown:
        lines.append(f"| {spot['family']} | {spot['variant'] or '-'} | {spot['parameter']} | "
                     f"{spot['bias_sigma']:.1f} | {spot['magnitude_at_threshold']:.3g} {spot['unit']} |")
    return lines


def _markdown(result: DiagnosisResult, files: list[str], choice: dict[str, Any] | None = None) -> str:
    lines = ["# Sim-to-real gap diagnosis", ""]
    verdict = result.verdict
    lines += [f"**Verdict: {verdict.get('summary', result.status)}**", ""]
    inputs = result.inputs
    lines += [f"- data: {inputs.get('samples', 0)} samples, {inputs.get('duration_s', 0.0) / 3600:.3f} h, "
              f"{inputs.get('rejected_total', 0)} rejected {inputs.get('rejected', {})}",
              f"- nominal model: layout `{result.model.get('layout', '?')}`"]
    if result.status != "ok":
        lines += [f"- status: **{result.status}**: {result.reason}", ""]
        return "\n".join(lines) + "\n"
    cal = result.calibration
    lines += [f"- accepted effects: {', '.join(verdict.get('accepted_variants', [])) or 'none'}; "
              f"unexplained: {verdict.get('unexplained')}",
              f"- locations tested: {result.location_tests}, significance threshold {result.location_threshold:.2f} "
              f"(-log10 p, Bonferroni 1 %); significant before {verdict.get('significant_locations_before')}, "
              f"after {verdict.get('significant_locations_after')}",
              f"- nominal-model chi2/dof = {cal['chi2'] / cal['dof']:.5f} (z = {cal['chi2_z']:.2f}), fit band "
              f"<= {cal['f_max_hz']} Hz", ""]
    if choice is not None:
        lines += _choice_lines(choice)
    lines += ["## Torque-channel calibration (the nominal model: commanded torque over the nominal inertia)", "",
              "The reference of the gap search; it trusts the inertia and the thruster torque model"
              + (" (see above for the calibration to use)." if choice is not None else "."), "",
              "| GRS | G_phi | G_theta | G_psi | d_x [m] | d_y [m] | d_z [m] |",
              "|---|---|---|---|---|---|---|"]
    for grs in range(2):
        g = cal["g_angular"][grs]
        sg = cal["g_angular_sigma_relative"][grs]
        d = cal["com_offset_m"][grs]
        sd = cal["com_offset_sigma_m"][grs]
        lines.append(f"| {grs + 1} | " + " | ".join(f"{g[i]:.6g} ({sg[i] * 1e6:.0f} ppm)" for i in range(3)) + " | "
                     + " | ".join(f"{d[i]:.6g} ({sd[i] * 1e6:.0f} um)" for i in range(3)) + " |")
    lines += ["", "## Where: locations of the gap (nominal model)", "",
              "view: `marginal` = the channel against its own nominal spectrum, `conditional` = its innovation "
              "given the other channels.", "",
              "| channel | view | band [Hz] | kind | segment | gap (PSD ratio) | significance | significant |",
              "|---|---|---|---|---|---|---|---|"]
    for loc in result.locations[:15]:
        lines.append(f"| {loc.channel} | {loc.view} | {loc.band_hz[0]:.3g}-{loc.band_hz[1]:.3g} | {loc.kind} | "
                     f"{loc.segment} | {loc.gap:.3f} | {loc.significance:.2f} | {'yes' if loc.significant else ''} |")
    lines += ["", "## Which: candidate effects", "",
              "| effect | variant | magnitude | sigma | unit | delta chi2 | score (BIC) | accepted | shrink | "
              "held-out shrink | held-out z | aliases |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for effect in result.effects:
        lines.append(f"| {effect.name} | {effect.variant} | {_fmt(effect.magnitude, 4)} | {_fmt(effect.sigma, 2)} | "
                     f"{effect.unit} | {effect.delta_chi2:.1f} | {effect.score:.1f} | "
                     f"{'**yes**' if effect.accepted else ''} | {_fmt(effect.shrink, 2)} | "
                     f"{_fmt(effect.shrink_heldout, 2)} | {_fmt(effect.heldout_z, 2)} | {', '.join(effect.aliases)} |")
    lines += ["", "Forward selection:", ""]
    for step in result.steps:
        best = ", ".join(f"{t['candidate']} ({t['delta_chi2']}, {t['score']})" for t in step["top"][:3])
        lines.append(f"- step {step['step']}: accepted **{step['accepted'] or 'none'}**; best (delta chi2, score): "
                     f"{best}")
    accepted = [e for e in result.effects if e.accepted]
    if accepted:
        lines += ["", "## How far", ""]
        for effect in accepted:
            lines += [f"### {effect.key}: {_fmt(effect.magnitude, 4)} +- {_fmt(effect.sigma, 2)} {effect.unit}", "",
                      f"- shrink {_fmt(effect.shrink, 3)}; held out: trained magnitude "
                      f"{_fmt(effect.magnitude_train, 4)} +- {_fmt(effect.sigma_train, 2)}, shrink "
                      f"{_fmt(effect.shrink_heldout, 3)}, delta chi2 {_fmt(effect.heldout_delta_chi2, 3)} of "
                      f"{_fmt(effect.heldout_delta_chi2_best, 3)} possible"]
            onset = effect.parameters.get("onset_s")
            if onset:
                lines.append(f"- onset ({onset['kind']}): {onset['value']:.0f} +- {onset['sigma']:.0f} s "
                             f"(68 % {onset['interval'][0]:.0f}-{onset['interval'][1]:.0f} s, GLR delta chi2 "
                             f"{onset['delta_chi2']:.1f}, resolution {onset['resolution_s']:.1f} s; "
                             + ("modelled" if onset["modelled"] else "present from the start: not modelled") + ")")
            if effect.aliases:
                lines.append(f"- indistinguishable with these data from: {', '.join(effect.aliases)}")
            if effect.partners:
                lines.append(f"- determined only jointly with {', '.join(effect.partners)} (their magnitudes "
                             "correlate almost perfectly: the sum is well determined, the split is not; gain, "
                             "shrink and held-out check are those of the group)")
            if effect.g_shift:
                rel = np.array(effect.g_shift["relative"]) * 1e6
                dm = np.array(effect.d_shift["m"]) * 1e6 if effect.d_shift else np.zeros((2, 3))
                lines.append(f"- calibration moves once it is modelled: G [ppm] GRS1 {np.round(rel[0], 1).tolist()}, "
                             f"GRS2 {np.round(rel[1], 1).tolist()} (largest {effect.g_shift['max_abs_in_sigma']:.2f} "
                             f"sigma); d [um] GRS1 {np.round(dm[0], 2).tolist()}, GRS2 {np.round(dm[1], 2).tolist()}"
                             + (f" (largest {effect.d_shift['max_abs_in_sigma']:.2f} sigma)" if effect.d_shift else ""))
            lines += ["", "| channel | band [Hz] | kind | gap before | gap after | fraction explained |",
                      "|---|---|---|---|---|---|"]
            for cell in effect.cells:
                lines.append(f"| {cell['channel']} | {cell['band_hz'][0]:.3g}-{cell['band_hz'][1]:.3g} | "
                             f"{cell['kind']} | {cell['gap_before']:.3f} | {cell['gap_after']:.3f} | "
                             f"{_fmt(cell['fraction_explained'], 3)} |")
            lines.append("")
        if result.how_far:
            lines += ["Gap at the top nominal locations (whole run) after each accepted effect:", "",
                      "| channel | view | band [Hz] | kind | nominal | " + " | ".join(
                          f"+ {a['effect']}" for a in result.how_far[0]["after"]) + " |",
                      "|---|---|---|---|---|" + "---|" * len(result.how_far[0]["after"])]
            for row in result.how_far:
                lines.append(f"| {row['channel']} | {row['view']} | {row['band_hz'][0]:.3g}-{row['band_hz'][1]:.3g} | "
                             f"{row['kind']} | {row['gap_nominal']:.3f} | "
                             + " | ".join(f"{a['gap']:.3f}" for a in row["after"]) + " |")
    corrected = result.corrected
    heading = "## Corrected calibration (the nominal model extended with the named effects)"
    if result.corrected_withheld:
        lines += ["", heading, "", f"**Not given**: {result.corrected_withheld}. Use the star-tracker calibration "
                  "(`taiji2 calibrate`), and model the named effects before trusting a correction."]
    if corrected:
        lines += ["", heading, "",
                  f"Extended timing: {corrected['timing']}; effects: {corrected.get('effects')}", "",
                  "| GRS | parameter | nominal | corrected | sigma | shift [sigma] |", "|---|---|---|---|---|---|"]
        nominal_g, nominal_d = cal["g_angular"], cal["com_offset_m"]
        for grs in range(2):
            for i, axis in enumerate(("phi", "theta", "psi")):
                lines.append(f"| {grs + 1} | G_{axis} | {nominal_g[grs][i]:.6g} | "
                             f"{corrected['g_angular'][grs][i]:.6g} | "
                             f"{corrected['g_angular_sigma_relative'][grs][i] * 1e6:.0f} ppm | "
                             f"{corrected['g_shift_sigma'][grs][i]:+.2f} |")
            for i, axis in enumerate("xyz"):
                lines.append(f"| {grs + 1} | d_{axis} [m] | {nominal_d[grs][i]:.6g} | "
                             f"{corrected['com_offset_m'][grs][i]:.6g} | "
                             f"{corrected['com_offset_sigma_m'][grs][i] * 1e6:.1f} um | "
                             f"{corrected['d_shift_sigma'][grs][i]:+.2f} |")
        lines += ["", "Covariance (12 x 12, relative G then d): report.json `corrected_calibration.covariance`."]
        for alternative in corrected.get("alias_alternatives", []):
            worst = max(abs(x) for x in alternative["shift_from_corrected_sigma"])
            if alternative.get("kind") == "near_miss":
                lines += ["", f"Near miss: `{alternative['alias']}` gained at least 3 sigma but not the floor over "
                              "the catalog (not named, not ruled out); corrected with it added, G and d move by up "
                              f"to {worst:.2f} sigma of the named effects' fit "
                              "(report.json `corrected_calibration.alias_alternatives`)."]
                continue
            lines += ["", f"Alias: the data do not tell `{alternative['named']}` from `{alternative['alias']}` "
                          "(the same signature, or a fit worse by less than 3 sigma); corrected with the latter, G "
                          f"and d move by up to {worst:.2f} sigma of the named effect's fit "
                          "(report.json `corrected_calibration.alias_alternatives`)."]
        if corrected.get("alias_alternatives"):
            lines += ["", "The corrected values above hold whichever of these is the effect: each is the middle of "
                          "the range the alternatives span, its sigma the fit's with half that range added "
                          "(report.json `corrected_calibration.named_effects_calibration`: the named effect's own)."]
        if corrected.get("alias_uncertain"):
            lines += ["", "**Left uncertain by the alias** (moved by more than 1 sigma between the alternatives: "
                          "their sigma above carries it): " + ", ".join(corrected["alias_uncertain"]) + "."]
    lines += _impulse_lines(result.impulses)
    lines += _blind_spot_lines(result.blind_spots)
    remaining = result.verdict.get("remaining", [])
    lines += ["", "## Remaining gap", ""]
    if remaining:
        lines += ["Locations significant in a fresh scan, or strong gaps of the nominal model still open "
                  f"(stage 2, threshold {result.verdict.get('recheck_threshold', float('nan')):.2f}):", "",
                  "| channel | view | band [Hz] | kind | segment | time window [s] | gap | significance |",
                  "|---|---|---|---|---|---|---|---|"]
        for loc in remaining[:10]:
            window = (f"{loc['window_s'][0]:.0f}-{loc['window_s'][1]:.0f} (+- {loc['window_resolution_s']:.2g})"
                      if "window_s" in loc else "-")
            lines.append(f"| {loc['channel']} | {loc['view']} | {loc['band_hz'][0]:.3g}-{loc['band_hz'][1]:.3g} | "
                         f"{loc['kind']} | {loc['segment']} | {window} | {loc['gap']:.3f} | "
                         f"{loc['significance']:.2f} |")
    else:
        lines.append("No significant location remains.")
    lines += ["", "## Files", ""] + [f"- `{name}`" for name in files]
    lines += ["", f"Timing [s]: {result.timing_s}", ""]
    return "\n".join(lines) + "\n"


def _plots(result: DiagnosisResult, out: Path) -> list[str]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    plots = result.plots
    written = []
    if not plots:
        return written
    freq = np.asarray(plots["frequency_hz"])
    fs = float(plots["sample_rate_hz"])
    to_asd = 2.0 / fs  # per-bin variance -> one-sided PSD
    figure = Figure(figsize=(15, 16))
    FigureCanvasAgg(figure)
    axes = figure.subplots(5, 3)
    effects_drawn = not np.allclose(plots["psd_after"], plots["psd_before"])
    for c, name in enumerate(CHANNELS):
        ax = axes[c // 3][c % 3]
        ax.loglog(freq, np.sqrt(plots["psd_before"][:, c] * to_asd), color="tab:red", lw=1.2, label="residual, nominal")
        # a line equal to another is not drawn (it would hide under it yet be listed in the legend)
        if not np.allclose(plots["psd_after"][:, c], plots["psd_before"][:, c]):
            ax.loglog(freq, np.sqrt(plots["psd_after"][:, c] * to_asd), color="tab:blue", lw=1.2,
                      label="residual, with effects")
        ax.loglog(freq, np.sqrt(plots["psd_model"][:, c] * to_asd), color="k", lw=1.0, ls="--", label="nominal noise")
        if not np.allclose(plots["psd_model_after"][:, c], plots["psd_model"][:, c]):
            ax.loglog(freq, np.sqrt(plots["psd_model_after"][:, c] * to_asd), color="gray", lw=1.0, ls=":",
                      label="noise with effects")
        group = name.rsplit("_", 1)[0]
        ax.set_title(f"{name} [{_UNITS[group]}/rtHz]", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        if c == 0:
            ax.legend(fontsize=7, title=None if effects_drawn else "no effect accepted: residual = nominal's",
                      title_fontsize=7)
        if c // 3 == 4:
            ax.set_xlabel("frequency [Hz]")
    figure.suptitle(f"Residual ASD vs nominal noise - {result.verdict.get('summary', '')}"[:150], fontsize=11)
    figure.tight_layout(rect=(0, 0, 1, 0.97))
    figure.savefig(out / "psd_overlay.png", dpi=90)
    written.append("psd_overlay.png")

    bands = plots["bands"]
    labels = [f"{lo:.0e}-{hi:.0e}" for lo, hi in bands]
    figure = Figure(figsize=(14, 7))
    FigureCanvasAgg(figure)
    axes = figure.subplots(1, 2)
    vmax = max(float(np.max(plots["gap_map_before"])), float(plots["threshold"]) * 1.5, 1.0)
    for ax, key, title in ((axes[0], "gap_map_before", "nominal model"), (axes[1], "gap_map_after", "with effects")):
        data = np.asarray(plots[key])
        image = ax.imshow(data, aspect="auto", cmap="magma_r", vmin=0.0, vmax=vmax)
        ax.set_yticks(range(len(CHANNELS)), CHANNELS, fontsize=8)
        ax.set_xticks(range(len(labels)), labels, rotation=60, fontsize=7)
        for (i, j), value in np.ndenumerate(data):
            if value >= float(plots["threshold"]):
                ax.text(j, i, "*", ha="center", va="center", color="cyan", fontsize=10)
        ax.set_title(f"-log10 p by channel and band: {title}", fontsize=10)
        ax.set_xlabel("frequency band [Hz]")
        ax.set_ylabel("channel")
        figure.colorbar(image, ax=ax, fraction=0.046).set_label("significance of the excess, -log10 p")
    onsets = "; ".join(f"{key} from {value:.0f} +- {sigma:.0f} s" for key, value, sigma in plots.get("onsets", []))
    figure.suptitle(f"gap map (* above the threshold {plots['threshold']:.2f})"
                    + (f"; onsets: {onsets}" if onsets else ""), fontsize=11)
    figure.tight_layout(rect=(0, 0, 1, 0.95))
    figure.savefig(out / "gap_map.png", dpi=90)
    written.append("gap_map.png")
    return written


def write_report(result: DiagnosisResult, out_dir: str | Path, plots: bool = True,
                 choice: dict[str, Any] | None = None) -> dict[str, Path]:
    """Write ``report.json``, ``report.md`` and the PNG plots.

    Parameters
    ----------
    result : DiagnosisResult
        The diagnosis.
    out_dir : str or pathlib.Path
        Directory (created if missing).
    plots : bool
        Also write the PNG plots.
    choice : dict, optional
        Which calibration to use (:func:`.calibration_choice.calibration_choice`): a report section and
        ``calibration_to_use`` in ``report.json``.

    Returns
    -------
    dict of str to pathlib.Path
        Written files by name.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    with open(out / "report.json", "w", encoding="utf-8") as stream:
        data = result.to_json_dict()
        if choice is not None:
            data["calibration_to_use"] = choice
        json.dump(data, stream, indent=1, default=_json_default, allow_nan=False)
    files["report.json"] = out / "report.json"
    names = ["report.json", "report.md"]
    if plots and result.status == "ok":
        for name in _plots(result, out):
            files[name] = out / name
            names.append(name)
    (out / "report.md").write_text(_markdown(result, names, choice), encoding="utf-8")
    files["report.md"] = out / "report.md"
    return files
