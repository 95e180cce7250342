"""Headless Chromium over the DevTools protocol (CDP) on a pipe, for report checks and screenshots.

Why a pipe and no client library: ``--remote-debugging-pipe`` makes Chromium read CDP commands on
fd 3 and write replies on fd 4 as NUL-terminated JSON, so the standard library is all we need -
no websocket client, no Playwright/Selenium and no browser download. Only the system's Chromium
(Debian's ``chromium``) is used; ``POLARREF_CHROMIUM`` points at another binary.
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import queue
import shutil
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--no-default-browser-check",
         "--disable-extensions", "--hide-scrollbars", "--mute-audio", "--remote-debugging-pipe")


def find_chromium() -> str | None:
    """Path of a Chromium binary (``$POLARREF_CHROMIUM``, else chromium on PATH), or None."""
    env = os.environ.get("POLARREF_CHROMIUM")
    if env:
        return env if Path(env).is_file() else None
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _field_from_json(reply: dict, name: str) -> str:
    """The string ``name`` of a CDP reply (PolarrefError naming it when the reply lacks it)."""
    value = reply.get(name)
    if not isinstance(value, str):
        raise PolarrefError(f"Chromium: reply without {name}: {str(reply)[:200]}")
    return value


def _command_to_json(msg_id: int, method: str, params: dict, session: str | None) -> bytes:
    """One CDP command as the pipe carries it (without the NUL terminator)."""
    return json.dumps({"id": msg_id, "method": method, "params": params,
                       **({"sessionId": session} if session else {})}).encode()


def _message_from_json(raw: bytes) -> tuple[int | None, dict]:
    """(reply id or None for an event, the parsed message)."""
    msg = json.loads(raw)
    return msg.get("id"), msg


def _result_from_json(reply: dict, method: str) -> dict:
    """The ``result`` of a CDP reply; PolarrefError with CDP's message when the reply is an error."""
    if "error" in reply:
        raise PolarrefError(f"Chromium: {method}: {reply['error'].get('message')}")
    return reply.get("result", {})


class Chromium:
    """One headless Chromium process driven over CDP; use as a context manager."""

    def __init__(self, executable: str | None = None, timeout_s: float = 60.0):
        exe = executable or find_chromium()
        if exe is None:
            raise PolarrefError("Chromium not found (apt-get install chromium, or set POLARREF_CHROMIUM)")
        self.timeout_s = timeout_s
        self._profile = tempfile.mkdtemp(prefix="polarref-chromium-")
        cmd_r, self._cmd_w = os.pipe()
        self._res_r, res_w = os.pipe()

        def _fds():  # move our pipe ends to fds 3 and 4 without clobbering one with the other
            a, b = fcntl.fcntl(cmd_r, fcntl.F_DUPFD, 10), fcntl.fcntl(res_w, fcntl.F_DUPFD, 10)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen([exe, *FLAGS, f"--user-data-dir={self._profile}", "about:blank"],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, pass_fds=(3, 4), preexec_fn=_fds)
        os.close(cmd_r)
        os.close(res_w)
        self._next = 0
        self._replies: dict[int, dict] = {}
        self._events: queue.Queue = queue.Queue()
        self._cv = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(self._res_r, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                with self._cv:
                    self._replies[-1] = {"error": {"message": "Chromium closed the DevTools pipe"}}
                    self._cv.notify_all()
                return
            buf += chunk
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                msg_id, msg = _message_from_json(raw)
                if msg_id is not None:
                    with self._cv:
                        self._replies[msg_id] = msg
                        self._cv.notify_all()
                else:
                    self._events.put(msg)

    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        """Send one command and wait for its result (raises PolarrefError on a CDP error or timeout)."""
        self._next += 1
        os.write(self._cmd_w, _command_to_json(self._next, method, params or {}, session) + b"\0")
        deadline = time.monotonic() + self.timeout_s
        with self._cv:
            while self._next not in self._replies and -1 not in self._replies:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise PolarrefError(f"Chromium did not answer {method} within {self.timeout_s:.0f} s")
                self._cv.wait(left)
            reply = self._replies.pop(self._next, None) or self._replies[-1]
        return _result_from_json(reply, method)

    def open_page(self) -> str:
        """A new blank tab, attached: its session id."""
        target = _field_from_json(self._send("Target.createTarget", {"url": "about:blank"}), "targetId")
        return _field_from_json(self._send("Target.attachToTarget", {"targetId": target, "flatten": True}),
                                "sessionId")

    def screenshot(self, session: str, width: int, height: int) -> bytes:
        """PNG of the top ``width`` x ``height`` of the page."""
        reply = self._send("Page.captureScreenshot", {"format": "png", "clip": {
            "x": 0, "y": 0, "width": width, "height": height, "scale": 1}}, session)
        return base64.b64decode(_field_from_json(reply, "data"))

    def events(self) -> list[dict]:
        """Events received so far (drained)."""
        out = []
        while True:
            try:
                out.append(self._events.get_nowait())
            except queue.Empty:
                return out

    def wait_event(self, method: str, session: str, timeout_s: float | None = None) -> list[dict]:
        """Wait for ``method`` on ``session``; returns every event seen meanwhile (it included)."""
        seen, deadline = [], time.monotonic() + (timeout_s or self.timeout_s)
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise PolarrefError(f"Chromium: no {method} within {timeout_s or self.timeout_s:.0f} s")
            try:
                ev = self._events.get(timeout=min(left, 0.5))
            except queue.Empty:
                if self.proc.poll() is not None:
                    raise PolarrefError(f"Chromium exited with code {self.proc.returncode}") from None
                continue
            seen.append(ev)
            if ev.get("method") == method and ev.get("sessionId") == session:
                return seen

    def close(self) -> None:
        try:
            self._send("Browser.close")
        except PolarrefError:
            pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        for fd in (self._cmd_w, self._res_r):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> "Chromium":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class TableProbe:
    """The summary table's bounding box (CSS px) and whether it is the element seen at its centre."""

    top: float
    bottom: float
    width: float
    height: float
    viewport: float
    visible: bool


@dataclass(frozen=True)
class CanvasProbe:
    """Pixel statistics of the 3D view's canvas (``hash``: of the pixel values, to tell redraws apart)."""

    pixels: int
    dark_pixels: int
    variance: float
    hash: int
    rect: tuple[float, float, float, float]   # page x, y, width, height
    drawn: int                                # frames the viewer says it drew
    ready: bool


@dataclass(frozen=True)
class PageProbe:
    """What the page script :data:`_PROBE` measured."""

    images: int
    broken_images: int
    table: TableProbe | None
    canvas: CanvasProbe | None


@dataclass
class PageCheck:
    """What a headless load of a report page showed."""

    console_errors: list[str] = field(default_factory=list)
    network_requests: list[str] = field(default_factory=list)   # anything not file: or data:
    images: int = 0
    broken_images: int = 0
    summary_table: TableProbe | None = None
    canvas: CanvasProbe | None = None
    canvas_after_drag: CanvasProbe | None = None  # the same after a mouse drag across it (orbit)
    screenshot_png: bytes | None = None


def _canvas_from_json(c: dict | None) -> CanvasProbe | None:
    if c is None:
        return None
    return CanvasProbe(int(c["pixels"]), int(c["dark_pixels"]), float(c["variance"]), int(c["hash"]),
                       tuple(float(x) for x in c["rect"]), int(c["drawn"]), bool(c["ready"]))


def _probe_from_json(v: dict) -> PageProbe:
    """The probe's JSON value as a record."""
    t = v["table"]
    table = None if t is None else TableProbe(float(t["top"]), float(t["bottom"]), float(t["width"]),
                                              float(t["height"]), float(t["viewport"]), bool(t["visible"]))
    return PageProbe(int(v["images"]), int(v["broken"]), table, _canvas_from_json(v["canvas"]))


def _value_from_json(reply: dict):
    """The value of a ``Runtime.evaluate`` reply (``returnByValue``); PolarrefError when the script threw."""
    if "exceptionDetails" in reply:
        raise PolarrefError(f"page script failed: {reply['exceptionDetails'].get('text')}")
    return reply["result"].get("value")


def _evaluate(br: "Chromium", sid: str, expression: str):
    """Evaluate ``expression`` in the page and return its value (awaiting a promise)."""
    return _value_from_json(br._send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                         "awaitPromise": True}, sid))


# let the viewer's first requestAnimationFrame and any late console message arrive
_TWO_FRAMES = "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))"
_PROBE = """(() => {
  const imgs = Array.from(document.images);
  const t = document.querySelector('#summary table');
  let table = null;
  if (t) {
    const r = t.getBoundingClientRect(), s = getComputedStyle(t);
    const hit = document.elementFromPoint(r.left + r.width / 2, r.top + Math.min(r.height / 2, 20));
    table = {top: r.top, bottom: r.bottom, width: r.width, height: r.height, viewport: innerHeight,
             visible: s.visibility === 'visible' && s.display !== 'none' && !!hit && t.contains(hit)};
  }
  const c = document.getElementById('view3d-canvas');
  let canvas = null;
  if (c) {
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let n = 0, s = 0, s2 = 0, h = 0;
    for (let i = 0; i < d.length; i += 4) {
      const v = d[i] + d[i + 1] + d[i + 2];
      s += v; s2 += v * v; h = (h * 31 + v) % 1000000007;
      if (d[i] < 240 || d[i + 1] < 240 || d[i + 2] < 240) n++;
    }
    const N = d.length / 4;
    const r = c.getBoundingClientRect();
    canvas = {pixels: N, dark_pixels: n, variance: s2 / N - (s / N) ** 2, hash: h,
              rect: [r.left + scrollX, r.top + scrollY, r.width, r.height],
              drawn: Number(c.getAttribute('data-drawn') || 0),
              ready: document.getElementById('view3d').getAttribute('data-ready') === '1'};
  }
  return {images: imgs.length, broken: imgs.filter(i => !(i.complete && i.naturalWidth > 0)).length,
          table: table, canvas: canvas};
})()"""


def _errors_from_json(events: list[dict]) -> tuple[list[str], list[str]]:
    """Console errors and non-local requests among the CDP events (parsed JSON messages)."""
    errors, requests = [], []
    for ev in events:
        m, p = ev.get("method"), ev.get("params", {})
        if m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            errors.append("console: " + " ".join(str(a.get("value", a.get("description", ""))) for a in p["args"]))
        elif m == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            errors.append("exception: " + str(d.get("exception", {}).get("description") or d.get("text")))
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            errors.append("log: " + p["entry"].get("text", ""))
        elif m == "Network.requestWillBeSent":
            url = p.get("request", {}).get("url", "")
            if not url.startswith(("file:", "data:", "about:")):
                requests.append(url)
    return errors, requests


def check_page(html_path: str | Path, width: int = 1280, height: int = 800, screenshot: bool = False,
               drag: bool = False, chromium: str | None = None, timeout_s: float = 60.0) -> PageCheck:
    """Load ``html_path`` offline (network emulated as disconnected) at ``width`` x ``height``; probe it.

    The screenshot (``screenshot=True``) is taken before any drag, of the page's top.
    """
    url = Path(html_path).resolve().as_uri()
    with Chromium(chromium, timeout_s) as br:
        sid = br.open_page()
        for method in ("Runtime.enable", "Log.enable", "Network.enable", "Page.enable"):
            br._send(method, session=sid)
        br._send("Network.emulateNetworkConditions", {"offline": True, "latency": 0, "downloadThroughput": 0,
                                                     "uploadThroughput": 0}, sid)
        br._send("Emulation.setDeviceMetricsOverride", {"width": width, "height": height,
                                                       "deviceScaleFactor": 1, "mobile": False}, sid)
        br._send("Page.navigate", {"url": url}, sid)
        events = br.wait_event("Page.loadEventFired", sid)
        # let the viewer's first requestAnimationFrame and any late console message arrive
        _evaluate(br, sid, _TWO_FRAMES)
        probe = _probe_from_json(_evaluate(br, sid, _PROBE))
        shot = br.screenshot(sid, width, height) if screenshot else None
        after = _drag(br, sid) if drag and probe.canvas else None
        errors, requests = _errors_from_json(events + br.events())
    return PageCheck(errors, requests, probe.images, probe.broken_images, probe.table, probe.canvas, after, shot)


def _drag(br: Chromium, sid: str) -> CanvasProbe | None:
    """Scroll the canvas into view, drag across it with the left button, probe again."""
    _evaluate(br, sid, "document.getElementById('view3d-canvas').scrollIntoView()")
    pos = _evaluate(br, sid, "(() => {const r = document.getElementById('view3d-canvas')"
                             ".getBoundingClientRect(); return [r.left, r.top, r.width, r.height];})()")
    x0, y0 = pos[0] + pos[2] / 2, pos[1] + pos[3] / 2
    mouse = lambda kind, x, buttons: br._send("Input.dispatchMouseEvent", {
        "type": kind, "x": x, "y": y0, "button": "left", "buttons": buttons, "clickCount": 1}, sid)
    mouse("mousePressed", x0, 1)
    for k in range(1, 6):
        mouse("mouseMoved", x0 + 30 * k, 1)
    mouse("mouseReleased", x0 + 150, 0)
    _evaluate(br, sid, _TWO_FRAMES)
    return _probe_from_json(_evaluate(br, sid, _PROBE)).canvas


def screenshot(html_path: str | Path, png_path: str | Path, width: int = 1280, height: int = 800) -> PageCheck:
    """Write the top ``width`` x ``height`` of the page as PNG (atomically); returns the page check."""
    check = check_page(html_path, width, height, screenshot=True)
    png_path = Path(png_path)
    atomic_write(png_path, check.screenshot_png or b"")
    return check
