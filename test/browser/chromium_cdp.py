"""A headless Chromium driven through the Chrome DevTools Protocol (CDP) over its WebSocket, for the tests that
check what an operator sees in Yamcs's web interface. Debian's ``chromium``; ``websocket-client`` (already a
dependency of yamcs-client) speaks the protocol, so nothing else is installed."""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import requests
import websocket

__all__ = ["Browser", "chromium_path"]

#: what the DevTools protocol answers when the page navigated while a call ran in it
_NAVIGATED = "Inspected target navigated or closed"


def chromium_path() -> str | None:
    """Debian's Chromium, if installed."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Browser:
    """One headless Chromium page (``with Browser() as page: ...``)."""

    def __init__(self, width: int = 1400, height: int = 900, start_timeout_s: float = 60.0) -> None:
        self._profile = tempfile.mkdtemp(prefix="taiji2-chromium-")
        self._process = subprocess.Popen(
            [chromium_path(), "--headless=new", "--no-sandbox", "--disable-gpu", "--remote-debugging-port=0",
             "--no-first-run", f"--user-data-dir={self._profile}", f"--window-size={width},{height}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            env={**os.environ, "TMPDIR": self._profile})  # its singleton socket directory goes with the profile
        port_file = Path(self._profile) / "DevToolsActivePort"  # Chromium writes its port there once listening
        deadline = time.monotonic() + start_timeout_s
        while not (port_file.exists() and port_file.read_text().strip()):
            if self._process.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise RuntimeError("chromium did not start its DevTools endpoint")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        pages = requests.get(f"http://127.0.0.1:{port}/json/list", timeout=30).json()
        target = next(p for p in pages if p["type"] == "page")
        # no Origin header: Chromium refuses a WebSocket from a foreign origin, and this client has none
        self._socket = websocket.create_connection(target["webSocketDebuggerUrl"], suppress_origin=True, timeout=60)
        self._id = 0

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        """One CDP command's result (events in between are skipped)."""
        self._id += 1
        self._socket.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            message = json.loads(self._socket.recv())
            if message.get("id") == self._id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def navigate(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def evaluate(self, expression: str, **options: Any) -> Any:
        """The value of a JavaScript expression in the page; None if the page navigated away meanwhile (a
        redirect, e.g. after signing in: the caller asks again)."""
        try:
            result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, **options)
        except RuntimeError as exc:
            if _NAVIGATED in str(exc):
                return None
            raise
        return result.get("result", {}).get("value")

    def pause(self, seconds: float) -> None:
        """Let the page run for ``seconds`` (a timer inside the page, awaited)."""
        self.evaluate(f"new Promise(r => setTimeout(r, {1000 * seconds:.0f}))", awaitPromise=True)

    def text(self) -> str:
        """What the page shows (``document.body.innerText``)."""
        return self.evaluate("document.body ? document.body.innerText : ''") or ""

    def screenshot(self, path: Path) -> Path:
        """A PNG of the page's viewport."""
        path.write_bytes(base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"]))
        return path

    def close(self) -> None:
        sock = getattr(self, "_socket", None)
        if sock is not None:
            sock.close()
        self._process.terminate()
        try:
            self._process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._process.kill()
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
