"""A headless Chromium driven over the DevTools protocol on a pipe, to look at the Rerun web viewer as a
user on a headless machine would (tests, benchmarks/bench_viewer.py, the docs' screenshot scripts).

`--remote-debugging-pipe`: NUL-terminated JSON on file descriptors 3 and 4, which needs nothing beyond the
standard library. Plain `--screenshot` cannot wait for the viewer: it shoots on the page's load event,
while the wasm viewer is still "Loading Application Bundle"; callers re-shoot until the content is drawn.
WebGL2 runs in software (SwiftShader), so it works without a GPU. The page is 1600x1000 unless
EVSTREAM_VIEWPORT says otherwise (e.g. 1024x640: software rendering costs grow with the pixels).
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import shutil
import signal
import subprocess
import time
from pathlib import Path

CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
VIEWPORT = tuple(int(v) for v in os.environ.get("EVSTREAM_VIEWPORT", "1600x1000").split("x"))


class BrowserError(RuntimeError):
    """Chromium exited, refused a command or did not answer in time."""


class HeadlessChromium:
    """A headless Chromium (its own process group and throwaway profile) and a DevTools client on a pipe."""

    def __init__(self, profile: Path, log: Path):
        to_browser, from_browser = os.pipe(), os.pipe()
        # Descriptors >= 10 so that bash's redirections onto 3 and 4 cannot clobber them.
        fds = [fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10) for fd in (*to_browser, *from_browser)]
        for fd in (*to_browser, *from_browser):
            os.close(fd)
        child_in, self._write_fd, self._read_fd, child_out = fds
        cmd = [CHROMIUM, "--headless=new", "--remote-debugging-pipe", f"--user-data-dir={profile}",
               # the test runs as root in CI, where Chromium's sandbox cannot start; the page is our own
               "--no-sandbox",
               # the loopback and nothing else: host names do not resolve (the viewer's examples list is
               # not fetched), no update, sync or metrics connections
               "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--disable-quic", "--mute-audio", "--hide-scrollbars",
               # WebGL2 in software, also where the GPU blocklist or a missing GPU would refuse it
               "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
               # a headless tab counts as hidden: keep its timers and frames running
               "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
               "--disable-backgrounding-occluded-windows",
               f"--window-size={VIEWPORT[0]},{VIEWPORT[1]}", "about:blank"]
        self.log = log
        with open(log, "wb") as err:
            self.process = subprocess.Popen(
                ["bash", "-c", f'exec "$@" 3<&{child_in} 4>&{child_out} {child_in}<&- {child_out}>&-', "bash", *cmd],
                pass_fds=(child_in, child_out), stdin=subprocess.DEVNULL, stdout=err, stderr=subprocess.STDOUT,
                start_new_session=True,  # its GPU, renderer and zygote processes go with the group
            )
        os.close(child_in)
        os.close(child_out)
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict] = []

    def _receive(self, deadline: float, what: str) -> dict:
        """The next DevTools message (a reply or an event)."""
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError(f"Chromium: no {what} in time; its log: {self.log_tail()}")
            if select.select([self._read_fd], [], [], left)[0]:
                chunk = os.read(self._read_fd, 1 << 20)
                if not chunk:
                    raise BrowserError(f"Chromium exited ({self.process.poll()}): {self.log_tail()}")
                self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, params: dict | None = None, session: str | None = None,
             timeout_s: float = 60.0) -> dict:
        """Send one DevTools command and wait for its reply (events meanwhile are kept for `wait_for`)."""
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._write_fd, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._receive(deadline, f"reply to {method}")
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error']}")
                return reply["result"]
            if "method" in reply:
                self._events.append(reply)

    def wait_for(self, event: str, session: str, timeout_s: float) -> dict:
        """The first `event` of `session` (seen already, or next to come)."""
        deadline = time.monotonic() + timeout_s
        while True:
            for i, message in enumerate(self._events):
                if message["method"] == event and message.get("sessionId") == session:
                    return self._events.pop(i)["params"]
            self._events = []
            message = self._receive(deadline, event)
            if "method" in message:
                self._events.append(message)

    def open(self, url: str, timeout_s: float) -> str:
        """A new tab of VIEWPORT size showing `url` (loaded: its load event fired); its session id."""
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        self.call("Page.enable", session=session)
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": VIEWPORT[0], "height": VIEWPORT[1], "deviceScaleFactor": 1, "mobile": False}, session)
        nav = self.call("Page.navigate", {"url": url}, session)
        if nav.get("errorText"):
            raise BrowserError(f"Chromium could not open {url}: {nav['errorText']}")
        self.wait_for("Page.loadEventFired", session, timeout_s)
        return session

    def screenshot(self, session: str, png: Path, timeout_s: float = 60.0) -> Path:
        """Write the tab's page to `png`. Under load the renderer can take a minute and more to draw a frame
        of the wasm viewer in software: a caller waiting for a drawn picture gives it the rest of its time."""
        shot = self.call("Page.captureScreenshot", {"format": "png"}, session, timeout_s=timeout_s)
        png.write_bytes(base64.b64decode(shot["data"]))
        return png

    def log_tail(self) -> str:
        lines = [ln for ln in self.log.read_text(errors="replace").splitlines() if "dbus" not in ln]
        return "\n".join(lines[-10:])

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout_s=10)
        except (BrowserError, OSError):
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass
        try:
            os.killpg(self.process.pid, signal.SIGKILL)  # whatever of its group is left
        except ProcessLookupError:
            pass
        self.process.wait(timeout=10)
        os.close(self._write_fd)
        os.close(self._read_fd)


def wait_until(browser: HeadlessChromium, session: str, png: Path, drawn, timeout_s: float,
               alive=lambda: True, every_s: float = 2.0) -> bool:
    """Re-shoot `png` until `drawn(png)` holds (True), `timeout_s` passes or `alive()` fails (False).
    One shot may take all the time left (at least `every_s`): a slow frame is not a failure before the end."""
    deadline = time.monotonic() + timeout_s
    while True:
        browser.screenshot(session, png, timeout_s=max(deadline - time.monotonic(), every_s))
        if drawn(png):
            return True
        if time.monotonic() > deadline or not alive():
            return False
        time.sleep(every_s)


def colour_counts(png: Path, colours: dict, box: tuple[float, float, float, float], tol: int = 40) -> dict:
    """Pixels within `tol` (per channel) of each named RGB colour, inside `box` = (left, top, right,
    bottom) as fractions of the screenshot. Pillow reads the PNG (rerun-sdk depends on it)."""
    import numpy as np
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB")).astype(np.int16)
    h, w, _ = img.shape
    left, top, right, bottom = box
    view = img[int(top * h): int(bottom * h), int(left * w): int(right * w)]
    return {name: int((np.abs(view - np.array(rgb)).max(axis=2) <= tol).sum()) for name, rgb in colours.items()}


# -- the web viewer's state: the ViewerState protobuf of `window._handle.viewer_state()` -------------------
def _varint(b: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        c = b[i]
        i += 1
        value |= (c & 0x7F) << shift
        shift += 7
        if c < 0x80:
            return value, i


def _fields(b: bytes) -> list[tuple[int, int, object]]:
    """(field number, wire type, value) of one protobuf message (no schema: what the wire says)."""
    out, i = [], 0
    while i < len(b):
        key, i = _varint(b, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(b, i)
        elif wire == 2:
            n, i = _varint(b, i)
            value, i = b[i:i + n], i + n
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
            value, i = b[i:i + size], i + size
        else:
            raise ValueError(f"protobuf wire type {wire}")
        out.append((number, wire, value))
    return out


def _name(msg: bytes) -> bytes | None:
    return dict((n, v) for n, _, v in _fields(msg)).get(1)


def _time(wire: int, value) -> int:
    """A time field: a varint, or a message whose field 1 is one (absent = 0)."""
    if wire == 0:
        return int(value)
    return int(dict((n, v) for n, _, v in _fields(value)).get(1, 0))


def viewer_times(state: bytes, timeline: str = "event_time") -> tuple[int | None, int | None]:
    """(time cursor, newest time ingested) on `timeline`, ns, from a ViewerState protobuf: its
    recordings (field 3) hold timelines (field 2: {1: {1: name}, 2: type, 3: {1: start, 2: end}}) and
    the current timeline and time (field 3: {1: {1: name}, 2: type, 3: time})."""
    want = timeline.encode()
    cursor = newest = None
    for number, wire, rec in _fields(state):
        if number != 3 or wire != 2:
            continue
        for n2, w2, sub in _fields(rec):
            if w2 != 2 or n2 not in (2, 3):
                continue
            parts = {n: (w, v) for n, w, v in _fields(sub)}
            if 1 not in parts or _name(parts[1][1]) != want:
                continue
            if n2 == 3:
                cursor = _time(*parts.get(3, (0, 0)))
            elif 3 in parts:
                span = {n: (w, v) for n, w, v in _fields(parts[3][1])}
                newest = _time(*span.get(2, (0, 0)))
    return cursor, newest


VIEWER_STATE_JS = "btoa(String.fromCharCode(...window._handle.viewer_state()))"


def page_viewer_times(browser: HeadlessChromium, session: str, timeline: str = "event_time"
                      ) -> tuple[int | None, int | None]:
    """(time cursor, newest time ingested) on `timeline`, ns, of the Rerun web viewer in a tab."""
    reply = browser.call("Runtime.evaluate", {"expression": VIEWER_STATE_JS, "returnByValue": True}, session)
    return viewer_times(base64.b64decode(reply["result"]["value"]), timeline)
