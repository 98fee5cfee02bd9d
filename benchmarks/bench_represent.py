"""Representations (time surface, voxel grid, histogram, count, last timestamp) at 346x260 in 10 k-event
chunks, beside tonic's ToTimesurface / ToVoxelGrid / ToFrame in the same run when tonic is installed
(`pip install -e '.[bench]'`).

Stream: the synthetic turntable recording tiled to 10 s and time-compressed 20x (5 M events/s, ~50 k
events per 10 ms window: a busy DAVIS346), all events counted. Each window's array is dense (C, 260, 346)
float32, so a window costs a fixed ~0.36 MB per channel of memory traffic on top of its events.
tonic works on a whole recording (a structured array in memory), not a stream: it is given the same
events as one array, with the same 10 ms windows (tonic's time surface: `dt` 10 ms, the same τ).
Round robin, best of `rounds` each, in CPU time (process_time): the machine is shared, and wall time
counts the time other processes hold the core (a window's kernel measured 0.3 ms or 12 ms in one run).
"""

from __future__ import annotations

from evstream.pipeline import build
from evstream.testing import split

from .bench_framing import tiled
from .common import best_cpu_s, peak_alloc_bytes, report, tonic_events

WINDOW_US = 10_000
TAU_US = 20_000
BINS = 5
CHUNK = 10_000


def tonic_cases(stream):
    """tonic's transforms on the same events, or the reason they cannot run."""
    try:
        import tonic.transforms as T
    except Exception as e:  # not installed (a benchmark-only extra), or broken
        return {}, f"tonic not importable ({type(e).__name__}: {e}); pip install -e '.[bench]'"
    ev, size = tonic_events(stream)
    n_windows = int((stream.t[-1] - stream.t[0]) // WINDOW_US) + 1
    return {
        "timesurface": lambda: T.ToTimesurface(sensor_size=size, dt=WINDOW_US, tau=TAU_US)(ev),
        "voxel": lambda: T.ToVoxelGrid(sensor_size=size, n_time_bins=BINS * n_windows)(ev),
        "histogram": lambda: T.ToFrame(sensor_size=size, time_window=WINDOW_US)(ev),
    }, None


def run(rounds: int = 5) -> None:
    stream = tiled(10, 20)
    n = len(stream)
    chunks = split(stream, list(range(0, n, CHUNK)) + [n])
    cases = {}
    for kind, extra in (("timesurface", {"tau_us": TAU_US}), ("voxel", {"bins": BINS}), ("histogram", {}),
                        ("count", {}), ("timestamp", {})):
        for window, wp in (("fw", {"window_us": WINDOW_US}), ("fn", {"n_events": 50_000}),
                           ("adaptive", {"window_us": WINDOW_US, "n_base": 50_000})):
            spec = {"kind": kind, "window": window, **wp, **extra, "all_events": True}
            cases[f"{kind} {window}"] = lambda spec=spec: _feed(build("framer", spec), chunks)
    cases["fw frames (counts only, reference)"] = lambda: _feed(build("framer", {"kind": "fw", "window_us": WINDOW_US}),
                                                                chunks)
    peers, why_not = tonic_cases(stream)
    for name, fn in peers.items():
        cases[f"tonic {name} (whole recording)"] = fn
    best = best_cpu_s(cases, rounds)
    for name in cases:
        extra = {}
        kind = name.split()[0]
        peer = f"tonic {kind} (whole recording)"
        if peer in best and not name.startswith("tonic"):
            extra["vs_tonic"] = f"{best[peer] / best[name]:.1f}x faster"
        if not name.startswith("tonic"):
            extra["peak_MB"] = f"{peak_alloc_bytes(cases[name]) / 2**20:.1f}"
            extra["target_100M"] = "met" if n / best[name] >= 1e8 else "NOT met"
        report(f"{name}", n / best[name], **extra)
    if why_not:
        print(f"tonic skipped: {why_not}")


def _feed(framer, chunks) -> int:
    k = 0
    for c in chunks:
        k += len(framer.push(c))  # arrays dropped at once, as a sink that writes them would
    return k + len(framer.finish())


if __name__ == "__main__":
    run()
