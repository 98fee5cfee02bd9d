"""Transforms (crop, flip, rotate, transpose, downsample, polarity, time range, rate limit, undistort) at
346x260 in 10 k-event chunks, beside tonic's CenterCrop / RandomFlipLR(p=1) / Downsample / CropTime on the
same events (a whole-recording structured array, as tonic works) when tonic is installed.

Stream: the turntable recording tiled to 10 s and time-compressed 20x (5 M events/s). Each case runs the
stage over every chunk and keeps the output (as the next stage would). Round robin, best of `rounds`
each, in CPU time (process_time): the machine is shared, and wall time counts the time other processes
hold the core.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from evstream.sources import native, open_source, prophesee_raw

from evstream.pipeline import build
from evstream.testing import split
from evstream.transforms import TimeRangeSource

from .bench_framing import tiled
from .common import best_cpu_s, report, tonic_events

CHUNK = 10_000


def stage_cases(stream):
    g = stream.geometry
    t0, t1 = int(stream.t[0]), int(stream.t[-1])
    specs = {
        "crop 200x150": {"kind": "crop", "x0": 73, "y0": 55, "width": 200, "height": 150},
        "flip x": {"kind": "flip", "axis": "x"},
        "rotate 90": {"kind": "rotate", "degrees": 90},
        "transpose": {"kind": "transpose"},
        "downsample 2": {"kind": "downsample", "factor": 2},
        "polarity on": {"kind": "polarity", "keep": "on"},
        "time_range middle half": {"kind": "time_range", "start_us": t0 + (t1 - t0) // 4,
                                   "end_us": t1 - (t1 - t0) // 4},
        "rate_limit 2 M ev/s": {"kind": "rate_limit", "rate_hz": 2e6},
        "undistort plumb_bob": {"kind": "undistort", "fx": 300.0, "fy": 300.0, "cx": g.width / 2,
                                "cy": g.height / 2, "distortion": [-0.3, 0.1, 0.001, -0.001, 0.0]},
    }
    return specs


def tonic_cases(stream):
    try:
        import tonic.transforms as T
    except Exception as e:
        return {}, f"tonic not importable ({type(e).__name__}: {e}); pip install -e '.[bench]'"
    ev, size = tonic_events(stream)
    t0, t1 = int(stream.t[0]), int(stream.t[-1])
    return {
        "crop 200x150": lambda: T.CenterCrop(sensor_size=size, size=(200, 150))(ev),
        "flip x": lambda: T.RandomFlipLR(sensor_size=size, p=1.0)(ev),
        "downsample 2": lambda: T.Downsample(spatial_factor=0.5)(ev),
        "time_range middle half": lambda: T.CropTime(min=t0 + (t1 - t0) // 4, max=t1 - (t1 - t0) // 4)(ev),
    }, None


def run(rounds: int = 5) -> None:
    stream = tiled(10, 20)
    n = len(stream)
    chunks = split(stream, list(range(0, n, CHUNK)) + [n])
    cases = {}
    for name, spec in stage_cases(stream).items():
        try:
            build("stage", spec)
        except ValueError as e:  # a stage this checkout does not have yet
            print(f"{name}: skipped ({e})")
            continue
        if spec["kind"] == "rate_limit":  # its bucket carries state: a fresh one per run
            cases[name] = lambda spec=spec: [st(c) for st in [build("stage", spec)] for c in chunks]
        else:  # stateless per event: one instance (undistort's table is made once, at its first chunk)
            stage = build("stage", spec)
            cases[name] = lambda stage=stage: [stage(c) for c in chunks]
    peers, why_not = tonic_cases(stream)
    for name, fn in peers.items():
        cases[f"tonic {name} (whole recording)"] = fn
    best = best_cpu_s(cases, rounds)
    for name in cases:
        peer = f"tonic {name} (whole recording)"
        extra = {"vs_tonic": f"{best[peer] / best[name]:.1f}x faster"} if peer in best else {}
        if not name.startswith("tonic"):
            extra["target_100M"] = "met" if n / best[name] >= 1e8 else "NOT met"
        report(name, n / best[name], **extra)
    spec = stage_cases(stream)["undistort plumb_bob"]
    t0 = time.process_time()
    build("stage", spec)(chunks[0])
    print(f"undistort: its lookup table for {stream.geometry} takes {1e3 * (time.process_time() - t0):.0f} ms "
          "of CPU, once per stream")
    if why_not:
        print(f"tonic skipped: {why_not}")
    seek_table()


class _NoSeek:
    """A source without `set_time_range`: what `--start-us` did before readers seeked (decode, then drop)."""

    def __init__(self, source):
        self.source = source
        self.geometry = source.geometry

    def __iter__(self):
        return iter(self.source)


def seek_table(rounds: int = 3) -> None:
    """`--start-us` at 90 % of a 40 s recording (the turntable tiled, ~10 M events, 2 EVT3 clock wraps):
    reading the last 10 % by seeking against decoding everything and dropping, CPU time, best of
    `rounds` round robin."""
    stream = tiled(40, 1)
    t0, t1 = int(stream.t[0]), int(stream.t[-1])
    start = t0 + (t1 - t0) * 9 // 10
    with tempfile.TemporaryDirectory() as folder:
        files = {}
        for version in ("evt3", "evt2"):
            files[f"RAW {version.upper()}"] = Path(folder) / f"r_{version}.raw"
            prophesee_raw.save(files[f"RAW {version.upper()}"], stream, version=version)
        files[".npy"] = Path(folder) / "r.npy"
        np.save(files[".npy"], stream.to_structured())
        files["native .npz"] = Path(folder) / "r.npz"  # deflated, with its seek index (native.save)
        native.save(files["native .npz"], stream)

        def read(path, seek):
            source = open_source(path, geometry=stream.geometry)  # a .npy has none: it would be fitted to every event
            n = 0
            for c in TimeRangeSource(source if seek else _NoSeek(source), start, None):
                n += len(c)
            return n

        cases = {f"{name} {how}": (lambda p=p, seek=seek: read(p, seek))
                 for name, p in files.items() for how, seek in (("seek", True), ("decode+drop", False))}
        best = best_cpu_s(cases, rounds)
        kept = int(np.count_nonzero(stream.t >= start))
        print(f"--start-us at 90 % of {len(stream):,} events over {(t1 - t0) / 1e6:.0f} s ({kept:,} kept), "
              "CPU ms:")
        for name in files:
            a, b = best[f"{name} seek"], best[f"{name} decode+drop"]
            print(f"  {name:<12} seek {1e3 * a:8.1f}   decode+drop {1e3 * b:8.1f}   {b / a:5.1f}x faster")


if __name__ == "__main__":
    run()
