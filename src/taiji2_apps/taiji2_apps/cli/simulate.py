"""Simulate an experiment in one batch and write it as a raw-data contract bag.

Two fidelities: ``standard`` (the simulator the node graph runs: 10 Hz steps, integrating GRS
readout, the nominal model's own conventions) and ``reference`` (an independently discretised
source: 200 Hz internal steps, thrusters with latency and rise time, anti-alias-filtered GRS
readout, star-tracker exposure; docs/physics_model.md). Timing conventions come from the layout's
``timing`` section (docs/interfaces.md) and from timing effects; ``--effect`` injects any catalog
effect (docs/diagnosis.md, section 9). The run's provenance (seed, fidelity, effects) is kept in
the bag's custom metadata, which the calibration and diagnosis never read.

Example: a reference-fidelity bag with a 0.1-s command latency and nothing else::

    taiji2 simulate --fidelity reference --effect actuation_delay:delay_s=0.1 --out latency_bag
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from taiji2_apps.cli.exit_status import ExitStatus
from taiji2_model.maneuver_choice import MANEUVER_HELP, choose_maneuver


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``taiji2 simulate``."""
    parser.add_argument("--layout", default="type1", help="built-in layout type1 | type2 (default type1)")
    parser.add_argument("--config", default="", help="simulator config YAML instead of --layout")
    parser.add_argument("--fidelity", default="standard", choices=("standard", "reference"),
                        help="standard (the node graph's simulator) or reference (independent discretisation)")
    parser.add_argument("--duration-s", type=float, default=None,
                        help="simulated duration [s] (default: the maneuver's end)")
    parser.add_argument("--maneuver", default=None, metavar="design|paper|FILE", help=MANEUVER_HELP)
    parser.add_argument("--seed", type=int, default=1, help="seed (default 1)")
    parser.add_argument("--effect", action="append", default=[],
                        help="catalog effect NAME[:key=value,...] (repeatable), e.g. actuation_delay:delay_s=0.1")
    parser.add_argument("--override", action="append", default=[],
                        help="layout override KEY=VALUE (YAML value), e.g. timing.grs_stamp=start")
    parser.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"), help="bag storage (default mcap)")
    parser.add_argument("--out", required=True, help="bag directory to create")


def _effect(text: str) -> dict[str, Any]:
    import yaml

    name, _, rest = text.partition(":")
    spec: dict[str, Any] = {"name": name.strip()}
    for item in filter(None, (part.strip() for part in rest.split(","))):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--effect {text!r}: expected key=value after the name, got {item!r}")
        spec[key.strip()] = yaml.safe_load(value)
    return spec


def _checked_effect(spec: dict[str, Any]) -> tuple[Any, list[str]]:
    """The catalog effect of an ``--effect`` spec, and notes on what was assumed.

    An unknown parameter is refused with the effect's valid keys; the notes name the defaults taken
    for parameters not given, say when the effect is inactive with these values (it changes
    nothing), and what a negative delay means.
    """
    import inspect

    from taiji2_model.effect_catalog import EFFECTS, make_effect

    name, given = spec["name"], {k: v for k, v in spec.items() if k != "name"}
    if name not in EFFECTS:
        return make_effect(name, **given), []  # make_effect names the known effects
    parameters = {k: p for k, p in inspect.signature(EFFECTS[name].__init__).parameters.items()
                  if k != "self" and p.kind is p.POSITIONAL_OR_KEYWORD}
    unknown = [k for k in given if k not in parameters]
    if unknown:
        raise ValueError(f"--effect {name}: unknown parameter {unknown[0]!r}; {name} takes "
                         f"{', '.join(f'{k}={p.default!r}' for k, p in parameters.items())} (the defaults)")
    effect = make_effect(name, **given)
    notes = []
    defaults = {k: p.default for k, p in parameters.items() if k not in given and k not in ("enabled", "onset_s")}
    if defaults:
        notes.append(f"--effect {name}: defaults used for {', '.join(f'{k}={v!r}' for k, v in defaults.items())}")
    if not getattr(effect, "active", True):
        notes.append(f"--effect {name}: inactive with these values (it changes nothing); give its magnitude, e.g. "
                     f"{name}:{next(iter(parameters))}=...")
    for key in ("delay_s", "offset_s"):
        value = given.get(key)
        if isinstance(value, (int, float)) and value < 0:
            notes.append(f"--effect {name}: {key}={value}: negative, the torque acts {-value:g} s before its "
                         "command's stamp (a command stamped late); batch simulation only")
    return effect, notes


def main(args: argparse.Namespace) -> int:
    """Run ``taiji2 simulate``."""
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()  # before any BLAS work: one BLAS thread (docs/threads.md)
    import numpy as np
    import yaml

    from taiji2_estimator_pkg.io.sim_bag import write_simulated_bag
    from taiji2_model.config import ConfigError, load_config
    from taiji2_sim_pkg.core.reference import simulate_reference
    from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

    try:
        overrides = {}
        for item in args.override:
            key, sep, value = item.partition("=")
            if not sep:
                raise ValueError(f"--override {item!r}: expected KEY=VALUE")
            overrides[key.strip()] = yaml.safe_load(value)
        config = load_config(args.config or args.layout, overrides)
        specs = [_effect(text) for text in args.effect]
        effects = []
        for spec in specs:
            effect, notes = _checked_effect(spec)
            effects.append(effect)
            for note in notes:
                print(f"note: {note}", file=sys.stderr)
        if args.duration_s is not None and not args.duration_s > 0:
            raise ValueError(f"--duration-s {args.duration_s}: must be positive")
        chosen = choose_maneuver(args.layout, args.maneuver, args.duration_s, config_file=args.config, preset=config)
        steps = round(chosen.duration_s * config.sample_rate_hz)
        commands = maneuver_torque_commands(config, steps, maneuver=chosen.maneuver)
        if commands.shape[0] == 0:
            raise ValueError("no samples to simulate (duration zero)")
        if args.fidelity == "reference":
            out = simulate_reference(config, args.seed, commands, effects=effects)
        else:
            out = simulate_batch(config, args.seed, commands, effects=effects)
        command_t = np.arange(commands.shape[0]) * config.dt_s
        provenance = {"seed": args.seed, "fidelity": args.fidelity, "config": config.to_dict(), "effects": specs,
                      "maneuver": chosen.provenance()}
        bag = write_simulated_bag(args.out, out.t_s, out.st_quat_xyzw, out.st_cov_rad2, out.voltages_v, command_t,
                                  commands, storage=args.storage, provenance=provenance)
    except (ConfigError, ValueError, TypeError) as exc:
        print(f"error: taiji2 simulate: {' '.join(str(exc).split())}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    print(json.dumps({"bag": str(bag), "samples": len(out), "fidelity": args.fidelity, "seed": args.seed,
                      "maneuver": chosen.label, "effects": specs}))
    return ExitStatus.OK
