"""Provenance stored in a recorded bag's ``custom_data`` (all values are strings).

Keys
----
``taiji2.recorder.version``        ``taiji2_runtime <version>``
``taiji2.recorder.git_revision``   ``git describe --always --dirty`` of the workspace, if it is a checkout
``taiji2.recorder.command_line``   the recorder's command line
``taiji2.recorder.runtime``        ``rclpy`` or ``cyclonedds``
``taiji2.recorder.started_utc``    ISO 8601 start of the recording
``taiji2.sim.provenance``          the simulator's provenance JSON (config, seed, t0, effects), verbatim
``taiji2.sim.seed``                the run seed, from that JSON
``taiji2.sim.layout``              the layout name (type1 / type2 / file), from that JSON
``taiji2.sim.maneuver``            what was flown, in words (the ``maneuver`` label of that JSON)
"""

from __future__ import annotations

import json
import shlex
import subprocess
from datetime import datetime, timezone
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from taiji2_runtime.ros import RUNTIME

PREFIX = "taiji2."
SIM_PROVENANCE_KEY = "taiji2.sim.provenance"


@cache
def git_revision() -> str | None:
    """``git describe --always --dirty`` of the checkout holding this package, or None."""
    here = Path(__file__).resolve().parent
    try:
        result = subprocess.run(["git", "-C", str(here), "describe", "--always", "--dirty", "--abbrev=12"],
                                capture_output=True, text=True, timeout=5.0, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    text = result.stdout.strip()
    return text if result.returncode == 0 and text else None


def package_version() -> str:
    """``taiji2_runtime <version>`` (``unknown`` when not installed as a distribution)."""
    try:
        return f"taiji2_runtime {version('taiji2_runtime')}"
    except PackageNotFoundError:
        return "taiji2_runtime unknown"


def recorder_provenance(argv: list[str]) -> dict[str, str]:
    """Custom data describing the recorder run (see the module docstring)."""
    data = {
        "taiji2.recorder.version": package_version(),
        "taiji2.recorder.command_line": shlex.join(argv),
        "taiji2.recorder.runtime": RUNTIME,
        "taiji2.recorder.started_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    revision = git_revision()
    if revision:
        data["taiji2.recorder.git_revision"] = revision
    return data


def simulator_provenance(text: str) -> dict[str, str]:
    """Custom data from the simulator's ``/taiji2/sim/provenance`` JSON (unparsable text kept verbatim)."""
    data = {SIM_PROVENANCE_KEY: text}
    try:
        parsed = json.loads(text)
    except ValueError:
        return data
    if isinstance(parsed, dict):
        if "seed" in parsed:
            data["taiji2.sim.seed"] = str(parsed["seed"])
        config = parsed.get("config")
        if isinstance(config, dict) and "layout" in config:
            data["taiji2.sim.layout"] = str(config["layout"])
        label = maneuver_label(parsed)
        if label:
            data["taiji2.sim.maneuver"] = label
    return data


def maneuver_label(provenance: object) -> str | None:
    """What was flown, in words, from a run's provenance (``{"maneuver": {"label": ...}}``), or None."""
    maneuver = provenance.get("maneuver") if isinstance(provenance, dict) else None
    label = maneuver.get("label") if isinstance(maneuver, dict) else None
    return str(label) if label else None


def flown_maneuver(custom_data: dict[str, str]) -> str | None:
    """What a recording's run flew, in words, from its custom data (a recorder's bag: ``taiji2.sim.maneuver``;
    a ``taiji2 simulate`` bag: the ``maneuver`` of ``taiji2.provenance``), or None when it does not say."""
    if custom_data.get("taiji2.sim.maneuver"):
        return custom_data["taiji2.sim.maneuver"]
    for key in ("taiji2.provenance", SIM_PROVENANCE_KEY):
        try:
            label = maneuver_label(json.loads(custom_data.get(key, "")))
        except ValueError:
            continue
        if label:
            return label
    return None
