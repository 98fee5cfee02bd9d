"""Shared measuring helpers: events per second (best of several runs), peak memory, the peer tool's
event layout, and `evstream` commands run as processes."""

from __future__ import annotations

import json
import random
import resource
import socket
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


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


def cpu_s(cases: dict[str, Callable[[], object]], rounds: int, shuffle: bool = False) -> dict[str, list[float]]:
    """Each case's CPU times over `rounds` interleaved rounds, after one warm-up run each (numba compiles).
    CPU time: on a shared machine, time spent preempted is not ours. `shuffle`: each round in its own
    order (seeded), so that no case always runs after the same other one (which leaves the caches and
    the allocator's free lists as it leaves them)."""
    times: dict[str, list[float]] = {name: [] for name in cases}
    for fn in cases.values():
        fn()
    order = list(cases.items())
    for r in range(rounds):
        if shuffle:
            random.Random(r).shuffle(order)
        for name, fn in order:
            t0 = time.process_time()
            fn()
            times[name].append(time.process_time() - t0)
    return times


def best_cpu_s(cases: dict[str, Callable[[], object]], rounds: int) -> dict[str, float]:
    """Each case's best CPU time over `rounds` interleaved rounds (`cpu_s`)."""
    return {name: min(t) for name, t in cpu_s(cases, rounds).items()}


def in_fresh_process(module: str, *args) -> object:
    """`python -m MODULE ARGS` in a fresh interpreter (a benchmark's cell), returning the JSON of its last line
    of output: each cell then starts from the same state (heap, free lists, caches, kernels loaded), whatever
    cells ran before it."""
    argv = [sys.executable, "-m", module, *map(str, args)]
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{' '.join(argv[2:])}: exit {done.returncode}: {done.stderr.strip()[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def tonic_events(stream) -> tuple[np.ndarray, tuple[int, int, int]]:
    """`stream` as tonic takes it: a structured x, y, t, p array, and its sensor size (width, height, 2)."""
    ev = np.empty(len(stream), np.dtype([("x", "<i8"), ("y", "<i8"), ("t", "<i8"), ("p", "<i8")]))
    ev["x"], ev["y"], ev["t"], ev["p"] = stream.x, stream.y, stream.t, stream.p
    return ev, (stream.geometry.width, stream.geometry.height, 2)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cli(*args: str, **kw) -> subprocess.Popen:
    """`evstream ARGS` as a process of this interpreter, its stdout and stderr piped as text."""
    return subprocess.Popen([sys.executable, "-m", "evstream.cli", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def wait_line(p: subprocess.Popen, stream: str, text: str, timeout_s: float = 60) -> None:
    """Read `p`'s `stream` ("stdout" or "stderr") until a line holds `text`."""
    deadline = time.monotonic() + timeout_s
    pipe = getattr(p, stream)
    while time.monotonic() < deadline:
        line = pipe.readline()
        if text in line:
            return
        if not line and p.poll() is not None:
            raise RuntimeError(f"process exited before {text!r}: {pipe.read()}")
    raise RuntimeError(f"no {text!r} within {timeout_s} s")
