"""What the ground reads from a running Yamcs through its HTTP API (``yamcs-client``): the instance's state,
and the raw packets of the archive for calibration.

A Yamcs address is ``yamcs://HOST:PORT/INSTANCE`` with an optional time range of packet generation times,
``?start=ISO&stop=ISO`` (UTC, e.g. ``2035-01-01T00:10:00Z``; start inclusive, stop exclusive). Where Yamcs
runs with authentication (as ``taiji2 ground serve`` starts it), the user and password come from the
environment (``YAMCS_USER`` and ``YAMCS_PASSWORD``, or a file named by ``YAMCS_CREDENTIALS_FILE``), never
from the command line, which other users of the machine can read (:func:`credentials`).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from taiji2_ground_pkg.mcs.errors import GroundError

__all__ = [
    "UNAUTHORIZED",
    "YamcsAddress",
    "archived_packets",
    "close_sessions",
    "command_history",
    "connect",
    "credentials",
    "frame_link_spis",
    "instance_state",
    "is_yamcs_url",
    "link_counts",
    "parse_yamcs_url",
    "set_frame_sequence",
    "set_parameters",
    "wait_for_link_count",
    "wait_for_verification",
]

_SCHEME = "yamcs"
#: what :func:`instance_state` says when the server refuses the login (no or wrong credentials)
UNAUTHORIZED = "UNAUTHORIZED"


@dataclass(frozen=True)
class YamcsAddress:
    """A parsed ``yamcs://`` address: the server, the instance, the generation-time range (UTC)."""

    server: str  # "host:port"
    instance: str
    start: dt.datetime | None = None
    stop: dt.datetime | None = None


def is_yamcs_url(text: str) -> bool:
    """Whether ``text`` names a Yamcs instance (``yamcs://...``), not a file."""
    return str(text).startswith(f"{_SCHEME}://")


def _time(url: str, key: str, values: list[str]) -> dt.datetime:
    text = values[-1]
    try:
        t = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError as exc:
        raise GroundError(f"{url}: {key}={text!r} is not an ISO 8601 time (e.g. 2035-01-01T00:10:00Z)") from exc
    if t.tzinfo is None:
        raise GroundError(f"{url}: {key}={text!r} has no time zone; write it in UTC with a Z")
    return t.astimezone(dt.timezone.utc)


def parse_yamcs_url(url: str) -> YamcsAddress:
    """The address of ``yamcs://HOST:PORT/INSTANCE[?start=ISO&stop=ISO]``; GroundError naming what is wrong."""
    parts = urlsplit(url)
    if parts.scheme != _SCHEME or not parts.hostname or parts.port is None:
        raise GroundError(f"{url}: not a Yamcs address; expected yamcs://HOST:PORT/INSTANCE")
    instance = parts.path.strip("/")
    if not instance or "/" in instance:
        raise GroundError(f"{url}: name one Yamcs instance after the port, e.g. yamcs://127.0.0.1:8090/taiji2")
    query = parse_qs(parts.query, keep_blank_values=True)
    unknown = sorted(set(query) - {"start", "stop"})
    if unknown:
        raise GroundError(f"{url}: unknown option(s) {', '.join(unknown)}; the options are start and stop")
    start = _time(url, "start", query["start"]) if "start" in query else None
    stop = _time(url, "stop", query["stop"]) if "stop" in query else None
    if start is not None and stop is not None and stop <= start:
        raise GroundError(f"{url}: stop is not after start")
    return YamcsAddress(f"{parts.hostname}:{parts.port}", instance, start, stop)


def credentials(environ: Mapping[str, str] | None = None) -> tuple[str, str] | None:
    """``(user, password)`` for Yamcs from the environment: ``YAMCS_USER`` and ``YAMCS_PASSWORD``, else the file
    named by ``YAMCS_CREDENTIALS_FILE`` (``KEY=VALUE`` lines with those two keys, as ``taiji2 ground serve``
    writes them); None without either. GroundError naming a file that cannot be read or lacks a key."""
    env = os.environ if environ is None else environ
    user, password = env.get("YAMCS_USER"), env.get("YAMCS_PASSWORD")
    if user and password:
        return user, password
    path = env.get("YAMCS_CREDENTIALS_FILE")
    if not path:
        return None
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise GroundError(f"YAMCS_CREDENTIALS_FILE {path}: cannot be read ({exc.strerror or exc})") from None
    values = dict(line.split("=", 1) for line in lines if "=" in line)
    if not values.get("YAMCS_USER") or not values.get("YAMCS_PASSWORD"):
        raise GroundError(f"YAMCS_CREDENTIALS_FILE {path}: needs YAMCS_USER=... and YAMCS_PASSWORD=... lines")
    return values["YAMCS_USER"], values["YAMCS_PASSWORD"]


def connect(server: str, environ: Mapping[str, str] | None = None, *, attempts: int = 5) -> Any:
    """A ``yamcs.client.YamcsClient`` of ``server`` (``HOST:PORT``), logged in with :func:`credentials`. Yamcs
    answers 429 to more than 5 logins a second from one address (its guard against guessing passwords): the
    login is tried again a second later, up to ``attempts`` times."""
    from yamcs.client import Credentials, YamcsClient

    login = credentials(environ)
    for attempt in range(attempts):
        try:
            return YamcsClient(server, credentials=Credentials(username=login[0], password=login[1])
                               if login else None)
        except Exception as exc:
            if "429" not in str(exc) or attempt == attempts - 1:
                raise
            time.sleep(1.0 + 0.1 * attempt)
    raise AssertionError("unreachable")


#: logged-in clients by (server, login, thread): Yamcs refuses more than 5 logins a second from one address (429,
#: its brute-force guard), and the ground's clients all run on this host, polling (the station's parameters once
#: a second, the experiment's link counts every 0.2 s): each logs in once per thread and keeps its session
_CLIENTS: dict[tuple, Any] = {}
_CLIENTS_LOCK = threading.Lock()


@contextlib.contextmanager
def _connected(server: str, environ: Mapping[str, str] | None = None) -> Iterator[Any]:
    """A logged-in client of ``server`` (:func:`connect`), kept for this thread's next calls; dropped (and the
    next call logs in again) when a call through it fails."""
    key = (server, credentials(environ), threading.get_ident())
    with _CLIENTS_LOCK:
        client = _CLIENTS.get(key)
    if client is None:
        client = connect(server, environ)
        with _CLIENTS_LOCK:
            _CLIENTS[key] = client
    try:
        yield client
    except BaseException as exc:
        # a session the server no longer takes, or a server gone: the next call logs in again (a refusal of
        # one request, e.g. 403, keeps the session: logging in again would only count against the 429 guard)
        if type(exc).__name__ in ("Unauthorized", "ConnectionFailure") or isinstance(exc, OSError):
            with _CLIENTS_LOCK:
                _CLIENTS.pop(key, None)
            client.close()
        raise


def close_sessions(http_port: int) -> None:
    """Close this process's kept clients of the server on ``http_port`` (by any host name), of every thread:
    before a server this host runs stops, or their session-renewal threads keep calling a server that is gone."""
    with _CLIENTS_LOCK:
        keys = [key for key in _CLIENTS if key[0].rsplit(":", 1)[-1] == str(int(http_port))]
        clients = [_CLIENTS.pop(key) for key in keys]
    for client in clients:
        client.close()


def instance_state(http_port: int, instance: str = "taiji2", host: str = "127.0.0.1",
                   environ: Mapping[str, str] | None = None) -> str | None:
    """The state of ``instance`` (``RUNNING`` when ready), :data:`UNAUTHORIZED` if the server refuses the login,
    or None while it does not answer."""
    import requests

    try:
        with _connected(f"{host}:{http_port}", environ) as client:
            states = {i.name: i.state for i in client.list_instances()}
    except (requests.exceptions.RequestException, OSError):
        return None
    except Exception as exc:  # yamcs-client's own errors (a server still starting answers 503)
        if type(exc).__name__ == "Unauthorized":
            return UNAUTHORIZED
        if type(exc).__module__.startswith("yamcs"):
            return None
        raise
    return states.get(instance)


def archived_packets(url: str) -> list[bytes]:
    """The raw packets that Yamcs archived at ``url`` (its time range, if any), in the archive's order
    (generation time, then sequence count); GroundError naming the address when it cannot be read."""
    address = parse_yamcs_url(url)
    try:
        with _connected(address.server) as client:
            names = {i.name for i in client.list_instances()}
            if address.instance not in names:
                raise GroundError(f"{url}: no instance {address.instance!r} on {address.server} "
                                  f"(it has {', '.join(sorted(names)) or 'none'})")
            archive = client.get_archive(address.instance)
            return [bytes(p.binary) for p in archive.stream_packets(start=address.start, stop=address.stop)]
    except GroundError:
        raise
    except Exception as exc:
        raise GroundError(f"{url}: cannot read the Yamcs archive: {type(exc).__name__}: {exc}") from exc


def link_counts(url: str, link: str = "ground-station") -> tuple[int, str]:
    """Packets the link has read so far and its status (e.g. ``OK``), through the API."""
    address = parse_yamcs_url(url)
    with _connected(address.server) as client:
        info = next((lk for lk in client.list_links(address.instance) if lk.name == link), None)
    if info is None:
        raise GroundError(f"{url}: the instance has no link {link!r}")
    return int(info.in_count), str(info.status)


def wait_for_link_count(url: str, target: int, *, since: int = 0, still_s: float = 60.0,
                        poll_s: float = 0.2) -> int:
    """The link's packet count minus ``since``, once it reaches ``target`` or has not moved for ``still_s`` of
    wall time (Yamcs reads ~10^5 packets a second: the bound is on its progress, not on a busy machine)."""
    read, last, still_since = link_counts(url)[0] - since, -1, time.monotonic()
    while read < target and time.monotonic() - still_since < still_s:
        time.sleep(poll_s)
        read = link_counts(url)[0] - since
        if read != last:
            last, still_since = read, time.monotonic()
    return read


def set_parameters(url: str, values: dict[str, float], processor: str = "realtime") -> None:
    """Set local parameters (names without the space system: ``grs1_G_Pphi``) of the instance at ``url``;
    GroundError naming the address when Yamcs refuses or does not answer."""
    from taiji2_ground_pkg.mcs.xtce import SYSTEM_NAME

    address = parse_yamcs_url(url)
    try:
        with _connected(address.server) as client:
            client.get_processor(address.instance, processor).set_parameter_values(
                {f"/{SYSTEM_NAME}/{name}": value for name, value in values.items()})
    except Exception as exc:
        raise GroundError(f"{url}: cannot set parameters: {type(exc).__name__}: {exc}") from exc


def command_history(url: str, since: dt.datetime, command: str = "insert_activities") -> list[dict[str, Any]]:
    """The archived history of the ``command`` commands issued at or after ``since`` (UTC), oldest first: the
    CCSDS ``seq_count`` Yamcs gave each, every stage's status (``Queued`` ... ``Acceptance``, ``Execution``:
    OK, NOK, PENDING, TIMEOUT, or None), the failure ``message`` and the operator's ``comment``."""
    from taiji2_ground_pkg.mcs.xtce import COMMAND_STAGES, SYSTEM_NAME, VERIFIER_STAGES

    address = parse_yamcs_url(url)
    verified = {s for s, _ in VERIFIER_STAGES}
    stages = {f"{'Verifier' if s in verified else 'Acknowledge'}_{s}": s for s in COMMAND_STAGES}
    out = []
    with _connected(address.server) as client:
        archive = client.get_archive(address.instance)
        for entry in archive.list_command_history(start=since, descending=False):
            if entry.name != f"/{SYSTEM_NAME}/{command}":
                continue  # (filtering by name in the request answers 404 on Yamcs 5.12)
            binary = entry.binary or b""
            acks = dict(entry.acknowledgments)
            out.append({"id": entry.id, "comment": entry.comment, "message": entry.error,
                        "seq_count": int.from_bytes(binary[2:4], "big") & 0x3FFF if len(binary) >= 4 else None,
                        **{stage: getattr(acks.get(key), "status", None) for key, stage in stages.items()}})
    return out


def wait_for_verification(url: str, since: dt.datetime, concluded: dict[str, int], *, still_s: float = 60.0,
                          poll_s: float = 0.5) -> list[dict[str, Any]]:
    """:func:`command_history` once, for each stage of ``concluded`` (e.g. ``{"Acceptance": 4}``), at least that
    many commands have it concluded (OK or NOK), or once the history has not changed for ``still_s`` of wall
    time (Yamcs verifies as the reports come: the bound is on its progress, not on a busy machine)."""
    def done(history: list[dict[str, Any]]) -> bool:
        return all(sum(h.get(stage) in ("OK", "NOK") for h in history) >= n for stage, n in concluded.items())

    history, still_since = command_history(url, since), time.monotonic()
    while not done(history) and time.monotonic() - still_since < still_s:
        time.sleep(poll_s)
        now = command_history(url, since)
        if now != history:
            history, still_since = now, time.monotonic()
    return history


def frame_link_spis(url: str, link: str) -> list[int]:
    """The SPIs of the instance's SDLS frame link ``link`` (empty if it has no such link)."""
    from yamcs.protobuf.sdls import sdls_pb2

    address = parse_yamcs_url(url)
    try:
        with _connected(address.server) as client:
            response = client.ctx.get_proto(f"/sdls/{address.instance}/{link}")
    except Exception as exc:
        if type(exc).__name__ == "NotFound":
            return []
        raise GroundError(f"{url}: cannot read the SDLS link {link}: {type(exc).__name__}: {exc}") from exc
    message = sdls_pb2.GetLinkSpisResponse()
    message.ParseFromString(response.content)
    return [int(spi) for spi in message.spis]


def set_frame_sequence(url: str, link: str, spi: int, next_sequence: int) -> None:
    """Set the IV counter Yamcs's frame link ``link`` signs its next frame of ``spi`` with (Yamcs keeps it across
    restarts; a spacecraft whose counters restart, as the emulated one does each run, needs the ground to
    start again above them)."""
    from yamcs.protobuf.sdls import sdls_pb2

    from taiji2_runtime.packets.sdls import IV_OCTETS

    address = parse_yamcs_url(url)
    body = sdls_pb2.SetSeqCtrRequestBody(seq=int(next_sequence).to_bytes(IV_OCTETS, "big"))
    try:
        with _connected(address.server) as client:
            client.ctx.put_proto(f"/sdls/{address.instance}/{link}/{spi}/seq", data=body.SerializeToString())
    except Exception as exc:
        raise GroundError(f"{url}: cannot set the SDLS sequence of {link} SPI {spi}: {type(exc).__name__}: "
                          f"{exc}") from exc
