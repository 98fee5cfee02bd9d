"""Shared measuring helpers: events per second (best of several runs) and peak memory."""

from __future__ import annotations

import resource
import time
import tracemalloc
from collections.abc import Callable


def events_per_s(fn: Callable[[], object], n_events: int, repeat: int = 5, warmup: int = 1) -> float:
    """Best-of-`repeat` throughput of `fn` over `n_events` (warm-up runs compile numba kernels)."""
    for _ in range(warmup):
        fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n_events / best


def peak_alloc_bytes(fn: Callable[[], object]) -> int:
    """Peak bytes allocated through Python and numpy while `fn` runs (tracemalloc)."""
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def noisy_scene(name: str, geometry, duration_us: int):
    """A synthetic scene with 3 Hz/pixel background activity and 0.1 % hot pixels at 500–2000 Hz."""
    from evstream.noise import NoiseSpec, inject
    from evstream.synth import scene

    sig = scene(name, geometry, duration_us=duration_us, seed=0)
    spec = NoiseSpec(ba_rate_hz=3.0, hot_pixels=max(1, geometry.n_pixels // 1000), hot_rate_hz=(500.0, 2000.0))
    return inject(sig, spec, seed=1, t_start_us=0, t_stop_us=duration_us)


def report(name: str, rate_hz: float, **extra) -> None:
    more = "  ".join(f"{k}={v}" for k, v in extra.items())
    print(f"{name:<48} {rate_hz / 1e6:9.1f} M events/s  {more}", flush=True)
