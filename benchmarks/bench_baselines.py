"""Throughput, state memory and quality of the baseline denoisers.

Stream (same as bench_paper): a synthetic scene (turntable at 346×260 for 1 s, bar at 1280×720 for
0.3 s) with 3 Hz/pixel background activity and 0.1 % hot pixels at 500–2000 Hz. Each filter with its
default parameters: the bare kernel over the whole stream (`classify`), the stage as a pipeline runs
it (50k-event chunks), and the scored pass (`classify_scored`); then its state size and its quality at
the default operating point (TPR, EDP) and over all thresholds (AUC of the one-pass scores).
`classify` and the stage run the class-only compiled variants (no score computed); the scored pass
the variants with the score. The BAF stage beside a plain numba BAF and dv-processing's C++ filters,
same events, same run: `python -m benchmarks paper` (bench_paper.py).
"""

from __future__ import annotations

import numpy as np

from evstream import metrics
from evstream.denoise.baf import BackgroundActivityFilter
from evstream.denoise.dwf import DoubleWindowFilter
from evstream.denoise.hotpixel import HotPixelLearner
from evstream.denoise.khodamoradi import KhodamoradiFilter
from evstream.denoise.refractory import RefractoryFilter
from evstream.denoise.stcf import SpatioTemporalCorrelationFilter
from evstream.denoise.ynoise import YNoiseFilter
from evstream.events import Geometry, NoiseClass
from evstream.testing import state_nbytes

from .common import events_per_s, noisy_scene, report

FILTERS = [("baf", BackgroundActivityFilter), ("stcf", SpatioTemporalCorrelationFilter),
           ("khodamoradi", KhodamoradiFilter), ("ynoise", YNoiseFilter), ("dwf", DoubleWindowFilter),
           ("refractory", RefractoryFilter),
           # the default 1 s learning window would leave no warm events in these short streams
           ("hotpixel (100 ms window)", lambda: HotPixelLearner(window_us=100_000))]
CHUNK = 50_000




def run() -> None:
    cases = [("turntable", Geometry(346, 260), 1_000_000), ("bar", Geometry(1280, 720), 300_000)]
    for scene_name, g, duration in cases:
        s = noisy_scene(scene_name, g, duration)
        n = len(s)
        counts = s.class_counts("label")
        print(f"-- {scene_name} {g}: {n:,} events ({counts[0]:,} signal, {counts[1]:,} background, "
              f"{counts[2]:,} hot), {n / (duration * 1e-6) / 1e6:.2f} M events/s of sensor time")
        for name, make in FILTERS:
            def kernel(make=make, s=s):
                return make().classify(s)

            def staged(make=make, s=s, n=n):
                stage = make()
                for a in range(0, n, CHUNK):
                    stage(s[a : a + CHUNK])
                return stage

            def scored(make=make, s=s):
                return make().classify_scored(s)

            report(f"{name}: kernel, one call", events_per_s(kernel, n, repeat=5))
            report(f"{name}: stage, {CHUNK // 1000}k chunks", events_per_s(staged, n, repeat=5))
            codes, score = scored()
            warm = s.t >= (200_000 if name.startswith("hotpixel") else 50_000)  # skip the history window
            lab = s.label[warm]
            keep = codes[warm] == NoiseClass.SIGNAL
            rm = metrics.removal_rates(lab, keep)
            report(f"{name}: scored pass", events_per_s(scored, n, repeat=5),
                   state_B_per_px=f"{state_nbytes(staged()) / g.n_pixels:.1f}",
                   TPR=f"{metrics.tpr(lab, keep):.3f}", EDP=f"{metrics.edp(lab, keep):.1f}",
                   removed_BA=f"{rm['background']:.3f}", removed_hot=f"{rm['hot_pixel']:.3f}",
                   AUC=f"{metrics.roc_auc(lab, score[warm]):.3f}",
                   EDP_at_TPR90=f"{metrics.edp_at_tpr(lab, score[warm], 0.9):.1f}")
        raw = np.ones(n, bool)
        print(f"   (no filter: EDP {metrics.edp(s.label, raw):.1f})")


if __name__ == "__main__":
    run()
