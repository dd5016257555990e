"""Campaign spec: a YAML mapping that expands into cases (one simulation + calibration each).

Every key is checked before anything runs; a bad key or value raises :class:`SpecError` naming it.
A case is a plain JSON-able dict, so it can be shipped to any worker and rerun there.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

#: Keys of a spec, with their meaning (docs/campaigns.md documents each).
SPEC_KEYS = {
    "name": "campaign name (str)",
    "layouts": "built-in layout names or YAML config paths (list)",
    "maneuvers": "what is flown (list, default [null]): null, what every verb flies by default (the layout's "
                 "shipped design where it has one, else its square wave); design; paper; a maneuver file of "
                 "the square family; or a built-in layout whose square wave replaces the case's",
    "durations_s": "experiment durations [s] (list, default [null]: the maneuver's end)",
    "seeds": "list of ints, or {start: int, count: int}",
    "methods": "estimator methods, subset of [gls, paper]",
    "overrides": "dotted-key config overrides applied to every case (mapping)",
    "grid": "dotted key -> list of values; the cases span their cartesian product (mapping)",
    "effect_sets": "list of effect sets; each a list of {name: <catalog effect>, <params>} ([] = none)",
    "fidelities": "simulators of the data, subset of [standard, reference] (list, default [standard]); "
                  "reference: independently discretised, its own timing conventions and noise streams",
    "model_overrides": "dotted-key overrides of the estimators' instrument model only (mapping, default {}): "
                       "data made with one noise budget, estimated with another",
    "crlb": "compute the Cramer-Rao bound per case (bool, default true)",
    "diagnose": "run the sim-to-real diagnosis per case (bool, default false)",
    "chunk_size": "completed cases per Parquet file (int, default 25)",
    "cases": "explicit list of cases instead of / besides the grid: mappings with keys layout, "
             "maneuver, duration_s, seed, overrides, effects",
}
CASE_KEYS = ("layout", "maneuver", "duration_s", "seed", "overrides", "effects", "fidelity", "model_overrides")
METHODS = ("gls", "paper")
FIDELITIES = ("standard", "reference")


class SpecError(ValueError):
    """A campaign spec key with a bad value; the message starts with the key."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"campaign spec: {key}: {problem}")
        self.key = key


def load_spec(source: str | os.PathLike[str] | Mapping[str, Any]) -> dict[str, Any]:
    """Read (if a path) and validate a spec; return it normalised (all keys present).

    Raises
    ------
    SpecError
        Unknown key, bad value, or a configuration that does not load (the config's parameter named).
    """
    if isinstance(source, Mapping):
        raw: Any = dict(source)
    else:
        try:
            raw = yaml.safe_load(Path(source).read_text(encoding="utf-8"))
        except OSError as exc:
            raise SpecError("<file>", f"cannot read {str(source)!r}: {exc.strerror or exc}") from None
        except yaml.YAMLError as exc:
            raise SpecError("<file>", f"{str(source)!r} is not valid YAML: {exc}") from None
    if not isinstance(raw, dict):
        raise SpecError("<root>", "a campaign spec must be a mapping")
    unknown = sorted(set(raw) - set(SPEC_KEYS))
    if unknown:
        raise SpecError(unknown[0], f"unknown key (known: {', '.join(SPEC_KEYS)})")
    spec = {
        "name": str(raw.get("name", "campaign")),
        "layouts": _list(raw, "layouts", ["type1"]),
        "maneuvers": _list(raw, "maneuvers", [None]),
        "durations_s": [None if v is None else _positive("durations_s", v)
                        for v in _list(raw, "durations_s", [None])],
        "seeds": _seeds(raw.get("seeds", {"start": 1, "count": 1})),
        "methods": _methods(raw.get("methods", ["gls"])),
        "overrides": _mapping(raw, "overrides"),
        "grid": _grid(raw.get("grid", {})),
        "effect_sets": _effect_sets(raw.get("effect_sets", [[]])),
        "fidelities": _fidelities(raw.get("fidelities", ["standard"])),
        "model_overrides": _mapping(raw, "model_overrides"),
        "crlb": _bool(raw, "crlb", True),
        "diagnose": _bool(raw, "diagnose", False),
        "chunk_size": int(_positive("chunk_size", raw.get("chunk_size", 25))),
        "cases": _explicit_cases(raw.get("cases", [])),
    }
    if "cases" in raw and "layouts" not in raw and "grid" not in raw:
        spec["layouts"] = []  # explicit cases only
    try:
        cases = expand_cases(spec)
    except ValueError as exc:  # a maneuver that cannot be resolved (its end is the default duration)
        raise SpecError("maneuvers", " ".join(str(exc).split())) from None
    _check_configs(cases)
    return spec


def expand_cases(spec: Mapping[str, Any]) -> list[dict[str, Any]]:
    """All cases of a normalised spec, in a stable order, each with its ``case_hash``."""
    from taiji2_apps.campaign.case import default_maneuver, maneuver_end_s

    cases: list[dict[str, Any]] = []
    grid_keys = list(spec["grid"])
    grid_values = [spec["grid"][k] for k in grid_keys]
    for layout, maneuver, duration_s, combo, effects, fidelity, seed in itertools.product(
            spec["layouts"], spec["maneuvers"], spec["durations_s"], itertools.product(*grid_values),
            spec["effect_sets"], spec.get("fidelities", ["standard"]), spec["seeds"]):
        overrides = {**spec["overrides"], **dict(zip(grid_keys, combo, strict=True))}
        flown = default_maneuver(layout) if maneuver is None else maneuver
        duration_s = maneuver_end_s(layout, flown) if duration_s is None else duration_s
        cases.append({"layout": layout, "maneuver": flown, "duration_s": float(duration_s), "seed": int(seed),
                      "overrides": overrides, "effects": list(effects), "fidelity": fidelity,
                      "model_overrides": dict(spec.get("model_overrides", {}))})
    for case in spec["cases"]:
        layout = case.get("layout", "type1")
        flown = default_maneuver(layout) if case.get("maneuver") is None else case["maneuver"]
        duration_s = case.get("duration_s")
        cases.append({"layout": layout, "maneuver": flown,
                      "duration_s": float(maneuver_end_s(layout, flown) if duration_s is None else duration_s),
                      "seed": int(case.get("seed", 1)),
                      "overrides": {**spec["overrides"], **dict(case.get("overrides", {}))},
                      "effects": list(case.get("effects", [])),
                      "fidelity": _fidelities([case.get("fidelity", "standard")])[0],
                      "model_overrides": {**spec.get("model_overrides", {}), **dict(case.get("model_overrides", {}))}})
    for case in cases:
        case["methods"] = list(spec["methods"])
        case["crlb"] = bool(spec["crlb"])
        case["diagnose"] = bool(spec["diagnose"])
        case["group"] = group_label(case)
        case["case_hash"] = case_hash(case)
    return cases


def group_label(case: Mapping[str, Any]) -> str:
    """Everything that defines a case except its seed: the cases a statistic pools over."""
    parts = [str(case["layout"]), f"{case['duration_s']:g}s"]
    if case.get("maneuver"):
        parts.append(f"maneuver={case['maneuver']}")
    parts += [f"{k}={json.dumps(v)}" for k, v in sorted(case["overrides"].items())]
    parts += [json.dumps(e, sort_keys=True) for e in case["effects"]]
    if case.get("fidelity", "standard") != "standard":
        parts.append(f"fidelity={case['fidelity']}")
    parts += [f"model.{k}={json.dumps(v)}" for k, v in sorted(case.get("model_overrides", {}).items())]
    return " ".join(parts)


def case_hash(case: Mapping[str, Any]) -> str:
    """Content hash of a case (inputs only; a layout file contributes its text)."""
    body = {k: case.get(k) for k in (*CASE_KEYS, "methods", "crlb", "diagnose")}
    # defaults leave the hash of the cases from before these keys existed unchanged
    if body.get("fidelity") in (None, "standard"):
        body.pop("fidelity")
    if not body.get("model_overrides"):
        body.pop("model_overrides")
    layout = Path(str(case["layout"]))
    if layout.suffix in (".yaml", ".yml") and layout.is_file():
        body["layout_text"] = layout.read_text(encoding="utf-8")
    text = json.dumps(body, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _list(raw: Mapping[str, Any], key: str, default: list[Any]) -> list[Any]:
    value = raw.get(key, default)
    if not isinstance(value, list) or not value:
        raise SpecError(key, f"expected a non-empty list, got {value!r}")
    return value


def _positive(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise SpecError(key, f"expected a positive number, got {value!r}")
    return float(value)


def _bool(raw: Mapping[str, Any], key: str, default: bool) -> bool:
    value = raw.get(key, default)
    if not isinstance(value, bool):
        raise SpecError(key, f"expected true or false, got {value!r}")
    return value


def _mapping(raw: Mapping[str, Any], key: str) -> dict[str, Any]:
    value = raw.get(key, {}) or {}
    if not isinstance(value, dict):
        raise SpecError(key, f"expected a mapping, got {value!r}")
    return {str(k): v for k, v in value.items()}


def _seeds(value: Any) -> list[int]:
    if isinstance(value, dict):
        extra = sorted(set(value) - {"start", "count"})
        if extra:
            raise SpecError(f"seeds.{extra[0]}", "unknown key (known: start, count)")
        start, count = value.get("start", 1), value.get("count")
        if not isinstance(start, int) or isinstance(start, bool) or start < 0:
            raise SpecError("seeds.start", f"expected a non-negative int, got {start!r}")
        if not isinstance(count, int) or isinstance(count, bool) or count < 1:
            raise SpecError("seeds.count", f"expected a positive int, got {count!r}")
        return list(range(start, start + count))
    if isinstance(value, list) and value and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0
                                                 for s in value):
        if len(set(value)) != len(value):
            raise SpecError("seeds", "duplicate seeds")
        return list(value)
    raise SpecError("seeds", f"expected a list of non-negative ints or {{start, count}}, got {value!r}")


def _methods(value: Any) -> list[str]:
    if not isinstance(value, list) or not value or any(m not in METHODS for m in value):
        raise SpecError("methods", f"expected a non-empty subset of {list(METHODS)}, got {value!r}")
    return list(dict.fromkeys(value))


def _fidelities(value: Any) -> list[str]:
    if not isinstance(value, list) or not value or any(f not in FIDELITIES for f in value):
        raise SpecError("fidelities", f"expected a non-empty subset of {list(FIDELITIES)}, got {value!r}")
    return list(dict.fromkeys(value))


def _grid(value: Any) -> dict[str, list[Any]]:
    if not isinstance(value, dict):
        raise SpecError("grid", f"expected a mapping of dotted key -> list of values, got {value!r}")
    for key, values in value.items():
        if not isinstance(values, list) or not values:
            raise SpecError(f"grid.{key}", f"expected a non-empty list of values, got {values!r}")
    return {str(k): list(v) for k, v in value.items()}


def _effect_sets(value: Any) -> list[list[dict[str, Any]]]:
    from taiji2_model.effect_catalog import effects_from_config

    if not isinstance(value, list) or not value:
        raise SpecError("effect_sets", f"expected a non-empty list of effect lists, got {value!r}")
    for position, effects in enumerate(value):
        if not isinstance(effects, list):
            raise SpecError(f"effect_sets[{position}]", f"expected a list of effects, got {effects!r}")
        try:
            effects_from_config(effects)
        except ValueError as exc:
            raise SpecError(f"effect_sets[{position}]", str(exc)) from None
    return [list(e) for e in value]


def _explicit_cases(value: Any) -> list[dict[str, Any]]:
    if not isinstance(value, list):
        raise SpecError("cases", f"expected a list of case mappings, got {value!r}")
    for position, case in enumerate(value):
        if not isinstance(case, dict):
            raise SpecError(f"cases[{position}]", f"expected a mapping, got {case!r}")
        unknown = sorted(set(case) - set(CASE_KEYS))
        if unknown:
            raise SpecError(f"cases[{position}].{unknown[0]}", f"unknown key (known: {', '.join(CASE_KEYS)})")
        if "duration_s" in case:
            _positive(f"cases[{position}].duration_s", case["duration_s"])
        if "effects" in case:
            _effect_sets([case["effects"]])
    return list(value)


def _check_configs(cases: Sequence[Mapping[str, Any]]) -> None:
    """Load every distinct configuration once, so an impossible one fails before anything runs."""
    from taiji2_apps.campaign.case import case_config
    from taiji2_model.config import ConfigError

    seen: set[str] = set()
    for case in cases:
        key = json.dumps({k: case[k] for k in ("layout", "maneuver", "duration_s", "overrides")},
                         sort_keys=True, default=str)
        if key in seen:
            continue
        seen.add(key)
        try:
            case_config(case)
        except ConfigError as exc:
            raise SpecError(_origin(exc), f"{exc} (case group: {group_label(case)})") from None
        except ValueError as exc:
            raise SpecError("layouts", str(exc)) from None


def _origin(exc: Exception) -> str:
    parameter = getattr(exc, "parameter", None) or getattr(exc, "key", None)
    return f"overrides/grid {parameter}" if parameter else "layouts"
