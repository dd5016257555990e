"""``taiji2 experiment --link ... --ground URL``: the ground station on Yamcs during the run.

The node :mod:`taiji2_ground_pkg.nodes.yamcs_station` forwards every packet the ground station receives to
the Yamcs instance at ``URL`` (started with ``taiji2 ground serve``), whose ``ground-station`` link
connects to it on ``--station-port``; Yamcs archives and decodes them (docs/operations.md). The planner
issues the time-tagged tables as Yamcs commands and the station signs and uplinks what Yamcs sends. The run
ends once the station has handed Yamcs everything; the results say what it sent, what Yamcs's link read and
each table's command history (``link.yamcs``).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

__all__ = ["YamcsFrames", "format_ground", "ground_problem", "ground_summary", "link_count", "publish_verdict",
           "yamcs_signs_frames"]


def ground_problem(url: str, station_port: int) -> str | None:
    """Why the run cannot feed ``url`` (a bad address, no running instance, a bad port); None if it can."""
    from taiji2_ground_pkg.mcs.errors import GroundError
    from taiji2_ground_pkg.mcs.yamcs_api import UNAUTHORIZED, instance_state, parse_yamcs_url

    if not 1 <= station_port <= 65535:
        return f"--station-port {station_port}: not a TCP port (1-65535)"
    try:
        address = parse_yamcs_url(url)
    except GroundError as exc:
        return f"--ground {exc}"
    host, port = address.server.rsplit(":", 1)
    state = instance_state(int(port), address.instance, host)
    if state == UNAUTHORIZED:
        return (f"--ground {url}: Yamcs refused the login; set YAMCS_CREDENTIALS_FILE to the operator's credentials "
                "(DIR/credentials/operator.env of taiji2 ground serve --data-dir DIR)")
    if state != "RUNNING":
        return (f"--ground {url}: no running Yamcs instance {address.instance!r} there "
                f"({'no answer' if state is None else state}); start one with taiji2 ground serve --data-dir DIR")
    return None


@dataclass(frozen=True)
class YamcsFrames:
    """Yamcs signs the telecommands itself: issued on ``stream``, they come as SDLS frames of ``spi`` to the
    station's UDP ``port``."""

    spi: int
    port: int
    stream: str


def yamcs_signs_frames(args: argparse.Namespace) -> tuple[YamcsFrames | None, str]:
    """Whether the instance at ``--ground`` signs its own SDLS frames (it has the frame link) and, if so, whether
    this run can fly them: ``--key-file`` must hold that SPI with the authenticated-encryption service (the
    spacecraft's key table). Sets Yamcs's next IV to 1: the emulated spacecraft's counters start at 0 each
    run. ``(frames or None, problem or "")``."""
    from taiji2_ground_pkg.mcs.errors import GroundError
    from taiji2_ground_pkg.mcs.yamcs_api import frame_link_spis, set_frame_sequence
    from taiji2_ground_pkg.mcs.yamcs_instance import FRAME_LINK_NAME, FRAME_STREAM
    from taiji2_runtime.packets.sdls_keys import AUTHENTICATED_ENCRYPTION, KeyFileError, load_key_file

    try:
        spis = frame_link_spis(args.ground, FRAME_LINK_NAME)
    except GroundError as exc:
        return None, f"--ground {exc}"
    if not spis:
        return None, ""  # Yamcs sends packets; the station signs them
    spi = spis[0]
    if not args.key_file:
        return None, (f"--ground {args.ground} signs telecommands itself (SDLS SPI {spi}): give the spacecraft its "
                      "key with --key-file (the file given to taiji2 ground serve --sdls-key-file)")
    try:
        sa = load_key_file(args.key_file).get(spi)
    except KeyFileError as exc:
        return None, f"--key-file {exc}"
    if sa is None or sa.service != AUTHENTICATED_ENCRYPTION:
        return None, (f"--key-file {args.key_file}: Yamcs signs with SPI {spi}, which the file "
                      f"{'lacks' if sa is None else 'has with service ' + sa.service}: the spacecraft would refuse "
                      "every frame")
    port = args.station_port + 1 if args.frame_port < 0 else args.frame_port
    try:
        set_frame_sequence(args.ground, FRAME_LINK_NAME, spi, 1)
    except GroundError as exc:
        return None, f"--ground {exc}"
    return YamcsFrames(spi, port, FRAME_STREAM), ""


def link_count(url: str) -> int:
    """Packets the instance's ground-station link has read so far (it counts across runs)."""
    from taiji2_ground_pkg.mcs.yamcs_api import link_counts

    return link_counts(url)[0]


def ground_summary(url: str, station: dict[str, Any] | None, count_before: int, started: Any = None,
                   reported: dict[str, int] | None = None) -> dict[str, Any]:
    """What the station received and sent, and what Yamcs's link read during the run (waiting while the
    link's count still moves toward what was sent); with ``started`` (the run's UTC start), the command
    history of the tables issued since, once Yamcs has verified each stage for which the ground received a
    report (``reported``: stage -> tables), or its verification has stopped moving."""
    from taiji2_ground_pkg.mcs.commanding import stage_counts
    from taiji2_ground_pkg.mcs.yamcs_api import wait_for_link_count, wait_for_verification

    sent = int((station or {}).get("sent", 0))
    read = wait_for_link_count(url, sent, since=count_before)
    out: dict[str, Any] = {"url": url, "station": station, "sent": sent, "read_by_yamcs": read}
    if started is not None:
        history = wait_for_verification(url, started, reported or {})
        out["commands"] = {**stage_counts(history), "history": history}
    return out


def publish_verdict(url: str, met: int, total: int) -> dict[str, Any]:
    """Set the verdict's requirement counts as the instance's parameters (``verdict_requirements_met``,
    ``..._not_met``, WARNING above 0); what was set, or the error (the run's results stand either way)."""
    from taiji2_ground_pkg.mcs.errors import GroundError
    from taiji2_ground_pkg.mcs.ground_parameters import verdict_values
    from taiji2_ground_pkg.mcs.yamcs_api import set_parameters

    values = verdict_values(met, total)
    try:
        set_parameters(url, values)
    except GroundError as exc:
        return {"error": str(exc)}
    return values


def format_ground(ground: dict[str, Any]) -> str:
    from taiji2_ground_pkg.mcs.xtce import COMMAND_STAGES

    station = ground.get("station") or {}
    line = (f"Yamcs ({ground['url']}): the ground received {station.get('received', 0)} packets, sent "
            f"{ground['sent']} to Yamcs; its link read {ground['read_by_yamcs']}")
    commands = ground.get("commands")
    if commands:
        line += (f"\n  commanded through Yamcs: {commands['issued']} table(s) issued; "
                 + ", ".join(f"{s} {commands[s]}" for s in COMMAND_STAGES)
                 + "".join(f"\n  table (count {f['seq_count']}) failed: {f['message']}" for f in commands["failed"]))
    return line
