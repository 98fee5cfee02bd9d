"""Make the pictures of docs/framing.md (representations) and docs/transforms.md (transforms) from the
shipped recording recordings/turntable.npz, through the Python API:

    python docs/represent_pictures.py [--out-dir docs] [--window-ms 30]

docs/represent_<kind>.png: the window around the middle of the recording as each representation sees it
(fixed 30 ms windows; the time surface with τ = 20 ms). docs/transforms.png: the same window's count
image after each transform.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evstream.sources import native  # noqa: E402

from evstream.events import concat  # noqa: E402
from evstream.framing.render import mosaic, render_representation, write_png  # noqa: E402
from evstream.framing.represent import REPRESENTATIONS  # noqa: E402
from evstream.pipeline import Pipeline, build  # noqa: E402
from evstream.testing import frames_of  # noqa: E402

EXTRA = {"timesurface": {"tau_us": 20_000}, "voxel": {"bins": 5}}
TRANSFORMS = [
    ("original", []),
    ("crop 200x150 at (73, 55)", [{"kind": "crop", "x0": 73, "y0": 55, "width": 200, "height": 150}]),
    ("flip x", [{"kind": "flip", "axis": "x"}]),
    ("rotate 90", [{"kind": "rotate", "degrees": 90}]),
    ("downsample 2", [{"kind": "downsample", "factor": 2}]),
    ("polarity on", [{"kind": "polarity", "keep": "on"}]),
    ("undistort k1 = -0.3", [{"kind": "undistort", "fx": 250.0, "fy": 250.0, "cx": 173.0, "cy": 130.0,
                              "distortion": [-0.3, 0.08, 0.0, 0.0, 0.0]}]),
]


def middle(frames):
    return frames[len(frames) // 2]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out-dir", default=str(ROOT / "docs"))
    ap.add_argument("--window-ms", type=float, default=30.0)
    args = ap.parse_args()
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    source = native.open(ROOT / "recordings" / "turntable.npz")
    events = concat(list(source), source.geometry)
    window_us = int(args.window_ms * 1000)
    for kind in REPRESENTATIONS:
        framer = build("framer", {"kind": kind, "window_us": window_us, **EXTRA.get(kind, {})})
        rep = middle(frames_of(framer, [events]))
        write_png(out / f"represent_{kind}.png", render_representation(rep))
        print(f"{out / f'represent_{kind}.png'}: {kind} {rep.data.shape}, window {rep.t_start}..{rep.t_end} µs, "
              f"{rep.n_events} events")
    pictures = []
    for name, stages in TRANSFORMS:
        pipe = Pipeline([build("stage", s) for s in stages])
        moved = pipe.process(events).events
        rep = middle(frames_of(build("framer", {"kind": "count", "window_us": window_us}), [moved]))
        pictures.append(render_representation(rep))
        print(f"transforms: {name}: {moved.geometry}, {len(moved):,} of {len(events):,} events")
    write_png(out / "transforms.png", mosaic([pictures[:4], pictures[4:]], background=255))
    print(f"{out / 'transforms.png'}: {', '.join(n for n, _ in TRANSFORMS)} (left to right, top to bottom)")


if __name__ == "__main__":
    main()
