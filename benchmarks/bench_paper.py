"""Throughput and state memory of the paper's cascade and of its two stages.

Stream: a synthetic scene (turntable at 346×260, bar at 1280×720) with 3 Hz/pixel background activity
and 0.1 % hot pixels at 500–2000 Hz; chunks of 10k and 100k events and one call. A control line
times the coarse stage on the same events evenly spaced in time.
"""

from __future__ import annotations

import numpy as np

from evstream.denoise.cascade import PaperCascade
from evstream.denoise.density import DensityFilter
from evstream.denoise.timeseries import TimeSeriesFilter
from evstream.events import Geometry
from evstream.noise import NoiseSpec, inject
from evstream.testing import state_nbytes

from .common import events_per_s, noisy_scene, peak_alloc_bytes, report


def run() -> None:
    cases = [("turntable", Geometry(346, 260), 1_000_000), ("bar", Geometry(1280, 720), 300_000)]
    for name, g, duration in cases:
        s = noisy_scene(name, g, duration)
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
        # Control: the same events at evenly spaced times, so that each arrival expires exactly one
        # event and the expiry loop's exit is always predicted. Its gap to the line above is what the
        # irregular expiry of real streams costs this CPU (docs/method.md, "Throughput").
        even = s.replace(t=np.linspace(int(s.t[0]), int(s.t[-1]), n).astype(np.int64))
        eps = events_per_s(lambda even=even: DensityFilter()(even), n, repeat=3)
        report("control: coarse, one call, evenly spaced times", eps)
    quality()


if __name__ == "__main__":
    run()


def quality() -> None:
    """Warm-state quality on the shipped synthetic recordings at 50 % and 200 % noise (the issue's
    targets: hot pixels >= 200 Hz 99 % removed, 50–200 Hz 90 %, signal 95 % kept, background 90 %
    removed at 50 %)."""
    from pathlib import Path

    from evstream.sources import open_source

    from evstream.events import NoiseClass, concat

    root = Path(__file__).resolve().parents[1] / "recordings"
    print("-- quality (warm state: after Δt + n/fs)")
    for name in ("turntable", "ball", "bar"):
        rec = concat(list(open_source(root / f"{name}.npz")))
        sig = rec[rec.label == NoiseClass.SIGNAL]
        for ratio in (0.5, 2.0):
            noisy = inject(sig, NoiseSpec(noise_ratio=ratio), seed=11, t_start_us=0, t_stop_us=int(rec.t[-1]) + 1)
            stage = PaperCascade()
            cls = stage(noisy).cls
            warm = noisy.t >= stage.history_us
            lab, cl = noisy.label[warm], cls[warm]
            hot = lab == NoiseClass.HOT_PIXEL
            pix = noisy.y[warm].astype(int) * noisy.geometry.width + noisy.x[warm]
            span_s = (int(noisy.t[-1]) - stage.history_us) * 1e-6
            ids, counts = np.unique(pix[hot], return_counts=True)
            rate = dict(zip(ids.tolist(), (counts / span_s).tolist()))
            r = np.array([rate.get(q, 0.0) for q in pix[hot]])
            removed = cl != NoiseClass.SIGNAL

            def frac(mask, removed=removed):
                return f"{100 * removed[mask].mean():5.1f}%" if mask.any() else "   - "

            fast = np.zeros(len(lab), bool)
            slow = np.zeros(len(lab), bool)
            fast[np.flatnonzero(hot)[r >= 200]] = True
            slow[np.flatnonzero(hot)[r < 200]] = True
            kept = 100 * (1 - removed[lab == NoiseClass.SIGNAL].mean())
            print(f"{name:<10} noise {round(100 * ratio):>3}%: signal kept {kept:5.1f}%  background removed "
                  f"{frac(lab == NoiseClass.BACKGROUND)}  hot >=200 Hz removed {frac(fast)}  "
                  f"50-200 Hz {frac(slow)}")
