"""One campaign case: batch simulation, offline estimators, CRLB, optional diagnosis -> rows.

:func:`run_case` is a pure function of its case dict (deterministic for the seed), so Dask may run
it on any worker and rerun it after a worker is lost. It never raises: a failure becomes one row
with ``status == "error"`` and the message.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import traceback
from collections.abc import Mapping
from functools import lru_cache
from typing import Any

import numpy as np

G_NAMES = ("G_Pphi", "G_Ptheta", "G_Ppsi")
AXES = ("x", "y", "z")
#: Row parameter names, in table order: G and d of GRS1 and GRS2, then d_1 - d_2.
PARAMETERS = ([f"grs{g}.{p}" for g in (1, 2) for p in G_NAMES] + [f"grs{g}.d_{a}" for g in (1, 2) for a in AXES]
              + [f"diff.d_{a}" for a in AXES])


def default_maneuver(layout: str) -> str | None:
    """A case's maneuver when the spec names none: what every verb flies by default (``design`` where the
    built-in layout ships one; a layout file or a layout without a design: its own square wave, None)."""
    from taiji2_model.maneuver_choice import choose_maneuver

    try:
        return "design" if choose_maneuver(str(layout), None, 1.0).kind == "design" else None
    except ValueError:  # a layout file: its own maneuver section
        return None


def maneuver_end_s(layout: str, maneuver: str | None) -> float:
    """The end [s] of a case's maneuver (its default duration)."""
    from taiji2_model.config import builtin_layouts, load_config
    from taiji2_model.maneuver_choice import choose_maneuver

    if maneuver is None or maneuver in builtin_layouts():
        m = load_config(str(layout if maneuver is None else maneuver)).maneuver
        return float(m.start_s + m.duration_s)
    return choose_maneuver(str(layout), maneuver, None).duration_s


def case_config(case: Mapping[str, Any]) -> Any:
    """The validated SimConfig of a case (layout, maneuver, duration, overrides).

    ``maneuver``: None, the layout's own square wave; a built-in layout name, that layout's square wave;
    otherwise a ``--maneuver`` choice (``design``, ``paper`` or a maneuver file) of the square family, whose
    period, amplitudes, phases and start replace the layout's (the batch simulator and the bound fly the
    configuration's square wave). ConfigError (key ``maneuver``) for a maneuver a case cannot fly.
    """
    from taiji2_model.config import ConfigError, builtin_layouts, load_config
    from taiji2_model.maneuver import SquareWaveManeuver
    from taiji2_model.maneuver_choice import choose_maneuver

    overrides: dict[str, Any] = {}
    maneuver = case.get("maneuver")
    if maneuver in builtin_layouts():
        preset = load_config(str(maneuver)).to_dict()["maneuver"]
        overrides.update({f"maneuver.{k}": v for k, v in preset.items() if k not in ("start_s", "duration_s")})
    elif maneuver and maneuver != "paper":
        try:
            flown = choose_maneuver(str(case["layout"]), str(maneuver), float(case["duration_s"])).maneuver
        except ValueError as exc:
            raise ConfigError("maneuver", str(exc)) from None
        if not isinstance(flown, SquareWaveManeuver):
            raise ConfigError("maneuver", f"{maneuver}: a campaign flies square waves (the batch simulator's and "
                              f"the bound's maneuver), got family {type(flown).__name__}")
        overrides.update({"maneuver.period_s": float(flown.period_s),
                          "maneuver.amplitude_n_m": [float(v) for v in flown.amplitude_n_m],
                          "maneuver.phase_s": [float(v) for v in flown.phase_s],
                          "maneuver.start_s": float(flown.start_s)})
    overrides["maneuver.duration_s"] = float(case["duration_s"])
    overrides.update(case.get("overrides", {}))
    return load_config(str(case["layout"]), overrides=overrides)


def config_hash(config: Any) -> str:
    """Hash of the full resolved configuration (what the simulator actually ran)."""
    return hashlib.sha256(json.dumps(config.to_dict(), sort_keys=True, default=str).encode()).hexdigest()[:20]


def run_case(case: Mapping[str, Any]) -> dict[str, Any]:
    """Run one case.

    Returns
    -------
    dict
        ``{"case_hash", "status" ("ok" | "error"), "error", "compute_s", "cpu_s", "rows": [...]}``;
        one row per method and parameter (G relative to truth is left to the summary: rows are SI).
        ``compute_s`` is the case's wall time, ``cpu_s`` the CPU time of its whole process over the
        case (in a Dask worker the worker's own threads included; on a busy machine the fairer
        measure of what a case costs). ``worker_pid`` is the process that ran it.
    """
    started = time.perf_counter()
    cpu_started = time.process_time()
    try:
        rows = _rows(case)
        status, error = "ok", ""
    except Exception as exc:  # a failing case is data, not the end of the campaign
        rows, status = [], "error"
        error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=4)}"
    compute_s = time.perf_counter() - started
    cpu_s = time.process_time() - cpu_started
    for row in rows:
        row["compute_s"] = compute_s
    return {"case_hash": case["case_hash"], "status": status, "error": error, "compute_s": compute_s,
            "cpu_s": cpu_s, "worker_pid": os.getpid(), "rows": rows}


def _rows(case: Mapping[str, Any]) -> list[dict[str, Any]]:
    from taiji2_estimator_pkg.core.instrument import InstrumentModel
    from taiji2_estimator_pkg.core.pipeline import calibrate
    from taiji2_model.config import load_config
    from taiji2_model.effect_catalog import effects_from_config
    from taiji2_sim_pkg.core.reference import simulate_reference
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    config = case_config(case)
    cfg_hash = config_hash(config)
    commands = maneuver_torque_commands(config)
    effects = effects_from_config(case.get("effects", []))
    simulate = simulate_reference if case.get("fidelity", "standard") == "reference" else simulate_batch
    out = simulate(config, int(case["seed"]), commands, effects=effects)
    model_config = config
    if case.get("model_overrides"):
        model_config = load_config(config.to_dict(), overrides=dict(case["model_overrides"]))
    instrument = InstrumentModel.from_layout(model_config)
    g_true = np.concatenate([s.angular_scale_factors for s in config.grs.sensors])
    d_true = np.concatenate([s.com_offset_m for s in config.grs.sensors])
    truth = np.concatenate([g_true, d_true, d_true[:3] - d_true[3:]])
    # the bound of the data (their noise budget), which an estimator with another model cannot beat
    bound = _crlb(cfg_hash, config) if case.get("crlb", True) else np.full(truth.size, np.nan)
    verdict = _diagnose(case, config, out, commands) if case.get("diagnose") else ""
    rows = []
    for method in case["methods"]:
        r = calibrate(out.t_s, out.st_quat_xyzw, out.voltages_v, instrument, method=method)
        diff, diff_cov = r.com_offsets.difference()
        estimate = np.concatenate([r.scale_factors.values, r.com_offsets.values, diff])
        sigma = np.concatenate([r.scale_factors.sigma, r.com_offsets.sigma, np.sqrt(np.diag(diff_cov))])
        nis = [r.scale_factors.nis_mean] * 6 + [r.com_offsets.nis_mean] * 9
        nis_band = [float("nan")] * 6 + [r.com_offsets.nis_band] * 9
        for j, name in enumerate(PARAMETERS):
            rows.append({"case_hash": case["case_hash"], "group": case["group"], "layout": str(case["layout"]),
                         "duration_s": float(case["duration_s"]), "seed": int(case["seed"]), "method": method,
                         "overrides": json.dumps(case.get("overrides", {}), sort_keys=True),
                         "effects": json.dumps(case.get("effects", []), sort_keys=True),
                         "fidelity": str(case.get("fidelity", "standard")),
                         "model_overrides": json.dumps(case.get("model_overrides", {}), sort_keys=True),
                         "config_hash": cfg_hash, "parameter": name,
                         "unit": "rad s^-2 V^-1" if j < 6 else "m",
                         "estimate": float(estimate[j]), "sigma": float(sigma[j]), "truth": float(truth[j]),
                         "error": float(estimate[j] - truth[j]), "crlb": float(bound[j]),
                         "nis_mean": float(nis[j]), "nis_band": float(nis_band[j]),
                         "noise_adjusted": bool(r.com_offsets.noise_adjusted) if j >= 6 else False,
                         "diagnosis": verdict})
    return rows


@lru_cache(maxsize=16)
def _crlb_cached(cfg_hash: str, config_json: str) -> tuple[float, ...]:
    from taiji2_apps.layout_bound import crlb_for_layout

    bound = crlb_for_layout(json.loads(config_json))
    return tuple(np.concatenate([bound.scale_factor_sigma, bound.com_offset_sigma, bound.difference_sigma()]))


def _crlb(cfg_hash: str, config: Any) -> np.ndarray:
    # the bound depends on the configuration only: computed once per worker and configuration
    return np.asarray(_crlb_cached(cfg_hash, json.dumps(config.to_dict(), sort_keys=True)))


def _diagnose(case: Mapping[str, Any], config: Any, out: Any, commands: np.ndarray) -> str:
    from taiji2_estimator_pkg.diagnosis.engine import diagnose
    from taiji2_estimator_pkg.diagnosis.inputs import prepare_input

    inp = prepare_input(out.t_s, out.st_quat_xyzw, out.voltages_v, commands, config.sample_rate_hz)
    result = diagnose(inp, config)
    named = [e.key for e in result.effects if e.accepted]
    return json.dumps({"status": result.status, "accepted": named})
