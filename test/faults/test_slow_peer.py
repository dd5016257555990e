"""A stalled reliable subscriber slows the simulator down (back-pressure); it never ends it."""

import os
import signal
import subprocess
import time
from pathlib import Path

from support import PYTHON, python_subprocess_env

HERE = Path(__file__).parent


def _sim(duration_s: float, *extra: str) -> subprocess.Popen:
    cmd = [PYTHON, "-m", "taiji2_apps.cli.main", "run", "taiji2_sim_pkg", "spacecraft_sim", "--ros-args",
           "-p", f"duration_s:={duration_s}", "-p", "sync_with_command:=false", "-p", "seed:=3",
           "-p", "wait_for_subscribers:=[1, 0, 0]", "-p", "publish_truth:=false", *extra]
    return subprocess.Popen(cmd, env=python_subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def test_stalled_reliable_reader_gets_every_sample_and_the_simulator_exits_0():
    steps = 8000  # 800 s at 10 Hz: a 5-s stall at ~200x real time leaves ~10^4 samples unacknowledged,
    # more than Cyclone's writer history cache holds, so the writer blocks and times out
    reader = subprocess.Popen([PYTHON, str(HERE / "slow_reader.py"), str(steps), "20"], env=python_subprocess_env(),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert reader.stdout.readline().strip() == "ready"
        sim = _sim(steps / 10.0)
        assert reader.stdout.readline().strip() == "first"  # the run is under way: stall the reader
        os.kill(reader.pid, signal.SIGSTOP)
        time.sleep(5.0)
        os.kill(reader.pid, signal.SIGCONT)
        _, sim_err = sim.communicate(timeout=180)
        received = reader.communicate(timeout=60)[0].strip()
    finally:
        for proc in (reader,):
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGCONT)
                proc.kill()
    assert sim.returncode == 0, sim_err[-2000:]
    assert "error:" not in sim_err
    assert int(received) == steps


def test_sigint_stops_the_simulator_silently_with_exit_0():
    sim = _sim(100000.0, "-p", "wait_for_subscribers:=[0, 0, 0]")
    first = sim.stderr.readline()  # the node's first log line: it is up and stepping
    time.sleep(1.0)
    sim.send_signal(signal.SIGINT)
    _, err = sim.communicate(timeout=60)
    err = first + err
    assert sim.returncode == 0, err[-2000:]
    assert "error" not in err.lower() and "Traceback" not in err
