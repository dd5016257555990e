"""``taiji2 experiment --link ... --uplink-attack KINDS``: an intruder on the uplink during the run.

The intruder node (:mod:`taiji2_sim_pkg.nodes.uplink_intruder`) sends frames built to be refused; the run's
results say what it sent and what the spacecraft refused, per reason (``link.attacks``). For the ``revoked``
attack the onboard key table must hold a revoked key the intruder has leaked: with the run's throwaway key
file that is SPI 1 (revoked; SPI 2 signs), with ``--key-file`` its revoked SPIs.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

from taiji2_sim_pkg.uplink_attacks import ATTACK_KINDS

__all__ = ["attack_kinds", "attack_summary", "format_attacks", "leaked_key_file"]


def attack_kinds(text: str) -> list[str]:
    """The kinds of ``--uplink-attack`` (comma-separated, or ``all``); ValueError naming an unknown one."""
    kinds = list(ATTACK_KINDS) if text.strip() == "all" else [k.strip() for k in text.split(",") if k.strip()]
    unknown = sorted(set(kinds) - set(ATTACK_KINDS))
    if unknown or not kinds:
        raise ValueError(f"--uplink-attack {text!r}: choose from all, {', '.join(ATTACK_KINDS)} (comma-separated)")
    return kinds


def leaked_key_file(key_file: str) -> tuple[str, Any]:
    """A key file of ``key_file``'s revoked keys (what the intruder holds) in a private temporary directory,
    and the callable that removes it; ValueError if ``key_file`` has no revoked key."""
    from taiji2_runtime.packets.sdls_keys import REVOKED, KeyTable, load_key_file, write_key_file

    revoked = [sa for sa in load_key_file(key_file) if sa.state == REVOKED]
    if not revoked:
        raise ValueError(f"{key_file}: no revoked SPI, the revoked attack needs one (or leave the attack out)")
    folder = tempfile.mkdtemp(prefix="taiji2-leaked-")
    path = write_key_file(Path(folder) / "leaked_keys.json", KeyTable(revoked))
    return str(path), lambda: shutil.rmtree(folder, ignore_errors=True)


def attack_summary(intruder: dict[str, Any] | None, diagnostics: dict[str, Any]) -> dict[str, Any]:
    """What the intruder sent and what the spacecraft counted (its last ``/diagnostics``: frames accepted,
    refused per reason, telecommands refused at acceptance)."""
    status = diagnostics.get("onboard_executor")
    onboard = {kv.key: json.loads(kv.value) for kv in status.values} if status is not None else {}
    refused = {k: n for k, n in onboard.get("frames_refused", {}).items() if n}
    return {"intruder": intruder, "frames_accepted": onboard.get("frames_accepted"), "frames_refused": refused,
            "refused_total": sum(refused.values()), "invalid_telecommands": onboard.get("invalid_telecommands")}


def format_attacks(attacks: dict[str, Any]) -> str:
    sent = (attacks.get("intruder") or {}).get("sent", {})
    return (f"Uplink attack: {sum(sent.values())} frames sent (" + ", ".join(f"{k} {n}" for k, n in sent.items())
            + f"); onboard refused {attacks['refused_total']} ("
            + ", ".join(f"{k} {n}" for k, n in attacks["frames_refused"].items())
            + f"), accepted {attacks['frames_accepted']} (the planner's)")
