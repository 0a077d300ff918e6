"""Headless Chromium driven through the DevTools protocol, standard library only.

The browser is started with ``--remote-debugging-pipe``: it reads DevTools commands from file
descriptor 3 and writes replies and events to descriptor 4, one JSON message per NUL-terminated
chunk, so no websocket client (or Playwright) is needed. :func:`load_page` opens one page and
returns what a test wants to know about it: console messages by level, uncaught exceptions, every
URL the page requested, the time from navigation start to the page's own "ready" signal, and a
screenshot.

Used by the report's test (``tests/test_report.py``) and its benchmark (``benchmarks/bench_report.py``).
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["CHROMIUM", "PERFORMANCE_NOTES", "PageLoad", "load_page"]

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)

# The flags of the brief for a quiet, offline headless browser. WebGL runs on SwiftShader (CPU);
# --enable-unsafe-swiftshader opts in to it explicitly, which Chromium otherwise does as a
# deprecated automatic fallback that logs a warning to the page's console.
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
         "--no-first-run", "--enable-unsafe-swiftshader", "--hide-scrollbars", "--mute-audio"]

#: Chromium's own performance notes about how plotly.js reads pixels back (its WebGL picking pass
#: and its font measuring): logged by the browser (source "rendering", level warning), not by the
#: page, and harmless. Everything else a page logs at warning level or above counts as a problem.
PERFORMANCE_NOTES = ("GPU stall due to ReadPixels", "Multiple readback operations using getImageData")


@dataclass
class PageLoad:
    """What happened while one page loaded.

    console : list of (level, text): console API calls (``log``, ``warning``, ``error``, ...) and
        browser log entries (``Log.entryAdded``: level ``info``/``warning``/``error``, text prefixed by
        their source);
    exceptions : list of str, uncaught exceptions;
    requests : list of str, every URL the page asked for (the page's own included);
    ready_ms : float or None, ``performance.now()`` when the ready condition first held (milliseconds
        from navigation start), None when it never did within the timeout;
    screenshot : PNG bytes of the viewport, or None;
    dom : the page's ``document.documentElement.outerHTML`` at the end;
    values : the value of each expression of ``load_page(evaluate=...)``, evaluated once ready.
    """

    console: list = field(default_factory=list)
    exceptions: list = field(default_factory=list)
    requests: list = field(default_factory=list)
    ready_ms: float | None = None
    screenshot: bytes | None = None
    dom: str = ""
    values: dict = field(default_factory=dict)

    def problems(self, ignore=PERFORMANCE_NOTES) -> list[str]:
        """Console errors and warnings and uncaught exceptions, one line each (but the notes in ``ignore``)."""
        return [f"{lvl}: {text}" for lvl, text in self.console
                if lvl in ("error", "warning", "assert") and not any(note in text for note in ignore)] + \
            [f"exception: {e}" for e in self.exceptions]


class _Browser:
    def __init__(self, width: int, height: int):
        if CHROMIUM is None:
            raise RuntimeError("chromium not installed (scripts/setup.sh installs it)")
        self.profile = tempfile.mkdtemp(prefix="primkit-chromium-")
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()

        def plumb():
            # the child's descriptors 3 (commands in) and 4 (replies out); copied high first so that
            # neither dup2 is a no-op onto itself (which would keep close-on-exec) or overwrites the
            # other's source. dup2 makes its target inheritable; every other descriptor of ours is
            # close-on-exec (Python's default), so close_fds=False leaks nothing.
            high_r = fcntl.fcntl(to_child_r, fcntl.F_DUPFD, 100)
            high_w = fcntl.fcntl(from_child_w, fcntl.F_DUPFD, 100)
            os.dup2(high_r, 3)
            os.dup2(high_w, 4)

        self.proc = subprocess.Popen(
            [CHROMIUM, *FLAGS, f"--user-data-dir={self.profile}", f"--window-size={width},{height}",
             "--remote-debugging-pipe", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            close_fds=False, preexec_fn=plumb)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buffer = b""
        self._id = 0
        self.events: list = []
        self.session = None

    def _read_message(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("chromium did not answer in time")
            ready, _, _ = select.select([self._from_child], [], [], left)
            if ready:
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise RuntimeError(f"chromium closed the DevTools pipe (exit code {self.proc.poll()})")
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def send(self, method: str, params: dict | None = None, *, session: bool = True, timeout: float = 60.0) -> dict:
        self._id += 1
        message = {"id": self._id, "method": method, "params": params or {}}
        if session and self.session:
            message["sessionId"] = self.session
        os.write(self._to_child, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def pump(self, seconds: float) -> None:
        """Collect events for up to ``seconds``."""
        deadline = time.monotonic() + seconds
        try:
            while time.monotonic() < deadline:
                self.events.append(self._read_message(deadline))
        except TimeoutError:
            pass

    def close(self) -> None:
        try:
            self.send("Browser.close", session=False, timeout=10)
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._to_child, self._from_child):
            os.close(fd)
        shutil.rmtree(self.profile, ignore_errors=True)


def _text(args) -> str:
    out = []
    for a in args:
        out.append(str(a.get("value", a.get("description", a.get("type", "")))))
    return " ".join(out)


def load_page(url, *, ready: str = "document.body && document.body.dataset.ready === '1'", timeout: float = 120.0,
              width: int = 1200, height: int = 900, settle: float = 0.5, screenshot: bool = True,
              evaluate=(), media: str | None = None) -> PageLoad:
    """Open ``url`` (a path or a URL) in a fresh headless Chromium and watch it load.

    ``ready`` is a JavaScript expression polled until it is true; then the events of ``settle`` more
    seconds are collected, the expressions of ``evaluate`` are evaluated (JSON-serialisable results)
    and the viewport is captured. ``media``: the CSS media type to emulate (``"print"``), or None.
    """
    if not str(url).startswith(("file:", "http:", "https:", "about:", "data:")):
        url = Path(url).resolve().as_uri()
    browser = _Browser(width, height)
    try:
        target = browser.send("Target.createTarget", {"url": "about:blank"}, session=False)["targetId"]
        browser.session = browser.send("Target.attachToTarget", {"targetId": target, "flatten": True},
                                       session=False)["sessionId"]
        for domain in ("Runtime", "Log", "Network", "Page"):
            browser.send(f"{domain}.enable")
        browser.send("Emulation.setDeviceMetricsOverride", {"width": width, "height": height, "deviceScaleFactor": 1,
                                                            "mobile": False})
        if media is not None:
            browser.send("Emulation.setEmulatedMedia", {"media": media})
        browser.send("Page.navigate", {"url": str(url)})
        out = PageLoad()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            got = browser.send("Runtime.evaluate", {"expression": f"({ready}) ? performance.now() : -1",
                                                    "returnByValue": True})
            value = got.get("result", {}).get("value", -1)
            if isinstance(value, (int, float)) and value >= 0:
                out.ready_ms = float(value)
                break
            browser.pump(0.05)
        browser.pump(settle)
        for expression in evaluate:
            got = browser.send("Runtime.evaluate", {"expression": expression, "returnByValue": True})
            out.values[expression] = got.get("result", {}).get("value")
        if screenshot:
            shot = browser.send("Page.captureScreenshot", {"format": "png"})
            out.screenshot = base64.b64decode(shot["data"])
        out.dom = browser.send("Runtime.evaluate", {"expression": "document.documentElement.outerHTML",
                                                    "returnByValue": True})["result"].get("value", "")
        browser.pump(0.1)
        for event in browser.events:
            method, params = event.get("method"), event.get("params", {})
            if method == "Runtime.consoleAPICalled":
                out.console.append((params.get("type", "log"), _text(params.get("args", []))))
            elif method == "Runtime.exceptionThrown":
                d = params.get("exceptionDetails", {})
                out.exceptions.append(d.get("exception", {}).get("description") or d.get("text", "exception"))
            elif method == "Log.entryAdded":
                e = params.get("entry", {})
                out.console.append((e.get("level", "info"), f"[{e.get('source', '')}] {e.get('text', '')}"))
            elif method == "Network.requestWillBeSent":
                out.requests.append(params.get("request", {}).get("url", ""))
        return out
    finally:
        browser.close()
