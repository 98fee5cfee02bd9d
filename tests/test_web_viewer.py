"""The web viewer for real: `evstream replay --serve` on 127.0.0.1, the page it prints opened in headless
Chromium (WebGL2 on SwiftShader, the CPU), and the screenshot must show the three class colours in the
3D view, as a user on a headless machine sees it through an SSH tunnel. The browser is driven by
`evstream.chromium` (DevTools on a pipe). Skipped, with the reason, where no Chromium is installed
(`.ci/run` installs Debian's `chromium`)."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_rerun_sink_viewer import TURNTABLE, assert_shows_three_classes, listeners, read_json_line

from evstream.chromium import CHROMIUM, HeadlessChromium

pytestmark = pytest.mark.skipif(CHROMIUM is None or shutil.which("bash") is None,
                                reason="no Chromium binary (apt-get install chromium)")

RENDER_TIMEOUT_S = 90.0  # page load, wasm compile and the first frames on a loaded 2-core machine


def shows_three_classes(png: Path) -> bool:
    try:
        assert_shows_three_classes(png)
    except AssertionError:
        return False
    return True


def test_served_web_viewer_renders_the_three_classes_in_headless_chromium(tmp_path):
    # Ctrl-C, unless this run ignores SIGINT (started in the background by a non-interactive shell): the
    # replay inherits that, so it gets SIGTERM, which it handles the same way.
    stop = signal.SIGINT if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN else signal.SIGTERM
    replay = subprocess.Popen(
        [sys.executable, "-m", "evstream.cli", "replay", str(TURNTABLE), "--serve", "--json", "--denoise", "truth",
         "--memory-limit", "256MiB"],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path,
    )
    browser = None
    try:
        summary = read_json_line(replay, 60)
        assert summary["output"] == "serve" and summary["events_hot_pixel"] > 0
        web_url = summary["web_url"]
        web_port = int(web_url.split("://", 1)[1].split("/")[0].rsplit(":", 1)[1])
        assert web_url.startswith("http://127.0.0.1:") and listeners(web_port) == ["127.0.0.1"]

        deadline = time.monotonic() + RENDER_TIMEOUT_S
        browser = HeadlessChromium(tmp_path / "chromium-profile", tmp_path / "chromium.log")
        session = browser.open(web_url, RENDER_TIMEOUT_S)
        png = tmp_path / "web-viewer.png"
        # The first shots show the loading screen (no class colours at all); shoot again until drawn.
        # A shot may take the time left: under load the software renderer draws a frame in a minute and more.
        while (not shows_three_classes(browser.screenshot(session, png, max(deadline - time.monotonic(), 2.0)))
               and time.monotonic() < deadline):
            assert replay.poll() is None, "the replay and its server stopped before Ctrl-C"
            time.sleep(2.0)
        assert_shows_three_classes(png)
        assert replay.poll() is None, "the replay and its server stopped before Ctrl-C"
    finally:
        try:
            if browser is not None:
                browser.close()
        finally:
            replay.send_signal(stop)  # the replay ends its server and exits 0
            try:
                code = replay.wait(timeout=20)
            except subprocess.TimeoutExpired:
                replay.kill()
                code = replay.wait()
            errors = replay.stderr.read().decode(errors="replace")
            replay.stdout.close()
            replay.stderr.close()
            print(errors[-2000:], file=sys.stderr)  # shown by pytest when the test fails
    assert code == 0, f"the replay exited {code} on {stop.name}"
