"""Throughput and state memory of the paper's cascade and of its two stages.

Stream: a synthetic scene (turntable at 346×260, bar at 1280×720) with 3 Hz/pixel background activity
and 0.1 % hot pixels at 500–2000 Hz; chunks of 10k and 100k events and one call.
"""

from __future__ import annotations

from evstream.denoise.cascade import PaperCascade
from evstream.denoise.density import DensityFilter
from evstream.denoise.timeseries import TimeSeriesFilter
from evstream.events import Geometry
from evstream.noise import NoiseSpec, inject
from evstream.synth import scene
from evstream.testing import state_nbytes

from .common import events_per_s, peak_alloc_bytes, report


def stream(name: str, g: Geometry, duration_us: int):
    sig = scene(name, g, duration_us=duration_us, seed=0)
    spec = NoiseSpec(ba_rate_hz=3.0, hot_pixels=max(1, g.n_pixels // 1000), hot_rate_hz=(500.0, 2000.0))
    return inject(sig, spec, seed=1, t_start_us=0, t_stop_us=duration_us)


def run() -> None:
    cases = [("turntable", Geometry(346, 260), 1_000_000), ("bar", Geometry(1280, 720), 300_000)]
    for name, g, duration in cases:
        s = stream(name, g, duration)
        n = len(s)
        rate = n / (duration * 1e-6)
        print(f"-- {name} {g}: {n:,} events, {rate / 1e6:.2f} M events/s of sensor time")
        for label, make in [("coarse (density, relative)", DensityFilter),
                            ("coarse (density, absolute)", lambda: DensityFilter(mode="absolute")),
                            ("fine (DC) alone", TimeSeriesFilter),
                            ("cascade (paper)", PaperCascade)]:
            for chunk in (10_000, 100_000, None):
                def go(make=make, chunk=chunk, s=s):
                    stage = make()
                    step = chunk or len(s)
                    for a in range(0, len(s), step):
                        stage(s[a : a + step])
                    return stage

                eps = events_per_s(go, n, repeat=3)
                report(f"{label}, chunks {chunk or 'all'}", eps)
            stage = go()
            report(f"{label} state", eps, state_bytes_per_pixel=f"{state_nbytes(stage) / g.n_pixels:.1f}",
                   peak_alloc_MB=f"{peak_alloc_bytes(go) / 1e6:.1f}")


if __name__ == "__main__":
    run()
