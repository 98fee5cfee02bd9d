"""Make docs/viewer-turntable.png: recordings/turntable.npz replayed through the default pipeline (the
paper's cascade) with the fixed-window framer, shown by the native Rerun viewer under Xvfb.

    .venv/bin/python docs/make_picture.py [--time-s 0.35]

Needs Xvfb and a Vulkan driver (Debian: xvfb mesa-vulkan-drivers). The viewer listens on 127.0.0.1.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evstream.sinks.rerun_sink import TIMELINE  # noqa: E402
from evstream.sinks.rerun_viewer import free_port, open_output  # noqa: E402

from evstream.cli import main as evstream  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--time-s", type=float, default=0.35, help="time cursor (event time, s)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "viewer-turntable.png"))
    ap.add_argument("--size", default="1600x900", help="window size in points")
    args = ap.parse_args()
    from rerun.experimental import ViewerClient

    width, height = (int(v) for v in args.size.split("x"))
    # A screen bigger than the window keeps Xvfb's pointer (the screen centre) off it: no tooltip.
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", "1", "-screen", "0", f"{width * 4}x{height * 4}x24",
                             "-nolisten", "tcp"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    viewer = None
    try:
        os.environ["DISPLAY"] = ":" + xvfb.stdout.readline().strip()
        port = free_port()
        viewer = open_output(spawn=True, grpc_port=port).process
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        assert evstream(["replay", str(ROOT / "recordings" / "turntable.npz"), "--framer", "fw",
                         "--connect", url]) == 0
        client = ViewerClient.connect(url)
        client.set_time(TIMELINE, duration=args.time_s, play_state="paused")
        time.sleep(15)  # the viewer's start-up notices fade out
        client.save_screenshot(args.out)
        print(f"wrote {args.out}")
    finally:
        if viewer is not None:
            viewer.terminate()
            viewer.wait(timeout=10)
        xvfb.terminate()
        xvfb.wait(timeout=10)


if __name__ == "__main__":
    main()
