"""The viewer for real: the native Rerun viewer renders our recording under Xvfb (software Vulkan) and
the screenshot must show the three class colours in the 3D view; `--spawn` and `--serve` listen on
127.0.0.1 only and accept a connection from it. Skipped, with the reason, where Xvfb is missing
(`.ci/run` installs xvfb and mesa-vulkan-drivers)."""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from evstream.sinks.rerun_sink import CLASS_COLOURS, RerunSink
from evstream.sinks.rerun_viewer import free_port, is_listening, open_output, rerun_binary
from evstream.sources import open_source

from evstream.pipeline import Pipeline, build

ROOT = Path(__file__).resolve().parents[1]
TURNTABLE = ROOT / "recordings" / "turntable.npz"
needs_xvfb = pytest.mark.skipif(shutil.which("xvfb-run") is None or shutil.which("Xvfb") is None,
                                reason="Xvfb not installed (apt-get install xvfb mesa-vulkan-drivers)")


def replay_turntable(rec: rr.RecordingStream) -> RerunSink:
    src = open_source(str(TURNTABLE))
    sink = RerunSink(rec, geometry=src.geometry, play_state="following")
    Pipeline([build("stage", {"kind": "truth"})]).run(src, [sink])
    return sink


def colour_pixels(png: Path) -> tuple[dict, int]:
    """Pixels near each class colour inside the 3D view (left part of the window, below the top bar:
    the time-series legends elsewhere use the same colours), and the number of distinct colours."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB")).astype(np.int16)
    h, w, _ = img.shape
    view = img[int(0.06 * h): int(0.95 * h), : int(0.55 * w)]
    counts = {c.name: int((np.abs(view - np.array(rgb)).max(axis=2) <= 40).sum()) for c, rgb in CLASS_COLOURS.items()}
    return counts, len(np.unique(view.reshape(-1, 3), axis=0))


def assert_shows_three_classes(png: Path) -> None:
    counts, distinct = colour_pixels(png)
    assert distinct > 200, f"screenshot looks blank ({distinct} colours)"
    for name, n in counts.items():
        assert n >= 300, f"{name} colour hardly visible in the 3D view: {counts}"


def listeners(port: int) -> list[str]:
    """Local addresses of LISTEN sockets on `port`, from /proc/net/tcp and tcp6 ('127.0.0.1', '::', ...)."""
    found = []
    for table, v6 in (("/proc/net/tcp", False), ("/proc/net/tcp6", True)):
        if not os.path.exists(table):
            continue
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            addr, port_hex = fields[1].split(":")
            if fields[3] != "0A" or int(port_hex, 16) != port:
                continue
            if v6:
                found.append("::" if int(addr, 16) == 0 else "v6:" + addr)
            else:
                found.append(".".join(str(b) for b in reversed(bytes.fromhex(addr))))
    return found


@needs_xvfb
def test_native_viewer_screenshot_shows_the_three_classes(tmp_path):
    rrd, png = tmp_path / "turntable.rrd", tmp_path / "shot.png"
    out = open_output(save=str(rrd))
    replay_turntable(out.rec)
    out.finish()
    # A screen bigger than the window keeps Xvfb's pointer (at the screen centre) off it: no tooltip.
    cmd = ["xvfb-run", "-a", "-s", "-screen 0 6000x4000x24", rerun_binary(), "--bind", "127.0.0.1",
           "--port", "0", str(rrd), "--screenshot-to", str(png), "--window-size", "1600x900"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "RERUN_APP_ONLY": "true"})
    assert proc.returncode == 0 and png.is_file(), proc.stderr[-2000:]
    assert_shows_three_classes(png)


@needs_xvfb
def test_spawned_viewer_listens_on_loopback_and_renders_the_stream(tmp_path, monkeypatch):
    from rerun.experimental import ViewerClient

    xvfb = subprocess.Popen(["Xvfb", "-displayfd", "1", "-screen", "0", "6000x4000x24", "-nolisten", "tcp"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out = None
    try:
        display = xvfb.stdout.readline().strip()
        assert display, "Xvfb did not start"
        monkeypatch.setenv("DISPLAY", f":{display}")
        port = free_port()
        out = open_output(spawn=True, grpc_port=port, memory_limit="1GiB", log_dir=tmp_path)
        assert out.process is not None
        assert listeners(port) == ["127.0.0.1"]
        replay_turntable(out.rec)
        out.finish()
        client = ViewerClient.connect(out.grpc_url)
        deadline = time.monotonic() + 30
        while not client.get_state().recordings and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(1.0)  # let it draw
        png = tmp_path / "spawn.png"
        client.save_screenshot(str(png))
        assert_shows_three_classes(png)
    finally:
        if out is not None and out.process is not None:
            out.process.terminate()
            out.process.wait(timeout=10)
        xvfb.terminate()
        xvfb.wait(timeout=10)


def read_json_line(proc: subprocess.Popen, timeout_s: float) -> dict:
    """The child's JSON summary line, read from its stdout pipe unbuffered: a buffered readline behind
    select can keep the line in Python's buffer while select waits on an empty pipe. Fails (never
    hangs) when no line comes: a serving replay does not exit on its own."""
    fd, seen = proc.stdout.fileno(), b""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in seen.split(b"\n")[:-1]:
            if line.startswith(b"{"):
                return json.loads(line)
        if select.select([fd], [], [], 0.5)[0]:
            chunk = os.read(fd, 1 << 16)
            if not chunk:
                break
            seen += chunk
        elif proc.poll() is not None:
            break
    raise AssertionError(f"no JSON summary within {timeout_s:.0f} s (exit {proc.poll()}): {seen[-2000:]!r}")


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_serve_listens_on_loopback_only_and_accepts_a_local_connection(tmp_path, stop):
    proc = subprocess.Popen(
        [sys.executable, "-m", "evstream.cli", "replay", str(TURNTABLE), "--serve", "--json", "--denoise", "truth",
         "--memory-limit", "256MiB"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, start_new_session=True,
    )
    try:
        summary = read_json_line(proc, 60)
        assert summary["output"] == "serve" and summary["events_in"] == 254_078
        grpc_port = int(summary["grpc_url"].rsplit(":", 1)[1].split("/")[0])
        web_port = int(summary["web_url"].split("://", 1)[1].split("/")[0].rsplit(":", 1)[1])
        for port in (grpc_port, web_port):
            assert listeners(port) == ["127.0.0.1"], (port, listeners(port))
        assert summary["web_url"].startswith(f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp")
        with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10) as r:
            assert r.status == 200 and b"<html" in r.read(4096).lower()
        # a second SDK client logs into the server over gRPC from 127.0.0.1
        probe = rr.RecordingStream("evstream-probe")
        probe.connect_grpc(summary["grpc_url"])
        probe.log("probe", rr.Scalars(1.0))
        probe.flush(timeout_sec=10)
        probe.disconnect()
        assert proc.poll() is None, "the server stopped before Ctrl-C"
    finally:
        proc.send_signal(stop)
        try:
            code = proc.wait(timeout=20)
        except subprocess.TimeoutExpired:  # fail, but leave no server (nor its viewer) listening behind
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
    assert code == (-signal.SIGKILL if stop == signal.SIGKILL else 0)
    deadline = time.monotonic() + 10  # the server goes with the replay, even when that is killed
    while is_listening("127.0.0.1", grpc_port) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not is_listening("127.0.0.1", grpc_port) and not is_listening("127.0.0.1", web_port)
