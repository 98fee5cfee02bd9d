"""`evstream synth`: seconds of CPU per second of scene, the compiled steps against the numpy reference.

Each scene is simulated with the compiled steps (`scene()`, what `evstream synth` runs) and with
`compiled=False` (numpy samples the field at every step, as synth did before: a hypot, an arctan2, a sin,
two tanh and a log per pixel of the region, 10,000 times a second of scene), interleaved in one process,
best of a few rounds; the events must be the same. Where the time goes in the reference: the field's
transcendental functions over the region (~80 %), the crossings (~10 %), numpy's per-call overhead.
"""

from __future__ import annotations

import time

import numpy as np

from evstream import synth


def _timed(name, duration_us, compiled):
    t0 = time.process_time()
    out = synth.scene(name, duration_us=duration_us, seed=1, compiled=compiled)
    return time.process_time() - t0, out


def run(duration_us: int = 1_000_000, rounds: int = 2) -> None:
    for name in sorted(synth.SCENES):
        synth.scene(name, duration_us=1_000, seed=1)  # compile (or load) the kernels
        synth.scene(name, duration_us=1_000, seed=1, compiled=False)
        best = {"compiled": float("inf"), "reference": float("inf")}
        for _ in range(rounds):
            tc, fast = _timed(name, duration_us, True)
            tr, ref = _timed(name, duration_us, False)
            best["compiled"], best["reference"] = min(best["compiled"], tc), min(best["reference"], tr)
        same = len(fast) == len(ref) and all(np.array_equal(getattr(fast, a), getattr(ref, a)) for a in "txyp")
        scene_s = duration_us * 1e-6
        print(f"synth {name:<10} {len(fast):>8,} events  compiled {best['compiled'] / scene_s:6.2f} s CPU per s of "
              f"scene  reference {best['reference'] / scene_s:6.2f}  x{best['reference'] / best['compiled']:.1f}  "
              f"same events: {same}", flush=True)


if __name__ == "__main__":
    run()
