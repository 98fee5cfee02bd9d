"""Make docs/live-restart.png: a live stream whose publisher restarts, in the Rerun web viewer.

A router and `evstream subscribe 'evstream/*/events' --serve` on 127.0.0.1, then `evstream publish
recordings/bar.npz` twice on the same key (the second starts again at sequence 0); the page the subscriber
prints is opened in headless Chromium (software WebGL) and shot once the 3D view shows the three class
colours after the restart. The second stream's timeline continues after the first one's (docs/live.md).

    .venv/bin/python docs/make_restart_picture.py [--out docs/live-restart.png]

Needs Chromium (Debian: chromium).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VIEW_3D = (0.0, 0.06, 0.58, 0.95)  # the events view: the left 3/5 of the sink's layout


def main() -> int:
    from evstream.sinks.colours import CLASS_COLOURS
    from evstream.sinks.rerun_viewer import free_port

    from evstream.chromium import CHROMIUM, HeadlessChromium, colour_counts, page_viewer_times, wait_until

    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "docs" / "live-restart.png"))
    ap.add_argument("--timeout-s", type=float, default=240.0)
    args = ap.parse_args()
    if CHROMIUM is None:
        print("no Chromium (apt-get install chromium)", file=sys.stderr)
        return 1
    evstream = [sys.executable, "-m", "evstream.cli"]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        port = free_port()
        ep = f"tcp/127.0.0.1:{port}"
        procs = []
        browser = None
        try:
            router = subprocess.Popen([*evstream, "router", "--listen", ep], stderr=subprocess.DEVNULL,
                                      stdout=subprocess.DEVNULL)
            procs.append(router)
            time.sleep(2)
            sub = subprocess.Popen([*evstream, "subscribe", "evstream/*/events", "--connect", ep, "--serve"],
                                   stdout=subprocess.PIPE, stderr=open(d / "sub.err", "wb"), text=True)
            procs.append(sub)
            url = sub.stdout.readline().split("web viewer: ", 1)[1].strip()
            browser = HeadlessChromium(d / "profile", d / "chromium.log")
            session = browser.open(url, args.timeout_s)
            for _ in range(2):  # the same key twice: the second publisher's sequence starts at 0 again
                subprocess.run([*evstream, "publish", str(ROOT / "recordings" / "bar.npz"), "--key",
                                "evstream/front/events", "--connect", ep, "--speed", "0.5", "--wait-subscribers",
                                "10", "--drain-s", "0"], check=True, stdout=subprocess.DEVNULL)
            restarted = "publisher restarted" in (d / "sub.err").read_text()
            png = d / "shot.png"
            colours = {c.name: rgb for c, rgb in CLASS_COLOURS.items()}
            deadline = time.monotonic() + args.timeout_s
            second_ns = 600_000_000  # the second stream: after the first (0.5 s) and one slab (0.1 s)
            while (page_viewer_times(browser, session)[0] or 0) < second_ns + 300_000_000:
                if time.monotonic() > deadline:
                    print("the viewer did not reach the second stream in time", file=sys.stderr)
                    return 1
                time.sleep(2.0)
            if not wait_until(browser, session, png, lambda png: min(colour_counts(png, colours, VIEW_3D).values())
                              >= 100, deadline - time.monotonic()):
                print("the 3D view did not show the three classes in time", file=sys.stderr)
                return 1
            Path(args.out).write_bytes(png.read_bytes())
            print(f"wrote {args.out} (the subscriber {'saw' if restarted else 'did NOT see'} the restart)")
            return 0 if restarted else 1
        finally:
            if browser is not None:
                browser.close()
            for p in reversed(procs):  # Ctrl-C stops a subscriber's stream, a second one its server
                for _ in range(3):
                    p.send_signal(signal.SIGINT)
                    try:
                        p.wait(timeout=10)
                        break
                    except subprocess.TimeoutExpired:
                        continue
                else:
                    p.kill()
                    p.wait()


if __name__ == "__main__":
    sys.exit(main())
