"""A page rendered by headless Chromium, seen through the DevTools protocol.

Chromium is driven over ``--remote-debugging-pipe`` (JSON messages separated by NUL on file
descriptors 3 and 4), so the test needs no websocket library and opens no port. What comes
back: the console messages and uncaught exceptions, every network request the page made (an
offline page makes none but ``data:`` and its own ``file:``), the ids of its sections, whether
every image decoded, and optionally a full-page PNG screenshot.

The Debian package ``chromium`` provides the browser (.ci/run installs it when missing).
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--remote-debugging-pipe",
]


def chromium_exe() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


@dataclass
class Rendered:
    console: list[dict] = field(default_factory=list)  # {"type", "text"}
    exceptions: list[str] = field(default_factory=list)
    log_errors: list[str] = field(default_factory=list)  # Log.entryAdded at level error
    requests: list[str] = field(default_factory=list)  # URLs the page asked for
    failed: list[str] = field(default_factory=list)  # Network.loadingFailed
    sections: list[str] = field(default_factory=list)  # ids of <section> elements
    images: list[dict] = field(default_factory=list)  # {"alt", "ok"} per <img>
    title: str = ""
    height: int = 0


class _Pipe:
    def __init__(self, proc: subprocess.Popen, write_fd: int, read_fd: int):
        self.proc, self.w, self.r = proc, write_fd, read_fd
        self.buf = b""
        self.next_id = 0
        self.events: list[dict] = []

    def send(
        self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 30.0
    ) -> dict:
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.w, json.dumps(msg).encode() + b"\0")
        while True:
            m = self._read(timeout)
            if m.get("id") == self.next_id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def wait_event(self, method: str, timeout: float = 30.0) -> dict:
        for i, e in enumerate(self.events):
            if e.get("method") == method:
                return self.events.pop(i)
        while True:
            m = self._read(timeout)
            if m.get("method") == method:
                return m
            self.events.append(m)

    def _read(self, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        while b"\0" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.r], [], [], left)[0]:
                raise TimeoutError("no answer from chromium")
            chunk = os.read(self.r, 1 << 16)
            if not chunk:
                raise RuntimeError(f"chromium closed the pipe (exit {self.proc.poll()})")
            self.buf += chunk
        raw, self.buf = self.buf.split(b"\0", 1)
        return json.loads(raw)


def render(page: Path, screenshot: Path | None = None, width: int = 1280, timeout: float = 60.0) -> Rendered:
    """Load ``page`` in headless Chromium and report what happened (see the module doc)."""
    exe = chromium_exe()
    if exe is None:
        raise FileNotFoundError("chromium")
    to_chrome_r, to_chrome_w = os.pipe()
    from_chrome_r, from_chrome_w = os.pipe()

    def child_fds():  # chromium reads commands on fd 3 and writes on fd 4
        a, b = os.dup(to_chrome_r), os.dup(from_chrome_w)  # away from 3, 4 first: a pipe
        os.dup2(a, 3)  # may already sit there, and
        os.dup2(b, 4)  # dup2 onto itself keeps CLOEXEC

    with tempfile.TemporaryDirectory(prefix="calbench-chromium-") as profile:
        proc = subprocess.Popen(
            [exe, *FLAGS, f"--user-data-dir={profile}", "about:blank"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=child_fds,
            close_fds=False,
        )
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        pipe = _Pipe(proc, to_chrome_w, from_chrome_r)
        try:
            return _drive(pipe, page, screenshot, width, timeout)
        finally:
            try:
                pipe.send("Browser.close", timeout=5)
            except (RuntimeError, TimeoutError, OSError):
                pass
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            os.close(to_chrome_w)
            os.close(from_chrome_r)


def _drive(pipe: _Pipe, page: Path, screenshot: Path | None, width: int, timeout: float) -> Rendered:
    target = pipe.send("Target.createTarget", {"url": "about:blank"})["targetId"]
    sid = pipe.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
    for domain in ("Page", "Runtime", "Log", "Network"):
        pipe.send(f"{domain}.enable", session=sid)
    pipe.send(
        "Emulation.setDeviceMetricsOverride",
        {"width": width, "height": 900, "deviceScaleFactor": 1, "mobile": False},
        session=sid,
    )
    pipe.events.clear()
    pipe.send("Page.navigate", {"url": page.resolve().as_uri()}, session=sid)
    pipe.wait_event("Page.loadEventFired", timeout)
    out = Rendered()
    probe = """JSON.stringify({
        sections: Array.from(document.querySelectorAll('section[id]')).map(s => s.id),
        images: Array.from(document.images).map(i => ({alt: i.alt,
                 ok: i.complete && i.naturalWidth > 0})),
        title: document.title, height: document.documentElement.scrollHeight})"""
    got = json.loads(
        pipe.send("Runtime.evaluate", {"expression": probe, "returnByValue": True}, session=sid)["result"][
            "value"
        ]
    )
    out.sections, out.images = got["sections"], got["images"]
    out.title, out.height = got["title"], int(got["height"])
    if screenshot is not None:
        shot = pipe.send(
            "Page.captureScreenshot",
            {
                "format": "png",
                "captureBeyondViewport": True,
                "clip": {"x": 0, "y": 0, "width": width, "height": out.height, "scale": 1},
            },
            session=sid,
            timeout=timeout,
        )
        screenshot.write_bytes(base64.b64decode(shot["data"]))
    for e in pipe.events:
        m, p = e.get("method"), e.get("params", {})
        if m == "Runtime.consoleAPICalled":
            out.console.append(
                {
                    "type": p.get("type"),
                    "text": " ".join(
                        str(a.get("value", a.get("description", ""))) for a in p.get("args", [])
                    ),
                }
            )
        elif m == "Runtime.exceptionThrown":
            out.exceptions.append(p.get("exceptionDetails", {}).get("text", "?"))
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            out.log_errors.append(p["entry"].get("text", "?"))
        elif m == "Network.requestWillBeSent":
            out.requests.append(p.get("request", {}).get("url", "?"))
        elif m == "Network.loadingFailed":
            out.failed.append(p.get("errorText", "?"))
    return out
