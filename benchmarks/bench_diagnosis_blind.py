"""Blind benchmark of the sim-to-real gap diagnosis.

Length (over 600 lines): one script a user runs as one command (draw, simulate, diagnose, score, shard,
summarize); its pieces are used nowhere else.

Generates data sets of 3 h (Type-1 by default) with none, one or two catalog effects drawn at
random (family, variant, sign, magnitude near the detection limit), plus data sets with an effect
the diagnoser does not know (a catalog effect left out of its candidates, or an effect defined only
here), and runs the diagnosis on the raw arrays only (the draw stays in this process's bookkeeping).
The sets fly the layout's square-wave preset with the GRS readout unclipped (``--clipped``: saturating at
the range, the layout's default, which that preset leaves in ~15 % of the Type-1 samples: clipped
samples are outside the diagnosis's model, and the clean sets then read "unexplained").

Two fidelities, half the sets each: ``standard`` (the simulator of the node graph, the nominal
model's own conventions; its draws include the timing families) and ``reference`` (the
independently discretised source of :mod:`taiji2_sim_pkg.core.reference`, with random timing
conventions unknown to the diagnoser: GRS stamp, star-tracker stamp offset and actuation latency
each zero or uniform in +-0.15 s, thruster time constant zero or uniform in 0..0.15 s; its drawn
effects are physical ones, the conventions being its timing). The work runs on Dask (a local
cluster of ``--workers`` processes, or ``--scheduler``). Prints the score table:

- top-1 attribution: the first accepted effect is the drawn one (strict), or one of its reported
  aliases (alias-aware: signatures the data cannot tell apart, e.g. a torque gain g and an inertia
  error -g on the same axis);
- false alarms on clean data: a physical (non-timing) effect named; separately, "unexplained";
- timing findings on clean sets: the named timing effects reduce to a command-to-GRS group delay
  G = D + T, a star-tracker offset e and, where a lag is named beside a delay, the lag T
  (docs/interfaces.md); their error against the drawn conventions, in sigmas; components left
  unnamed (below the detection limit, or missed);
- magnitude error in sigmas (fitted minus drawn, over the fitted sigma);
- held-out shrink of the correctly named effects;
- out-of-catalog: "unexplained" (success) vs a confident wrong name.

Magnitudes are drawn as k sigma, k uniform in [kmin, kmax] (default 4..12), sigma being the 1-sigma
of the variant on these data (``variant_sensitivities`` on a clean reference run); the gain floor of
the selection is 3.8 sigma, "detectable" means k >= 6 here. Catalog effects left out of the
candidates are drawn at 15..30 sigma (a gap the diagnosis must see without the matching template).
Pairs are scored over all pairs and over the pairs whose two components are both detectable: a
component drawn at 4..5 sigma clears the floor with probability Phi(k - 3.8) (66 % at 4.2 sigma)
for any test at this false-alarm rate, less once its partner is fitted beside it;
``two_both_found_expected_at_floor`` is the mean over the pairs of that product, what the draw
alone allows. A component drawn below k = 6 is one the held-out part cannot confirm, so it is named only above
naming rule 2b's floor (delta chi2 18.0, 4.24 sigma; ``standing``): ``two_both_found_expected_at_naming_floor``
is the same mean with Phi(k - 4.24), what the draw allows at the naming level.

Usage::

    python benchmarks/bench_diagnosis_blind.py [--sets 40] [--layout type1] [--seed 1] [--workers 2]
        [--duration-s 10800] [--kmin 4] [--kmax 12] [--reference-fraction 0.5] [--json results.json]
        [--clean N] [--pairs N] [--out-of-catalog N] [--onset-fraction F] [--transients N] [--multi N]
        [--impulses N] [--clipped] [--shard I/N] [--merge JSON [JSON ...]]

Several hundred sets take hours on two cores: ``--shard I/N`` runs the sets of the plan whose index is I
modulo N (the same plan on every shard: give every shard the same other arguments), each writing its
``--json``; ``--merge`` scores those files together (without running anything).

The plan of issue 39 (pairs with onsets, multi-parameter effects with onsets, impulses; the scores include
both effects of a pair named, pairs fully explained, wrong names, the corrected G and d within 3 sigma
where biased and never worse than the nominal calibration + 1 sigma)::

    python benchmarks/bench_diagnosis_blind.py --sets 24 --clean 2 --pairs 6 --out-of-catalog 1 \
        --onset-fraction 0.5 --impulses 4 --multi 2 --seed 11 --json taiji2_out/blind39.json

The extended plan of issue 24 (onsets, multi-parameter effects, transients, both fidelities)::

    python benchmarks/bench_diagnosis_blind.py --sets 36 --clean 8 --pairs 2 --out-of-catalog 2 \
        --onset-fraction 0.7 --transients 3 --multi 3 --json taiji2_out/blind.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one BLAS thread per worker
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
from dask.distributed import as_completed  # noqa: E402
from scipy.stats import chi2 as chi2_dist  # noqa: E402

try:
    from taiji2_estimator_pkg.diagnosis import FAMILIES, DiagnosisOptions, candidate_catalog, diagnose, prepare_input
except ImportError:  # editable install made before the package had modules
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src" / "taiji2_estimator_pkg"))
    from taiji2_estimator_pkg.diagnosis import FAMILIES, DiagnosisOptions, candidate_catalog, diagnose, prepare_input
from taiji2_apps.campaign.engine import open_cluster  # noqa: E402
from taiji2_estimator_pkg.diagnosis.candidates import ONSET_KINDS, TIMING_FAMILIES  # noqa: E402
from taiji2_estimator_pkg.diagnosis.model import NominalModel  # noqa: E402
from taiji2_estimator_pkg.diagnosis.sensitivities import variant_sensitivities  # noqa: E402
from taiji2_estimator_pkg.diagnosis.standing import unconfirmed_floor  # noqa: E402
from taiji2_model.config import load_config  # noqa: E402
from taiji2_model.effect_catalog import GravityGradient, make_effect  # noqa: E402
from taiji2_model.effects import Effect  # noqa: E402
from taiji2_sim_pkg.core.reference import simulate_reference  # noqa: E402
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch  # noqa: E402

#: a drawn magnitude (in sigmas of the variant alone) at or above which the effect is detectable here
DETECTABLE_K = 6.0

#: the selection's floor in sigmas (delta chi2 14.5: the Bonferroni gain floor over the catalog)
FLOOR_K = 3.8

#: the naming floor of an effect the held-out part cannot confirm (naming rule 2b, delta chi2 18.0 for one parameter:
#: every component drawn below k = 6 is such an effect), in sigmas
NAMING_FLOOR_K = math.sqrt(unconfirmed_floor(float(chi2_dist.sf(FLOOR_K ** 2, 1)), 1))

PHYSICAL = tuple(f for f in FAMILIES if f not in TIMING_FAMILIES)

EXCLUDABLE = ("readout_nonlinearity", "tm_stiffness", "thruster_force_leakage")


class SinusoidalTorque(Effect):
    """Out-of-catalog: a periodic disturbance torque (e.g. a mechanism), not among the candidates."""

    name = "sinusoidal_torque"

    def __init__(self, amplitude_n_m: float, frequency_hz: float, axis: int) -> None:
        self.amplitude_n_m, self.frequency_hz, self.axis = amplitude_n_m, frequency_hz, axis

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        out = np.array(torque_n_m)
        out[:, self.axis] += self.amplitude_n_m * np.sin(2 * np.pi * self.frequency_hz * t_s)
        return out


class GrsBiasStep(Effect):
    """Out-of-catalog: a step in one linear GRS readout half-way through the run."""

    name = "grs_bias_step"

    def __init__(self, step_m_s2: float, grs: int, axis: int, t_step_s: float) -> None:
        self.step_m_s2, self.grs, self.axis, self.t_step_s = step_m_s2, grs, axis, t_step_s

    def grs_accelerations(self, t_s: np.ndarray, grs_id: int, angular: np.ndarray, linear: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
        if grs_id != self.grs:
            return angular, linear
        out = np.array(linear)
        out[:, self.axis] += np.where(t_s >= self.t_step_s, self.step_m_s2, 0.0)
        return angular, out


ONSET_FAMILIES = tuple(f for f in FAMILIES if f not in ("star_tracker_lowfreq_noise", "grs_time_offset"))
"""Families drawn with an onset (the noise's onset is not estimated; a GRS stamp convention changing
mid-run is not simulated)."""


def _with_onset(drawn: dict, rng: np.random.Generator, onset_fraction: float, duration_s: float) -> dict:
    """Give a drawn effect an onset (with probability ``onset_fraction``), uniform in 15..60 % of the run,
    its magnitude scaled so that its detectability stays k sigma (a step active over a fraction f of the
    run has sigma / sqrt(f); a drift over the last part, (1 / f)^1.5)."""
    if drawn["family"] not in ONSET_FAMILIES or rng.random() >= onset_fraction:
        rng.random()  # keep the plan's stream independent of the draw
        return drawn
    return _at_onset(drawn, float(rng.uniform(0.15, 0.6)) * duration_s, duration_s)


def _at_onset(drawn: dict, onset: float, duration_s: float) -> dict:
    """The drawn effect from ``onset`` [s] on, scaled to keep its detectability (see :func:`_with_onset`)."""
    active = 1.0 - onset / duration_s
    scale = active ** -1.5 if ONSET_KINDS[drawn["family"]] == "ramp" else active ** -0.5
    spec = _scaled(drawn["spec"], scale)
    spec["onset_s"] = onset
    truth = {key: value * scale for key, value in drawn["truth"].items()}
    return dict(drawn, spec=spec, truth=truth, onset_s=onset)


def _scaled(spec: dict, scale: float) -> dict:
    keys = ("rate_per_s", "misalignment_rad", "imbalance", "offset_s", "gain", "rate_m_s", "k", "relative",
            "products_kg_m2", "scale", "stiffness_s2", "leakage_per_m", "delay_s", "time_constant_s")
    out = dict(spec)
    for key in keys:
        if key in out:
            out[key] = (np.asarray(out[key], dtype=np.float64) * scale).tolist()
    return out


class TorquePulse(Effect):
    """Out-of-catalog transient: a short disturbance torque (a micrometeoroid hit, a glitch) about one axis."""

    name = "torque_pulse"

    def __init__(self, amplitude_n_m: float, t_start_s: float, duration_s: float, axis: int) -> None:
        self.amplitude_n_m, self.t_start_s, self.duration_s, self.axis = amplitude_n_m, t_start_s, duration_s, axis

    def applied_torque_n_m(self, t_s: np.ndarray, torque_n_m: np.ndarray) -> np.ndarray:
        out = np.array(torque_n_m)
        hit = (t_s >= self.t_start_s) & (t_s < self.t_start_s + self.duration_s)
        out[hit, self.axis] += self.amplitude_n_m
        return out


def _draw_effect(rng: np.random.Generator, families: list[str], sigmas: dict[str, float], kmin: float, kmax: float,
                 model: NominalModel, by_family: dict[str, list], noise: object) -> dict:
    family = str(rng.choice(families))
    k = float(rng.uniform(kmin, kmax))
    sign = float(rng.choice([-1.0, 1.0])) if family != "thruster_response" else 1.0  # a time constant is >= 0
    if family == "star_tracker_lowfreq_noise":
        kappa = k * sigmas[family]
        spec = noise.inject(np.array([kappa]), model)  # type: ignore[attr-defined]
        return {"family": family, "variant": family, "k": k, "spec": spec, "truth": {family: math.sqrt(kappa)}}
    candidate = by_family[family][int(rng.integers(len(by_family[family])))]
    magnitude = sign * k * sigmas[candidate.key]
    if family == "gravity_gradient":
        # one physical scale drives all three axes: its size is set by the most sensitive axis at k sigma
        # (through a nearly insensitive axis, k sigma would mean an absurd torque on the other two)
        rng.uniform(0, 2 * np.pi)  # the phase is fixed by the orbit; drawn only to keep the plan's stream
        specs = {c.key: c.inject(np.array([k * sigmas[c.key], 0.0]), model) for c in by_family[family]}
        key = min(specs, key=lambda c: specs[c]["scale"])
        candidate, spec = next(c for c in by_family[family] if c.key == key), specs[key]
        effect = GravityGradient(orbit_period_s=spec["orbit_period_s"], scale=spec["scale"])
        _, tau_c, tau_s = effect.harmonic_coefficients_n_m(model.inertia_kg_m2)
        truth = {f"gravity_gradient[{'xyz'[a]}]": float(np.hypot(tau_c[a], tau_s[a])) for a in range(3)}
        return {"family": family, "variant": candidate.key, "k": k, "spec": spec, "truth": truth}
    spec = candidate.inject(np.array([magnitude]), model)
    return {"family": family, "variant": candidate.key, "k": k, "spec": spec, "truth": {candidate.key: magnitude}}


def _timing_convention(rng: np.random.Generator) -> dict[str, float]:
    """Random timing conventions of a reference set (layout overrides; each part zero half the time)."""
    def part(low: float, high: float) -> float:
        return float(rng.uniform(low, high)) if rng.random() < 0.5 else 0.0

    return {"timing.grs_stamp": part(-0.15, 0.15), "timing.star_tracker_stamp_offset_s": part(-0.15, 0.15),
            "timing.actuation_latency_s": part(-0.15, 0.15), "timing.thruster_time_constant_s": part(0.0, 0.15)}


def make_plan(count: int, seed: int, sigmas: dict[str, float], model: NominalModel, kmin: float, kmax: float,
              clean: int | None = None, fidelity: str = "standard", onset_fraction: float = 0.0,
              duration_s: float = 10800.0, out_of_catalog: int | None = None, pairs: int | None = None) -> list[dict]:
    """The hidden draw of every data set (``clean``: number of clean sets, default 20 %)."""
    rng = np.random.default_rng(seed)
    candidates, noise = candidate_catalog()
    by_family: dict[str, list] = {}
    for candidate in candidates:
        by_family.setdefault(candidate.name, []).append(candidate)
    families = list(FAMILIES if fidelity == "standard" else PHYSICAL)
    n_clean = max(4, round(0.2 * count)) if clean is None else clean
    rest = count - n_clean
    n_out = (max(3, round(0.15 * count)) if rest > 0 else 0) if out_of_catalog is None else out_of_catalog
    n_two = (max(3, round(0.15 * count)) if rest > 0 else 0) if pairs is None else pairs
    n_one = max(0, rest - n_out - n_two)
    plan = []
    for _ in range(n_clean):
        plan.append({"kind": "clean", "effects": []})
    onset_rng = np.random.default_rng(seed + 104729)  # its own stream: the plan without onsets is unchanged
    for _ in range(n_one):
        drawn = _draw_effect(rng, families, sigmas, kmin, kmax, model, by_family, noise)
        plan.append({"kind": "one", "effects": [_with_onset(drawn, onset_rng, onset_fraction, duration_s)]})
    for _ in range(n_two):
        first = _draw_effect(rng, families, sigmas, kmin, kmax, model, by_family, noise)
        second = _draw_effect(rng, [f for f in families if f != first["family"]], sigmas, kmin, kmax, model,
                              by_family, noise)
        plan.append({"kind": "two", "effects": [first, _with_onset(second, onset_rng, onset_fraction, duration_s)]})
    for i in range(n_out):
        if i % 2 == 0:
            left_out = EXCLUDABLE[(i // 2) % len(EXCLUDABLE)]
            drawn = _draw_effect(rng, [left_out], sigmas, 15.0, 30.0, model, by_family, noise)
            plan.append({"kind": "out_of_catalog", "effects": [drawn], "exclude": left_out})
        elif i % 4 == 1:
            plan.append({"kind": "out_of_catalog", "private": {"name": "sinusoidal_torque",
                         "amplitude_n_m": float(rng.uniform(1.5e-8, 3e-8)), "frequency_hz": float(rng.uniform(
                             2e-3, 8e-3)), "axis": int(rng.integers(3))}, "effects": []})
        else:
            plan.append({"kind": "out_of_catalog", "private": {"name": "grs_bias_step",
                         "step_m_s2": float(rng.choice([-1, 1]) * rng.uniform(1e-12, 2e-12)),
                         "grs": int(rng.integers(1, 3)), "axis": int(rng.integers(3)), "t_step_s": 5400.0},
                         "effects": []})
    for entry in plan:
        entry["fidelity"] = fidelity
        entry["timing"] = _timing_convention(rng) if fidelity == "reference" else {}
    order = rng.permutation(len(plan))
    return [dict(plan[i], index=int(j), seed=int(seed * 1000 + j)) for j, i in enumerate(order)]


def _private(spec: dict) -> Effect:
    spec = dict(spec)
    name = spec.pop("name")
    if name == "torque_pulse":
        return TorquePulse(**spec)
    return SinusoidalTorque(**spec) if name == "sinusoidal_torque" else GrsBiasStep(**spec)


def transient_plan(count: int, seed: int, model: NominalModel, duration_s: float, fidelity: str) -> list[dict]:
    """Transient sets: a torque pulse of 5 s about one axis at a random time (10..90 % of the run), of
    3..6 times the thruster torque noise per step (40..200 times its energy in one step)."""
    rng = np.random.default_rng(seed + 15485863)
    sigma = float(np.sqrt(np.max(model.var_torque)))
    plan = []
    for _ in range(count):
        plan.append({"kind": "transient", "effects": [], "fidelity": fidelity,
                     "timing": _timing_convention(rng) if fidelity == "reference" else {},
                     "private": {"name": "torque_pulse", "amplitude_n_m": float(rng.choice([-1, 1])
                                 * rng.uniform(3.0, 6.0) * sigma), "t_start_s": float(rng.uniform(0.1, 0.9)
                                                                                       * duration_s),
                                 "duration_s": 5.0, "axis": int(rng.integers(3))}})
    return plan


def impulse_plan(count: int, seed: int, model: NominalModel, duration_s: float, fidelity: str) -> list[dict]:
    """Impulse sets: one momentum kick at a random time (10..90 % of the run), its angular momentum along a
    random direction at a matched-filter SNR uniform in 4..16 in the torque channel (against the thruster torque
    and GRS angular noise per sample), a linear impulse of 0..3 sigma of the thruster force noise per step along
    another random direction."""
    rng = np.random.default_rng(seed + 32452843)
    dt = model.dt_s
    # per-sample covariance of the torque channel (rad s^-2)^2: thruster torque noise through J^-1, GRS angular
    # readout noise of the mean of the two GRS (white; docs/diagnosis.md section 3)
    cov = model.inertia_inv @ np.diag(model.var_torque) @ model.inertia_inv.T + 0.25 * sum(
        c.T @ np.diag(v) @ c for c, v in zip(model.c_tmrf, model.var_angular, strict=True))
    plan = []
    for _ in range(count):
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        snr = float(rng.uniform(4.0, 16.0))
        acc = direction * snr / math.sqrt(direction @ np.linalg.solve(cov, direction))  # rad s^-2 in one sample
        linear = rng.standard_normal(3)
        linear *= (rng.uniform(0.0, 3.0) * math.sqrt(float(np.max(model.var_force_acc))) * model.mass_kg * dt
                   / np.linalg.norm(linear))
        plan.append({"kind": "impulse", "fidelity": fidelity, "snr": snr,
                     "timing": _timing_convention(rng) if fidelity == "reference" else {},
                     "effects": [{"family": "impulse", "variant": "", "k": snr, "spec": {
                         "name": "impulse", "time_s": float(rng.uniform(0.1, 0.9) * duration_s),
                         "angular_momentum_n_m_s": (model.inertia_kg_m2 @ acc * dt).tolist(),
                         "linear_impulse_n_s": linear.tolist()}}]})
    return plan


def impulse_scores(results: list[dict]) -> dict:
    """Impulses: found (an event within 0.2 s of the drawn time) per SNR band, the time and L errors, the
    verdict; clean sets with a reported impulse, and the other sets without a drawn impulse that report one."""
    rows = [r for r in results if r["kind"] == "impulse"]
    clean = [r for r in results if r["kind"] == "clean"]
    # the other sets hold no impulse either: one reported there is false, whatever else the set holds
    others = [r for r in results if r["kind"] not in ("impulse", "clean")]
    out: dict = {"impulse_sets": len(rows),
                 "clean_with_an_impulse": sum(bool(r["impulses"]) for r in clean) / max(len(clean), 1),
                 "other_sets_with_an_impulse": f"{sum(bool(r['impulses']) for r in others)}/{len(others)}",
                 "other_sets_impulses_max": max((len(r["impulses"]) for r in others), default=0)}
    found, dt_err, z, z_time = {}, [], [], []
    for r in rows:
        spec = r["drawn"][0]["spec"]
        hits = [e for e in r["impulses"] if abs(e["time_s"] - spec["time_s"]) <= 0.2]
        band = "snr>=8" if r["drawn"][0]["k"] >= 8.0 else "snr6-8" if r["drawn"][0]["k"] >= 6.0 else "snr<6"
        found.setdefault(band, []).append(bool(hits))
        if hits:
            dt_err.append(hits[0]["time_s"] - spec["time_s"])
            z_time.append(dt_err[-1] / hits[0]["time_sigma_s"])
            z += list((np.array(hits[0]["angular_momentum_n_m_s"]) - spec["angular_momentum_n_m_s"])
                      / np.array(hits[0]["angular_momentum_sigma_n_m_s"]))
    for band, hits in sorted(found.items()):
        out[f"impulse_found_{band}"] = f"{sum(hits)}/{len(hits)}"
    strong = found.get("snr>=8", [])
    out["impulse_found_snr>=8_fraction"] = float(np.mean(strong)) if strong else None
    out["impulse_time_error_max_s"] = float(np.max(np.abs(dt_err))) if dt_err else None
    out["impulse_L_z_std"] = float(np.std(z)) if len(z) > 1 else None
    out["impulse_time_z_rms"] = float(np.sqrt(np.mean(np.square(z_time)))) if z_time else None
    out["impulse_explained"] = sum(not r["verdict"]["unexplained"] for r in rows)
    out["impulse_with_a_catalog_name"] = sum(bool(_physical(r["accepted"])) for r in rows)
    return out


#: Multi-parameter effects (issue 24: one effect, several parameters): (family, variant suffixes of one
#: GRS or axis set). The variants' specs of one effect are merged into one spec (vectors add) where the
#: effect takes a vector, else injected side by side (a drift of several channels).
MULTI_KINDS = (("cross_coupling", ("misalign_x", "misalign_y", "misalign_z", "imbalance_x", "imbalance_y",
                                   "imbalance_z")),
               ("cross_coupling", ("misalign_x", "misalign_y", "misalign_z")),
               ("inertia_error", ("x", "y", "z")),
               ("com_drift", ("x", "y", "z")),
               ("scale_factor_drift", ("x", "y", "z")))


def _merged(specs: list[dict]) -> list[dict]:
    """Specs of one effect merged: the vectors of the same effect (name, GRS) added."""
    out: dict[tuple, dict] = {}
    vectors = ("misalignment_rad", "imbalance", "relative", "products_kg_m2", "rate_m_s")
    for spec in specs:
        key = (spec["name"], spec.get("grs"), None if any(v in spec for v in vectors) else spec.get("axis"))
        if key not in out:
            out[key] = dict(spec)
            continue
        for name in vectors:
            if name in spec:
                base = np.asarray(out[key].get(name, np.zeros(3)), dtype=np.float64)
                out[key][name] = (base + np.asarray(spec[name], dtype=np.float64)).tolist()
    return list(out.values())


def multi_plan(count: int, seed: int, sigmas: dict[str, float], model: NominalModel, fidelity: str,
               kmin: float = 6.0, kmax: float = 12.0, onset_fraction: float = 0.0, duration_s: float = 10800.0
               ) -> list[dict]:
    """Multi-parameter sets: every variant of one effect of one GRS (or the three axes) at once, each
    component k sigma (k uniform in kmin..kmax, random sign), the kinds of :data:`MULTI_KINDS` in turn; with
    probability ``onset_fraction`` all of it from one onset on (uniform in 15..60 % of the run, scaled as
    :func:`_with_onset`)."""
    rng = np.random.default_rng(seed + 32452843)
    onset_rng = np.random.default_rng(seed + 49979687)  # its own stream: the plan without onsets is unchanged
    candidates, _ = candidate_catalog()
    by_key = {c.key: c for c in candidates}
    plan = []
    for i in range(count):
        family, suffixes = MULTI_KINDS[i % len(MULTI_KINDS)]
        grs = int(rng.integers(1, 3))
        prefix = "" if family == "inertia_error" else f"grs{grs}."
        keys = [f"{family}[{prefix}{suffix}]" for suffix in suffixes]
        truth, specs, ks = {}, [], []
        for key in keys:
            ks.append(float(rng.uniform(kmin, kmax)))
            magnitude = float(rng.choice([-1.0, 1.0]) * ks[-1] * sigmas[key])
            truth[key] = magnitude
            specs.append(by_key[key].inject(np.array([magnitude]), model))
        drawn = [{"family": family, "variant": f"{family}[{prefix}{'+'.join(suffixes)}]", "k": max(ks),
                  "spec": spec, "truth": truth if j == 0 else {}} for j, spec in enumerate(_merged(specs))]
        if family in ONSET_FAMILIES and onset_rng.random() < onset_fraction:
            onset = float(onset_rng.uniform(0.15, 0.6)) * duration_s
            drawn = [_at_onset(d, onset, duration_s) for d in drawn]
        plan.append({"kind": "multi", "effects": drawn, "fidelity": fidelity,
                     "timing": _timing_convention(rng) if fidelity == "reference" else {}})
    return plan


def multi_scores(results: list[dict]) -> dict:
    """Multi-parameter sets: named as the one drawn family (no other physical name but its aliases, not "unexplained"),
    and the magnitudes (the standing family's vector, else the accepted variants') against the truth."""
    rows = [r for r in results if r["kind"] == "multi"]
    named, named_once, zs, onset_z = 0, 0, [], []
    for r in rows:
        family = r["drawn"][0]["family"]
        onset = r["drawn"][0].get("onset_s")
        if onset is not None:  # every named variant of the family: its modelled onset against the drawn one
            onset_z += [(a["onset_s"]["value"] - onset) / a["onset_s"]["sigma"]
                        for a in _physical(r["accepted"]) if a["name"] == family and a["onset_s"]
                        and a["onset_s"]["modelled"] and a["onset_s"]["sigma"] > 0]
        truth = r["drawn"][0]["truth"]
        physical = _physical(r["accepted"])
        # every physical name is the family or an alias of it (a torque gain for an inertia error)
        only_family = bool(physical) and all(a["name"] == family or any(_family(x) == family for x in a["aliases"])
                                             for a in physical)
        if only_family and not r["verdict"]["unexplained"]:
            named += 1
        standing = [f for f in r["verdict"].get("families", []) if f["stands"] and f["family"].startswith(family)]
        if standing and only_family:
            named_once += 1
            for key, value, sigma in zip(standing[0]["variants"], standing[0]["magnitudes"], standing[0]["sigmas"],
                                         strict=True):
                if key in truth and sigma > 0:
                    zs.append((value - truth[key]) / sigma)
        else:
            zs += [(a["magnitude"] - truth[a["key"]]) / a["sigma"] for a in r["accepted"]
                   if a["key"] in truth and a["sigma"]]
    z = np.array(zs)
    return {"multi_sets": len(rows), "multi_named_family_only": named, "multi_named_as_one_family": named_once,
            "multi_magnitude_z_std": float(np.std(z)) if z.size > 1 else None,
            "multi_magnitude_within_3_sigma": float(np.mean(np.abs(z) <= 3.0)) if z.size else None,
            "multi_with_onset": sum(r["drawn"][0].get("onset_s") is not None for r in rows),
            "multi_onset_within_2_sigma": (f"{int(np.sum(np.abs(onset_z) <= 2.0))}/{len(onset_z)}" if onset_z
                                           else None)}


def run_one(args: tuple[dict, str, float]) -> dict:
    """Simulate one data set and diagnose it from the raw arrays only."""
    entry, layout, duration_s = args
    config = load_config(layout)  # the diagnoser's nominal model: the layout, default conventions
    data_config = load_config(layout, {**(entry.get("timing") or {}), **entry.get("data_overrides", {})} or None)
    n = round(duration_s * config.sample_rate_hz)
    commands = maneuver_torque_commands(config, n)
    effects = [make_effect(**e["spec"]) for e in entry["effects"]]
    if entry.get("private"):
        effects.append(_private(entry["private"]))
    effects.sort(key=lambda e: e.name == "time_offset")
    if entry.get("fidelity") == "reference":
        out = simulate_reference(data_config, entry["seed"], commands, effects=effects)
    else:
        out = simulate_batch(data_config, entry["seed"], commands, effects=effects)
    inp = prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)
    families = tuple(f for f in FAMILIES if f != entry.get("exclude"))
    started = time.perf_counter()
    result = diagnose(inp, config, DiagnosisOptions(candidates=families))
    elapsed = time.perf_counter() - started
    effects_out = [{"key": e.key, "name": e.name, "magnitude": e.magnitude, "sigma": e.sigma, "accepted": e.accepted,
                    "aliases": e.aliases, "shrink": e.shrink, "shrink_heldout": e.shrink_heldout,
                    "heldout_z": e.heldout_z, "timing": e.name in TIMING_FAMILIES,
                    "onset_s": e.parameters.get("onset_s")} for e in result.effects if e.accepted]
    calibration = None
    if result.status == "ok":
        middle = int(np.argmin(np.abs(out.t_s - 0.5 * (out.t_s[0] + out.t_s[-1]))))
        calibration = {
            "g_true": np.asarray(out.truth.grs_angular_scale_factors)[middle].tolist(),
            "d_true": np.asarray(out.truth.com_offset_m)[middle].tolist(),
            "nominal": {k: result.calibration[k] for k in ("g_angular", "g_angular_sigma_relative", "com_offset_m",
                                                            "com_offset_sigma_m")},
            "corrected": {k: result.corrected[k] for k in ("g_angular", "g_angular_sigma_relative", "com_offset_m",
                                                            "com_offset_sigma_m")} if result.corrected else None}
    rejected = [{"key": e.key, "reason": e.rejected} for e in result.effects if e.rejected]
    impulses = result.impulses.get("events", []) if result.status == "ok" else []
    return {"index": entry["index"], "kind": entry["kind"], "drawn": entry["effects"], "private": entry.get("private"),
            "exclude": entry.get("exclude"), "fidelity": entry.get("fidelity", "standard"),
            "timing_truth": _reduced(data_config, effects), "status": result.status, "verdict": result.verdict,
            "accepted": effects_out, "rejected": rejected, "seconds": elapsed, "t0_s": float(inp.t_s[0]),
            "calibration": calibration, "impulses": impulses}


def _reduced(config: object, effects: list) -> dict[str, float]:
    """The data's observable timing [s]: the command-to-GRS group delay G = D + T, the star-tracker
    offset e and the thruster lag T (conventions plus drawn timing effects; docs/interfaces.md)."""
    timing = config.timing  # type: ignore[attr-defined]
    st_extra = 0.0
    for effect in effects:
        if effect.name == "time_offset":
            st_extra += effect.offset_s
        else:
            timing = effect.timing(timing)
    delay, st_offset, lag = timing.reduced
    return {"G": delay + lag, "e": st_offset + st_extra, "T": lag}


def _implied_timing(accepted: list[dict], sigma_e: float) -> dict[str, tuple[float, float] | None]:
    """(value, sigma) of G, e and T implied by the named timing effects (None: nothing named for it).

    At low frequency a lag T is a delay T, so a small lag is named as a delay (and the report lists
    the two as aliases): the group delay G is what the data fix. T is scored only where a lag is
    named beside a delay (the split, which the harmonics decide). Sigmas of sums are added in
    quadrature, ignoring the (negative) correlation of jointly fitted parts: conservative. A GRS
    time offset fixes G to its own sigma, but e only through the star tracker: its e is scored with
    ``sigma_e``, the 1-sigma of a star-tracker offset on these data.
    """
    parts: dict[str, list[tuple[float, float]]] = {"G": [], "e": [], "T": []}
    names = {a["name"] for a in accepted}
    for a in accepted:
        value, sigma = a["magnitude"], a["sigma"]
        if a["name"] == "actuation_delay":
            parts["G"].append((value, sigma))
        elif a["name"] == "grs_time_offset":
            parts["G"].append((value, sigma))
            parts["e"].append((-value, sigma_e))
        elif a["name"] == "time_offset":
            parts["e"].append((value, sigma))
        elif a["name"] == "thruster_response":
            parts["G"].append((value, sigma))
            if names & {"actuation_delay", "grs_time_offset"}:
                parts["T"].append((value, sigma))
    return {key: (sum(v for v, _ in items), math.sqrt(sum(s * s for _, s in items))) if items else None
            for key, items in parts.items()}


def _family(key: str) -> str:
    return key.split("[")[0]


def _physical(accepted: list[dict]) -> list[dict]:
    return [a for a in accepted if not a["timing"]]


def timing_findings(results: list[dict], sigma_e: float) -> dict:
    """Named timing against the drawn (G, e, T) on clean sets: errors in sigmas, components not named."""
    errors, missed, spurious = [], [], []
    for r in results:
        implied = _implied_timing(r["accepted"], sigma_e)
        for key, truth in r["timing_truth"].items():
            found = implied[key]
            if found is not None:
                value, sigma = found
                errors.append((key, (value - truth) / sigma if sigma > 0 else float("inf")))
            elif abs(truth) > 0.0 and key != "T":  # T unnamed: a lag named as (aliased with) a delay
                missed.append((key, truth))
        spurious += [a["key"] for a in r["accepted"] if a["timing"] and not any(r["timing_truth"].values())]
    z = np.abs(np.array([e for _, e in errors]))
    return {"named_components": int(z.size), "within_2_sigma": float(np.mean(z <= 2.0)) if z.size else None,
            "abs_error_sigma_median": float(np.median(z)) if z.size else None,
            "abs_error_sigma_max": float(np.max(z)) if z.size else None,
            "errors_sigma": [f"{k}:{e:+.1f}" for k, e in errors],
            "not_named": [f"{k}={v:+.3f} s" for k, v in missed], "named_without_timing": spurious}


def wrong_names(r: dict) -> list[str]:
    """The physical families named in a set that are neither drawn nor an alias of a drawn one (timing names are
    a reference set's own conventions: not counted)."""
    drawn = {d["family"] for d in r["drawn"]}
    return sorted({a["name"] for a in _physical(r["accepted"])
                   if a["name"] not in drawn and not any(_family(x) in drawn for x in a["aliases"])})


def score(results: list[dict], sigma_e: float) -> dict:
    """Score table."""
    table: dict[str, object] = {}
    clean = [r for r in results if r["kind"] == "clean"]
    table["clean_sets"] = len(clean)
    table["false_alarms_physical"] = sum(bool(_physical(r["accepted"])) for r in clean)
    table["clean_unexplained"] = sum(bool(r["verdict"]["unexplained"]) for r in clean)
    table["clean_alarms"] = sum(bool(_physical(r["accepted"])) or bool(r["verdict"]["unexplained"]) for r in clean)
    table["timing_on_clean"] = timing_findings(clean, sigma_e)
    rows = []
    for r in results:
        if r["kind"] not in ("one", "two"):
            continue
        for position, drawn in enumerate(r["drawn"]):
            # a physical draw is scored against the first physical name (a reference set's timing
            # conventions are named too), a timing draw against the first name of any kind
            accepted = r["accepted"] if drawn["family"] in TIMING_FAMILIES else _physical(r["accepted"])
            top = accepted[0] if accepted else None
            drawn_family = drawn["family"]
            strict = top is not None and any(top["name"] == d["family"] for d in r["drawn"])
            alias = strict or (top is not None and any(_family(a) == d["family"] for a in top["aliases"]
                                                       for d in r["drawn"]))
            found = next((a for a in accepted if a["name"] == drawn_family), None)
            if found is None:
                found = next((a for a in accepted if any(_family(x) == drawn_family for x in a["aliases"])), None)
            z = None
            if found is not None and found["key"] in drawn["truth"]:
                truth = drawn["truth"][found["key"]]
                z = (found["magnitude"] - truth) / found["sigma"] if found["sigma"] else None
            rows.append({"kind": r["kind"], "family": drawn_family, "k": drawn["k"], "first": position == 0,
                         "top1_strict": strict, "top1_alias": alias, "found": found is not None, "z": z,
                         "shrink_heldout": found["shrink_heldout"] if found else None,
                         "heldout_z": found["heldout_z"] if found else None,
                         "unexplained": r["verdict"]["unexplained"]})
    one = [x for x in rows if x["kind"] == "one"]
    detectable = [x for x in one if x["k"] >= DETECTABLE_K]
    for label, group in (("single", one), ("single_detectable", detectable)):
        table[f"{label}_sets"] = len(group)
        table[f"{label}_top1_strict"] = sum(x["top1_strict"] for x in group) / max(len(group), 1)
        table[f"{label}_top1_alias_aware"] = sum(x["top1_alias"] for x in group) / max(len(group), 1)
        table[f"{label}_found"] = sum(x["found"] for x in group) / max(len(group), 1)
    two = [r for r in results if r["kind"] == "two"]
    two_rows = [x for x in rows if x["kind"] == "two"]
    table["two_sets"] = len(two)
    table["two_top1_in_drawn"] = sum(x["top1_alias"] for x in two_rows if x["first"]) / max(len(two), 1)
    def covered(r: dict, drawn: dict) -> bool:
        return any(a["name"] == drawn["family"] or any(_family(x) == drawn["family"] for x in a["aliases"])
                   for a in r["accepted"])

    def pair_scores(label: str, group: list[dict]) -> None:
        table[f"{label}_both_found"] = sum(all(covered(r, d) for d in r["drawn"]) for r in group) / max(len(group), 1)
        table[f"{label}_fully_explained"] = sum(all(covered(r, d) for d in r["drawn"])
                                                and not r["verdict"]["unexplained"] for r in group) / max(len(group), 1)

    pair_scores("two", two)
    # what the draw allows: a component drawn at k sigma clears the floor with probability Phi(k - floor) for any
    # test at this false-alarm rate (less once its partner is fitted beside it), so a pair drawn near the floor
    # is missed by construction; the pairs with both components detectable (k >= 6, as for single sets) are
    # scored apart
    for label, floor_k in (("floor", FLOOR_K), ("naming_floor", NAMING_FLOOR_K)):
        table[f"two_both_found_expected_at_{label}"] = float(np.mean([
            np.prod([0.5 * (1.0 + math.erf((d["k"] - floor_k) / math.sqrt(2.0))) for d in r["drawn"]]) for r in two
        ])) if two else None
    detectable_two = [r for r in two if all(d["k"] >= DETECTABLE_K for d in r["drawn"])]
    table["two_detectable_sets"] = len(detectable_two)
    pair_scores("two_detectable", detectable_two)
    table["wrong_names"] = [f"set {r['index']}: {name}" for r in results if r["kind"] in ("one", "two")
                            for name in wrong_names(r)]
    zs = np.array([x["z"] for x in rows if x["z"] is not None])
    table["magnitude_error_sigma_median_abs"] = float(np.median(np.abs(zs))) if zs.size else None
    table["magnitude_error_sigma_rms"] = float(np.sqrt(np.mean(zs ** 2))) if zs.size else None
    table["magnitude_within_3_sigma"] = float(np.mean(np.abs(zs) <= 3.0)) if zs.size else None
    shrinks = np.array([x["shrink_heldout"] for x in rows if x["found"] and x["shrink_heldout"] is not None])
    table["heldout_shrink_median"] = float(np.median(shrinks)) if shrinks.size else None
    table["heldout_shrink_positive"] = float(np.mean(shrinks > 0)) if shrinks.size else None
    hz = np.array([x["heldout_z"] for x in rows if x["found"] and x["heldout_z"] is not None])
    table["heldout_z_median"] = float(np.median(hz)) if hz.size else None
    out = [r for r in results if r["kind"] == "out_of_catalog"]
    table["out_of_catalog_sets"] = len(out)
    table["out_of_catalog_unexplained"] = sum(r["verdict"]["unexplained"] for r in out) / max(len(out), 1)
    table["out_of_catalog_confident_wrong"] = sum((not r["verdict"]["unexplained"]) and bool(
        _physical(r["accepted"])) for r in out) / max(len(out), 1)
    table["out_of_catalog_named_physical_beside_unexplained"] = sum(
        r["verdict"]["unexplained"] and bool(_physical(r["accepted"])) for r in out) / max(len(out), 1)
    table["out_of_catalog_missed"] = sum((not r["verdict"]["unexplained"]) and not _physical(r["accepted"])
                                         for r in out) / max(len(out), 1)
    per_family = {}
    for family in FAMILIES:
        group = [x for x in one if x["family"] == family]
        if group:
            per_family[family] = f"{sum(x['top1_alias'] for x in group)}/{len(group)}"
    table["single_top1_alias_aware_by_family"] = per_family
    table.update(onset_scores(results))
    table.update(transient_scores(results))
    table.update(impulse_scores(results))
    table.update(multi_scores(results))
    table.update(corrected_scores(results))
    table["seconds_median"] = float(np.median([r["seconds"] for r in results]))
    table["seconds_max"] = float(np.max([r["seconds"] for r in results]))
    return table


def _match(r: dict, drawn: dict) -> dict | None:
    """The accepted effect that names a drawn one (its family or an alias)."""
    for a in r["accepted"]:
        if a["name"] == drawn["family"] or any(_family(x) == drawn["family"] for x in a["aliases"]):
            return a
    return None


def transient_scores(results: list[dict]) -> dict:
    """Transients: "unexplained", and a remaining location whose time window holds the pulse."""
    rows = [r for r in results if r["kind"] == "transient"]
    unexplained = sum(bool(r["verdict"]["unexplained"]) for r in rows)
    located = 0
    for r in rows:
        pulse = r["private"]
        start, end = pulse["t_start_s"], pulse["t_start_s"] + pulse["duration_s"]
        for loc in r["verdict"].get("remaining", []):
            if "window_s" in loc:
                lo, hi = loc["window_s"]
                slack = loc.get("window_resolution_s", 0.0)
                run = loc["segment_s"][1] - loc["segment_s"][0]
                if lo - slack <= end and start <= hi + slack and hi - lo < 0.5 * run:
                    located += 1
                    break
    confident_wrong = sum((not r["verdict"]["unexplained"]) and bool(_physical(r["accepted"])) for r in rows)
    return {"transient_sets": len(rows), "transient_unexplained": unexplained,
            "transient_window_contains_it": located, "transient_confident_wrong": confident_wrong}


def onset_scores(results: list[dict]) -> dict:
    """Onsets: the named effect's onset against the drawn one (0 for an effect present from the start)."""
    with_onset, from_start = [], []
    for r in results:
        for drawn in r["drawn"]:
            found = _match(r, drawn)
            if found is None or not found.get("onset_s"):
                continue
            onset = found["onset_s"]
            truth = drawn.get("onset_s", r.get("t0_s", 0.0))
            z = (onset["value"] - truth) / onset["sigma"]
            (with_onset if "onset_s" in drawn else from_start).append((z, onset["modelled"]))
    out: dict[str, object] = {}
    for label, rows in (("onset_drawn", with_onset), ("onset_from_start", from_start)):
        z = np.array([row[0] for row in rows])
        out[f"{label}_named"] = len(rows)
        out[f"{label}_modelled"] = sum(row[1] for row in rows)
        out[f"{label}_within_2_sigma"] = float(np.mean(np.abs(z) <= 2.0)) if z.size else None
        out[f"{label}_z_std"] = float(np.std(z)) if z.size > 1 else None
        out[f"{label}_z"] = [round(float(v), 2) for v in z]
    return out


def _calibration_z(part: dict, g_true: np.ndarray, d_true: np.ndarray) -> np.ndarray:
    """(12,) errors of G (relative) and d in their sigmas."""
    zg = (np.array(part["g_angular"]) / g_true - 1.0) / np.array(part["g_angular_sigma_relative"])
    zd = (np.array(part["com_offset_m"]) - d_true) / np.array(part["com_offset_sigma_m"])
    return np.concatenate((zg.ravel(), zd.ravel()))


def corrected_scores(results: list[dict]) -> dict:
    """Nominal and corrected G, d against the truth (at the middle of the run), in their sigmas.

    A parameter is *biased* by the drawn effect when its nominal calibration is more than 3 sigma from
    the truth; the goal is the corrected one within 2 sigma there.
    """
    biased_nominal, biased_corrected, corrected_all, sigma_ratio = [], [], [], []
    sets = worse = 0
    for r in results:
        cal = r.get("calibration")
        if not cal or not cal["corrected"] or r["kind"] not in ("one", "two", "multi"):
            continue
        sets += 1
        g_true, d_true = np.array(cal["g_true"]), np.array(cal["d_true"])

        zn, zc = (_calibration_z(cal[part], g_true, d_true) for part in ("nominal", "corrected"))
        corrected_all += zc.tolist()
        sigmas = [np.concatenate((np.ravel(cal[part]["g_angular_sigma_relative"]),
                                  np.ravel(cal[part]["com_offset_sigma_m"]))) for part in ("nominal", "corrected")]
        sigma_ratio += (sigmas[1] / sigmas[0]).tolist()
        biased = np.abs(zn) > 3.0
        biased_nominal += zn[biased].tolist()
        biased_corrected += zc[biased].tolist()
        worse += bool(np.max(np.abs(zc)) > np.max(np.abs(zn)) + 1.0)
    zc_all = np.array(corrected_all)
    zb = np.array(biased_corrected)
    return {"corrected_sets": sets, "corrected_biased_parameters": int(zb.size),
            "corrected_biased_within_2_sigma": float(np.mean(np.abs(zb) <= 2.0)) if zb.size else None,
            "corrected_biased_within_3_sigma": float(np.mean(np.abs(zb) <= 3.0)) if zb.size else None,
            "corrected_worse_than_nominal_plus_1_sigma": worse,
            "corrected_biased_nominal_abs_z_median": float(np.median(np.abs(biased_nominal))) if zb.size else None,
            "corrected_biased_abs_z_median": float(np.median(np.abs(zb))) if zb.size else None,
            "corrected_all_z_std": float(np.std(zc_all)) if zc_all.size > 1 else None,
            # the price of the corrected calibration's honesty: its sigma over the nominal one's (aliases, rivals
            # and near misses widen it; the re-fitted effects' marginalisation too)
            "corrected_sigma_ratio_median": float(np.median(sigma_ratio)) if sigma_ratio else None,
            "corrected_sigma_ratio_p90": float(np.percentile(sigma_ratio, 90)) if sigma_ratio else None,
            "corrected_all_within_2_sigma": float(np.mean(np.abs(zc_all) <= 2.0)) if zc_all.size else None}


def summarize(results: list[dict], sigma_e: float, header: str, failures: list[str], json_path: str) -> None:
    """Score the results (of one run, one shard, or merged shards), print the tables and the goals, write the JSON."""
    results = sorted(results, key=lambda r: r["index"])
    tables = {"all": score(results, sigma_e)}
    for fidelity in ("standard", "reference"):
        subset = [r for r in results if r["fidelity"] == fidelity]
        if subset:
            tables[fidelity] = score(subset, sigma_e)
    print(f"\nblind benchmark: {header}")
    if failures:
        print(f"  FAILED sets: {len(failures)} ({'; '.join(failures)})")
    width = max(len(k) for k in tables["all"])
    for name, table in tables.items():
        print(f" [{name}]")
        for key, value in table.items():
            shown = f"{value:.3f}" if isinstance(value, float) else value
            print(f"  {key:{width}s}  {shown}")
    goals = []
    for name in ("standard", "reference"):
        table = tables.get(name)
        if table is None:
            continue
        goals += [
            (f"{name}: top-1 (alias-aware) at detectable magnitudes >= 0.95", table["single_detectable_sets"],
             table["single_detectable_top1_alias_aware"] >= 0.95),
            (f"{name}: clean data named or 'unexplained' <= 5 %", table["clean_sets"],
             table["clean_alarms"] <= 0.05 * max(table["clean_sets"], 1)),
            (f"{name}: out of catalog unexplained, no confident wrong name", table["out_of_catalog_sets"],
             table["out_of_catalog_unexplained"] == 1.0 and table["out_of_catalog_confident_wrong"] == 0.0)]
    reference = tables.get("reference")
    if reference is not None:
        findings = reference["timing_on_clean"]
        goals.append(("reference: timing on clean data named within 2 sigma", findings["named_components"],
                      findings["within_2_sigma"] == 1.0))
    for name in ("standard", "reference"):
        table = tables.get(name)
        if table is None:
            continue
        goals.append((f"{name}: onset within 2 sigma >= 90 %", table["onset_drawn_named"],
                      (table["onset_drawn_within_2_sigma"] or 0.0) >= 0.9))
        goals.append((f"{name}: onset error/sigma std in [0.8, 1.25]", table["onset_drawn_named"],
                      table["onset_drawn_z_std"] is not None and 0.8 <= table["onset_drawn_z_std"] <= 1.25))
        goals.append((f"{name}: transient unexplained with a window holding it >= 90 %", table["transient_sets"],
                      table["transient_window_contains_it"] >= 0.9 * max(table["transient_sets"], 1)))
        goals.append((f"{name}: impulses of SNR >= 8 found within 0.2 s >= 90 %", table["impulse_sets"],
                      (table["impulse_found_snr>=8_fraction"] or 0.0) >= 0.9))
        goals.append((f"{name}: clean sets with a reported impulse <= 5 %", table["clean_sets"],
                      table["clean_with_an_impulse"] <= 0.05))
        goals.append((f"{name}: multi-parameter effect named as its family alone >= 90 %", table["multi_sets"],
                      table["multi_named_family_only"] >= 0.9 * max(table["multi_sets"], 1)))
        goals.append((f"{name}: both effects of a pair named >= 80 %", table["two_sets"],
                      table["two_both_found"] >= 0.8))
        goals.append((f"{name}: pairs fully explained >= 90 %", table["two_sets"],
                      table["two_fully_explained"] >= 0.9))
        goals.append((f"{name}: both named >= 80 %, pairs detectable on their own", table["two_detectable_sets"],
                      table["two_detectable_both_found"] >= 0.8))
        goals.append((f"{name}: fully explained >= 90 %, pairs detectable on their own", table["two_detectable_sets"],
                      table["two_detectable_fully_explained"] >= 0.9))
        goals.append((f"{name}: no wrong names", table["single_sets"] + table["two_sets"], not table["wrong_names"]))
        goals.append((f"{name}: corrected G, d within 3 sigma where biased >= 90 %",
                      table["corrected_biased_parameters"], (table["corrected_biased_within_3_sigma"] or 0.0) >= 0.9))
        goals.append((f"{name}: corrected never worse than nominal + 1 sigma", table["corrected_sets"],
                      table["corrected_worse_than_nominal_plus_1_sigma"] == 0))
    goals.append(("<= 60 s per 3-h set", len(results), tables["all"]["seconds_max"] <= 60.0))
    goals.append(("every set ran", len(results) + len(failures), not failures))
    for label, sets, ok in goals:
        print(f"  goal {label}: {'n/a (no such sets)' if not sets else 'met' if ok else 'NOT met'}")
    if json_path:
        Path(json_path).write_text(json.dumps({"tables": tables, "results": results, "sigma_time_offset_s": sigma_e,
                                               "failures": failures, "header": header}, indent=1, default=str))


def merge(paths: list[str], json_path: str) -> int:
    """Score the ``--json`` files of shards of one plan together (a set in two files counts once)."""
    results: dict[int, dict] = {}
    failures, headers, sigma_e = [], [], None
    for path in paths:
        data = json.loads(Path(path).read_text())
        results.update({r["index"]: r for r in data["results"]})
        failures += data.get("failures", [])
        headers.append(data.get("header", path))
        sigma_e = data["sigma_time_offset_s"]
    summarize(list(results.values()), sigma_e, f"{len(paths)} shards merged: " + " | ".join(headers), failures,
              json_path)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, default=40)
    parser.add_argument("--layout", default="type1")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2, help="local Dask workers (default 2)")
    parser.add_argument("--scheduler", default="", help="address of an existing Dask scheduler instead")
    parser.add_argument("--duration-s", type=float, default=10800.0)
    parser.add_argument("--kmin", type=float, default=4.0)
    parser.add_argument("--kmax", type=float, default=12.0)
    parser.add_argument("--clean", type=int, default=None, help="number of clean sets (default 20 %%)")
    parser.add_argument("--reference-fraction", type=float, default=0.5,
                        help="fraction of the sets drawn at reference fidelity (default 0.5)")
    parser.add_argument("--json", default="", help="write the per-set results and the table here")
    parser.add_argument("--out-of-catalog", type=int, default=None,
                        help="out-of-catalog sets per fidelity (default 15 %%, at least 3)")
    parser.add_argument("--pairs", type=int, default=None,
                        help="two-effect sets per fidelity (default 15 %%, at least 3)")
    parser.add_argument("--impulses", type=int, default=0,
                        help="impulse sets (a momentum kick, SNR 4..16) per fidelity, added to --sets (default 0)")
    parser.add_argument("--transients", type=int, default=0,
                        help="transient sets (a torque pulse) per fidelity, added to --sets (default 0)")
    parser.add_argument("--multi", type=int, default=0,
                        help="multi-parameter sets (one effect, several parameters) per fidelity, added to --sets")
    parser.add_argument("--onset-fraction", type=float, default=0.0,
                        help="fraction of the drawn effects (single sets, second effect of pairs) that start "
                             "mid-run (default 0: the plan of the earlier runs)")
    parser.add_argument("--clipped", action="store_true",
                        help="simulate the data with the GRS readout saturating at the range (the layout's default); "
                             "without it the readout is unclipped: the sets fly the layout's square-wave preset, "
                             "which leaves the range in ~15 %% of Type-1 samples, and clipped samples are outside "
                             "the diagnosis's model")
    parser.add_argument("--shard", default="",
                        help="I/N: run only the sets of the plan whose index is I modulo N (shards of one plan run on "
                             "several machines or days; --merge their --json files for the whole table)")
    parser.add_argument("--merge", nargs="+", default=[], metavar="JSON",
                        help="score the --json files of shards of one plan together instead of running")
    args = parser.parse_args()
    if args.merge:
        return merge(args.merge, args.json)
    workers = max(1, args.workers)
    config = load_config(args.layout)
    model = NominalModel.from_config(config)
    started = time.perf_counter()
    n = round(args.duration_s * config.sample_rate_hz)
    commands = maneuver_torque_commands(config, n)
    data_overrides = {} if args.clipped else {"grs.readout_saturation": False}
    reference = simulate_batch(load_config(args.layout, data_overrides or None), 10**6 + args.seed, commands)
    sigmas = variant_sensitivities(prepare_input(reference.t_s, reference.st_quat_xyzw, reference.voltages_v,
                                                 commands, config.sample_rate_hz), config)
    print(f"variant sensitivities on a clean reference run: {time.perf_counter() - started:.1f} s", file=sys.stderr)
    n_reference = round(args.reference_fraction * args.sets)
    clean = None if args.clean is None else (args.clean - args.clean // 2, args.clean // 2)
    plan = make_plan(args.sets - n_reference, args.seed, sigmas, model, args.kmin, args.kmax,
                     None if clean is None else clean[0], "standard", args.onset_fraction,
                     args.duration_s, args.out_of_catalog, args.pairs) if args.sets - n_reference else []
    if n_reference:
        plan += make_plan(n_reference, args.seed + 7919, sigmas, model, args.kmin, args.kmax,
                          None if clean is None else clean[1], "reference", args.onset_fraction, args.duration_s,
                          args.out_of_catalog, args.pairs)
    if args.transients:
        plan += transient_plan(args.transients, args.seed, model, args.duration_s, "standard")
        plan += transient_plan(args.transients, args.seed + 1, model, args.duration_s, "reference")
    if args.impulses:
        plan += impulse_plan(args.impulses, args.seed, model, args.duration_s, "standard")
        plan += impulse_plan(args.impulses, args.seed + 1, model, args.duration_s, "reference")
    if args.multi:
        plan += multi_plan(args.multi, args.seed, sigmas, model, "standard", onset_fraction=args.onset_fraction,
                           duration_s=args.duration_s)
        plan += multi_plan(args.multi, args.seed + 1, sigmas, model, "reference", onset_fraction=args.onset_fraction,
                           duration_s=args.duration_s)
    for index, entry in enumerate(plan):
        entry["index"], entry["seed"] = index, args.seed * 1000 + index
        entry["data_overrides"] = data_overrides
    if args.shard:
        shard, shards = (int(x) for x in args.shard.split("/"))
        plan = [entry for entry in plan if entry["index"] % shards == shard]
    results: list[dict] = []
    failures: list[str] = []
    with open_cluster(args.scheduler or None, workers) as client:  # Dask: the campaign engine's cluster
        futures = [client.submit(run_one, (entry, args.layout, args.duration_s), pure=False) for entry in plan]
        for future in as_completed(futures):
            try:
                result = future.result()
            except Exception as exc:  # a failed set is reported and counted, the others go on
                failures.append(f"set {plan[futures.index(future)]['index']}: {type(exc).__name__}: {exc}")
                print(f"set failed: {failures[-1]}", file=sys.stderr, flush=True)
                continue
            results.append(result)
            if args.json:  # as it goes: a cut-short run keeps what it has
                Path(args.json + ".partial").write_text(json.dumps({"results": results}, default=str))
            drawn = ", ".join(f"{d['variant']} ({d['k']:.1f} sigma" + (f", from {d['onset_s']:.0f} s" if "onset_s" in d
                                                                     else "") + ")" for d in result["drawn"]) or (
                result["private"]["name"] if result["private"] else "none")
            if result["exclude"]:
                drawn += f" [{result['exclude']} left out]"
            truth = result["timing_truth"]
            if any(truth.values()):
                drawn += " | timing " + " ".join(f"{k}={v:+.3f}" for k, v in truth.items() if v)
            got = ", ".join(f"{a['key']}={a['magnitude']:.3g}" if a["timing"] else a["key"]
                            for a in result["accepted"]) or "-"
            print(f"[{len(results):3d}/{len(plan)}] {result['fidelity'][:3]} {result['kind']:14s} drawn: {drawn:60s} "
                  f"-> {got}{' UNEXPLAINED' if result['verdict']['unexplained'] else ''} ({result['seconds']:.1f} s)",
                  file=sys.stderr, flush=True)
    n_standard = sum(entry["fidelity"] == "standard" for entry in plan)
    header = (f"{len(plan)} data sets of {args.duration_s / 3600:.1f} h ({n_standard} standard, "
              f"{len(plan) - n_standard} reference fidelity), layout {args.layout}, "
              f"magnitudes {args.kmin:g}..{args.kmax:g} sigma, seed {args.seed}"
              + (f", shard {args.shard} ({len(results) + len(failures)} sets)" if args.shard else "")
              + f", wall {time.perf_counter() - started:.0f} s")
    summarize(results, sigmas["time_offset"], header, failures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
