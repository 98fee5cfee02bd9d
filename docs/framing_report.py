"""Regenerate the tables and pictures of docs/framing.md: `python docs/framing_report.py [REAL_DIR]`.

For each recording: FW, FN, OA and the adaptive framer with the parameters printed, the paper's frame
statistics (Tables 5–6), frame rates over the first and last quarter of the recording, and a PNG strip
of frames (rows FW, FN, OA, adaptive; columns at evenly spaced times) in docs/.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from evstream.sources import open_source

from evstream.denoise.oracle import TruthStage
from evstream.events import concat
from evstream.framing import AdaptiveOverlap, FixedCount, FixedWindow, OverlapAccumulation
from evstream.framing.render import mosaic, paper, write_png
from evstream.framing.stats import frame_stats
from evstream.testing import split

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
WINDOW_US = 10_000
COLUMNS = 6

SYNTHETIC = [("turntable", ROOT / "recordings" / "turntable.npz"), ("ball", ROOT / "recordings" / "ball.npz")]
REAL = ["davis346_frames_imu_evlib.aedat4", "dvxplorer_320x240_tonic.aedat4", "prophesee_gen3_vga_evt2_faery.raw",
        "dvs128_lifetime_garfield.mat", "dvsgesture_slayer_1.bs2", "prophesee_gen41_hd_evt3_expelliarmus.raw"]


def framers(mean_per_window: int, geometry) -> dict:
    n = max(1, mean_per_window)
    out = {
        "FW": lambda: FixedWindow(window_us=WINDOW_US),
        "FN": lambda: FixedCount(n_events=n, max_window_us=None),
        "OA": lambda: OverlapAccumulation(window_us=WINDOW_US, stride_us=WINDOW_US // 2),
        "adaptive": lambda: AdaptiveOverlap(window_us=WINDOW_US, n_base=n),
    }
    if (geometry.width, geometry.height) == (346, 260):
        out["adaptive, N_base 8000"] = lambda: AdaptiveOverlap(window_us=WINDOW_US)
    return out


def run_framer(make, chunks):
    """Frames closed by their own rule (counted) and every frame (for pictures)."""
    f = make()
    counted = []
    for c in chunks:
        counted.extend(f.push(c))
    return counted, counted + f.finish(), f


def quarter_rates(frames, t0, t1):
    q = (t1 - t0) / 4
    ends = np.array([fr.t_end for fr in frames])
    return [np.count_nonzero((ends > a) & (ends <= a + q)) / (q * 1e-6) for a in (t0, t1 - q)]


def report(name: str, path: Path, denoise: bool) -> str:
    source = open_source(path)
    stream = concat(list(source))
    if denoise:
        stream = TruthStage()(stream)
    signal = stream if stream.cls is None else stream[stream.cls == 0]
    t0, t1 = int(stream.t[0]), int(stream.t[-1])
    duration_us = t1 - t0
    if duration_us < 4 * WINDOW_US:
        raise ValueError(f"{duration_us / 1e3:.1f} ms of events: shorter than four {WINDOW_US // 1000} ms frames")
    mean_per_window = round(len(signal) * WINDOW_US / max(duration_us, 1))
    chunks = split(stream, list(range(0, len(stream), 50_000)) + [len(stream)])
    lines = [f"### {name}", "",
             f"`{path.name}`: {stream.geometry}, {len(stream):,} events over {duration_us / 1e3:.1f} ms"
             + (f", {len(signal):,} of them signal (ground truth)" if denoise else ", all events framed")
             + f"; {mean_per_window:,} framed events per 10 ms on average (FN's N and the adaptive N_base).", "",
             "| method | parameters | frame rate (fps) | mean events | variance | fps first ¼ | fps last ¼ |",
             "|---|---|---:|---:|---:|---:|---:|"]
    rows = []
    for label, make in framers(mean_per_window, stream.geometry).items():
        counted, every, f = run_framer(make, chunks)
        s = frame_stats(counted, duration_us)
        first, last = quarter_rates(counted, t0, t1)
        params = ", ".join(f"{k} {v}" for k, v in f.params().items()
                           if k not in ("all_events", "max_empty_frames", "overlap_init_us") and v is not None)
        lines.append(f"| {label} | {params} | {s.frame_rate_hz:.1f} | {s.mean_events:,.1f} | "
                     f"{s.variance_events:,.0f} | {first:.0f} | {last:.0f} |")
        if not label.startswith("adaptive,"):
            rows.append(every)
    # the strip: for each method, the frame whose middle is nearest each of COLUMNS evenly spaced times
    times = np.linspace(t0, t1, COLUMNS + 2)[1:-1]
    strip = []
    for every in rows:
        mids = np.array([(fr.t_start + fr.t_end) / 2 for fr in every])
        strip.append([paper(every[int(np.argmin(np.abs(mids - t)))]) for t in times])
    png = DOCS / f"framing_{name}.png"
    write_png(png, mosaic(strip, gap=4, background=255))
    lines += ["", f"![FW, FN, OA and adaptive frames of {name}]({png.name})", ""]
    return "\n".join(lines)


def main(real_dir: str | None = None) -> None:
    parts = [report(name, path, denoise=True) for name, path in SYNTHETIC]
    real = Path(real_dir) if real_dir else ROOT.parent / "shared" / "data" / "real"
    for fname in REAL:
        path = real / fname
        if not path.exists():
            print(f"skipped {fname}: not present", file=sys.stderr)
            continue
        try:
            parts.append(report(Path(fname).stem, path, denoise=False))
        except Exception as e:  # a reader not landed yet, or a recording shorter than a frame
            print(f"skipped {fname}: {type(e).__name__}: {e}", file=sys.stderr)
    print("\n".join(parts))


if __name__ == "__main__":
    main(*sys.argv[1:])
