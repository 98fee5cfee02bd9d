"""The paper's cascade of this tree against the same cascade at an earlier git revision, with
dv-processing's BackgroundActivityNoiseFilter beside both, interleaved in one process.

On a shared machine absolute numbers move with the load; the ratios of cases measured round by round
in one process move much less. The earlier revision's `evstream` package is exported with `git archive`
into a temporary folder under another name (its numba kernels compile there on first use), its
classes are checked to be identical to this tree's, and each case keeps its best CPU time.

    EVSTREAM_AB_REV=ee5e3fe python -m benchmarks cascade_ab   # default revision: ee5e3fe (session 8 start)

Last, the CPU time of one call on a 1-event chunk (the cost of a call beyond its events) of both.
"""

from __future__ import annotations

import importlib
import io
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from evstream.denoise.cascade import PaperCascade
from evstream.events import Geometry

from .bench_paper import dv_store, pieces
from .common import ROOT, noisy_scene

REV = os.environ.get("EVSTREAM_AB_REV", "ee5e3fe")
ROUNDS = int(os.environ.get("EVSTREAM_BENCH_ROUNDS", "5"))


def package_at(rev: str, into: Path):
    """`evstream` as of `rev`, importable as `evstream_at_rev`, or the reason it cannot be had."""
    try:
        tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "evstream"], capture_output=True,
                             check=True).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        return None, f"git archive {rev} failed ({getattr(e, 'stderr', b'').decode().strip() or e})"
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(into, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
    (into / "evstream").rename(into / "evstream_at_rev")
    for f in (into / "evstream_at_rev").rglob("*.py"):
        f.write_text(re.sub(r"\b(from|import) evstream\b", r"\1 evstream_at_rev", f.read_text()))
    sys.path.insert(0, str(into))
    return importlib.import_module("evstream_at_rev"), ""


def run() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        old, why = package_at(REV, Path(tmp))
        if old is None:
            print(f"   (skipped: {why})")
            return
        old_cascade = importlib.import_module("evstream_at_rev.denoise.cascade").PaperCascade
        old_events = importlib.import_module("evstream_at_rev.events")
        for name, g, duration in [("turntable", Geometry(346, 260), 1_000_000), ("bar", Geometry(1280, 720), 300_000)]:
            compare(name, g, duration, old_cascade, old_events)
        per_call(old_cascade, old_events)


def per_call(old_cascade, old_events, calls: int = 10_000) -> None:
    """CPU µs of one cascade call on a 1-event chunk, warm, both revisions interleaved."""
    g = Geometry(346, 260)
    warm = noisy_scene("turntable", g, 20_000)
    warm_old = old_events.EventChunk.from_arrays(warm.t, warm.x, warm.y, warm.p, old_events.Geometry(346, 260))
    cases = {}
    for tag, make, w in ((f"cascade at {REV}", old_cascade, warm_old), ("cascade, this tree", PaperCascade, warm)):
        f = make()
        f(w)
        cases[tag] = (f, w[len(w) - 1 :])
    best = dict.fromkeys(cases, float("inf"))
    for _ in range(max(3, ROUNDS)):
        for k, (f, one) in cases.items():
            t0 = time.process_time()
            for _ in range(calls):
                f(one)
            best[k] = min(best[k], (time.process_time() - t0) / calls)
    print(f"-- per call, 1-event chunks, 346x260 (CPU, best of {max(3, ROUNDS)} interleaved rounds)")
    for k, sec in best.items():
        print(f"{k:<40} {sec * 1e6:7.2f} µs per call", flush=True)


def compare(name: str, g: Geometry, duration: int, old_cascade, old_events) -> None:
    s = noisy_scene(name, g, duration)
    so = old_events.EventChunk.from_arrays(s.t, s.x, s.y, s.p, old_events.Geometry(g.width, g.height))
    store, why = dv_store(s)
    cases = {}
    for chunk in (10_000, 100_000, None):
        label = f"{chunk // 1000}k" if chunk else "one call"
        bounds = pieces(len(s), chunk)
        for tag, make, parts in ((f"cascade at {REV}", old_cascade, [so[a:b] for a, b in bounds]),
                                 ("cascade, this tree", PaperCascade, [s[a:b] for a, b in bounds])):
            def go(make=make, parts=parts):
                f = make()
                return np.concatenate([f(p).cls for p in parts])
            cases[f"{tag}, {label}"] = go
        if store is not None:
            import dv_processing as dv

            slices = [store.slice(a, b - a) for a, b in bounds]

            def peer(slices=slices):
                f = dv.noise.BackgroundActivityNoiseFilter((g.width, g.height))
                for p in slices:
                    f.accept(p)
                    f.generateEvents()
            cases[f"dv BAF, {label}"] = peer
    first = {k: fn() for k, fn in cases.items()}  # warm-up (numba compiles), and the classes to compare
    for k in first:
        if k.startswith("cascade at"):
            other = k.replace(f"cascade at {REV}", "cascade, this tree")
            assert np.array_equal(first[k], first[other]), f"classes differ: {k}"
    best = dict.fromkeys(cases, float("inf"))
    for _ in range(ROUNDS):
        for k, fn in cases.items():
            t0 = time.process_time()
            fn()
            best[k] = min(best[k], time.process_time() - t0)
    print(f"-- {name} {g}: {len(s):,} events, best CPU time of {ROUNDS} interleaved rounds, load "
          f"{os.getloadavg()[0]:.1f}; classes identical" + ("" if store is not None else f" (dv skipped: {why})"))
    for k, sec in best.items():
        label = k.split(", ")[-1]
        dv_s = best.get(f"dv BAF, {label}")
        extra = f"  vs_dv_BAF={dv_s / sec:.2f}x" if dv_s and not k.startswith("dv") else ""
        print(f"{k:<40} {len(s) / sec / 1e6:7.1f} M events/s  {1e9 * sec / len(s):6.2f} ns/event{extra}", flush=True)


if __name__ == "__main__":
    run()
