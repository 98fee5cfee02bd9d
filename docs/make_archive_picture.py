"""Make docs/archive-rerun.png: recordings/turntable.npz archived with `--points --frames --keep-noise`
(ground-truth classes), the MCAP served by `rerun --serve-web` on 127.0.0.1 and opened in the Rerun web
viewer in headless Chromium (software WebGL), shot once the 3D view shows the three class colours.

    .venv/bin/python docs/make_archive_picture.py [--out docs/archive-rerun.png]

Needs Chromium (Debian: chromium).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VIEW_3D = (0.13, 0.06, 0.46, 0.74)  # the 3D view in Rerun's default layout for this archive


def main() -> int:
    from evstream.sinks.colours import CLASS_COLOURS
    from evstream.sinks.rerun_viewer import serve_file

    from evstream.chromium import CHROMIUM, HeadlessChromium, colour_counts, wait_until

    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "docs" / "archive-rerun.png"))
    ap.add_argument("--timeout-s", type=float, default=180.0)
    args = ap.parse_args()
    if CHROMIUM is None:
        print("no Chromium (apt-get install chromium)", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        mcap = d / "turntable.mcap"
        subprocess.run([sys.executable, "-m", "evstream.cli", "archive", str(ROOT / "recordings" / "turntable.npz"),
                        str(mcap), "--denoise", "truth", "--keep-noise", "--points", "--frames"], check=True)
        server, url = serve_file(mcap, log_dir=d)
        browser = HeadlessChromium(d / "profile", d / "chromium.log")
        try:
            session = browser.open(url, args.timeout_s)
            png = d / "shot.png"
            colours = {c.name: rgb for c, rgb in CLASS_COLOURS.items()}
            if not wait_until(browser, session, png, lambda png: min(colour_counts(png, colours, VIEW_3D).values())
                              >= 100, args.timeout_s):
                print(f"the 3D view did not show the three classes in {args.timeout_s:g} s", file=sys.stderr)
                return 1
            time.sleep(8.0)  # the viewer's start-up notices fade out
            browser.screenshot(session, png)
            Path(args.out).write_bytes(png.read_bytes())
            print(f"wrote {args.out}")
        finally:
            browser.close()
            server.terminate()
            server.wait(timeout=10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
