"""`evstream synth`: CPU and wall seconds per second of scene, today's against synth as it was before it
was made faster (commit f1e3e64: numpy sampled the field over the scene's region at every 100 µs step).

The shipped recordings' scenes, seeds and durations (`make recordings`), simulated by both in one process,
interleaved (new, old, new, old, ...), best of `rounds`; the events must be the same. CPU time
(process_time) is what a scene costs; wall time is what the user waits, and on a shared machine it also
counts the time other processes held the core. The old code is read from git (`git show`): without the
repository's history the table has today's numbers only.

Where the time went before: the field's transcendental functions (hypot, arctan2, sin, two tanh, a log)
over every pixel of the region at every step. Today a pixel is only looked at when the scene has moved
enough that it could cross a threshold (see evstream/synth.py).

    .venv/bin/python -m benchmarks synth
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from evstream import synth

from .common import ROOT

BASELINE = "f1e3e64bab33fe7dced367ff05f3fa008baac881"  # the parent of 4e4cec8, the first faster synth
SHIPPED = (("turntable", 1, 1_000_000), ("ball", 2, 1_000_000), ("bar", 3, 500_000))  # as `make recordings`


def baseline_module():
    """synth.py as of BASELINE, imported beside today's (the same evstream.events), or None."""
    try:
        source = subprocess.run(["git", "-C", str(ROOT), "show", f"{BASELINE}:evstream/synth.py"],
                                capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    path = Path(tempfile.mkdtemp(prefix="evstream-synth-baseline-")) / "synth_baseline.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("evstream._synth_baseline", path)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "evstream"
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _timed(module, name, seed, duration_us):
    c0, w0 = time.process_time(), time.perf_counter()
    events = module.scene(name, duration_us=duration_us, seed=seed)
    return time.process_time() - c0, time.perf_counter() - w0, events


def run(rounds: int = 3) -> None:
    old = baseline_module()
    if old is None:
        print(f"(no git history: the old synth, {BASELINE[:7]}, is not measured)")
    print(f"{'scene':<10} {'events':>9}  {'CPU s per s of scene':>26}  {'wall s per s of scene':>26}  same events")
    print(f"{'':<10} {'':>9}  {'before':>8} {'now':>8} {'x':>8}  {'before':>8} {'now':>8} {'x':>8}")
    for name, seed, duration_us in SHIPPED:
        modules = {"now": synth} if old is None else {"now": synth, "before": old}
        for module in modules.values():
            module.scene(name, duration_us=2_000, seed=seed)  # compile (or load) the kernels
        cpu, wall, events = {}, {}, {}
        for _ in range(rounds):
            for key, module in modules.items():
                c, w, events[key] = _timed(module, name, seed, duration_us)
                cpu[key], wall[key] = min(cpu.get(key, np.inf), c), min(wall.get(key, np.inf), w)
        scene_s = duration_us * 1e-6
        now = events["now"]
        if old is None:
            print(f"{name:<10} {len(now):>9,}  {'':>8} {cpu['now'] / scene_s:8.3f} {'':>8}  "
                  f"{'':>8} {wall['now'] / scene_s:8.3f}", flush=True)
            continue
        before = events["before"]
        same = len(now) == len(before) and all(np.array_equal(getattr(now, a), getattr(before, a)) for a in "txyp")
        print(f"{name:<10} {len(now):>9,}  {cpu['before'] / scene_s:8.3f} {cpu['now'] / scene_s:8.3f} "
              f"{cpu['before'] / cpu['now']:8.1f}  {wall['before'] / scene_s:8.3f} {wall['now'] / scene_s:8.3f} "
              f"{wall['before'] / wall['now']:8.1f}  {same}", flush=True)


if __name__ == "__main__":
    run()
