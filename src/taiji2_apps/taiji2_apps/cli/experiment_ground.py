"""``taiji2 experiment --link ... --ground URL``: the ground station on Yamcs during the run.

The node :mod:`taiji2_ground_pkg.nodes.yamcs_station` forwards every packet the ground station receives to
the Yamcs instance at ``URL`` (started with ``taiji2 ground serve``), whose ``ground-station`` link
connects to it on ``--station-port``; Yamcs archives and decodes them (docs/operations.md). The run ends
once the station has handed Yamcs everything; the results say what it sent and what Yamcs's link read
(``link.yamcs``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["format_ground", "ground_problem", "ground_summary", "link_count"]

def ground_problem(url: str, station_port: int) -> str | None:
    """Why the run cannot feed ``url`` (a bad address, no running instance, a bad port); None if it can."""
    from taiji2_ground_pkg.mcs.errors import GroundError
    from taiji2_ground_pkg.mcs.yamcs_api import instance_state, parse_yamcs_url

    if not 1 <= station_port <= 65535:
        return f"--station-port {station_port}: not a TCP port (1-65535)"
    try:
        address = parse_yamcs_url(url)
    except GroundError as exc:
        return f"--ground {exc}"
    host, port = address.server.rsplit(":", 1)
    state = instance_state(int(port), address.instance, host)
    if state != "RUNNING":
        return (f"--ground {url}: no running Yamcs instance {address.instance!r} there "
                f"({'no answer' if state is None else state}); start one with taiji2 ground serve --data-dir DIR")
    return None


def link_count(url: str) -> int:
    """Packets the instance's ground-station link has read so far (it counts across runs)."""
    from taiji2_ground_pkg.mcs.yamcs_api import link_counts

    return link_counts(url)[0]


def ground_summary(url: str, station: dict[str, Any] | None, count_before: int) -> dict[str, Any]:
    """What the station received and sent, and what Yamcs's link read during the run (waiting while the
    link's count still moves toward what was sent)."""
    from taiji2_ground_pkg.mcs.yamcs_api import wait_for_link_count

    sent = int((station or {}).get("sent", 0))
    read = wait_for_link_count(url, sent, since=count_before)
    return {"url": url, "station": station, "sent": sent, "read_by_yamcs": read}


def format_ground(ground: dict[str, Any]) -> str:
    station = ground.get("station") or {}
    return (f"Yamcs ({ground['url']}): the ground received {station.get('received', 0)} packets, sent "
            f"{ground['sent']} to Yamcs; its link read {ground['read_by_yamcs']}")
