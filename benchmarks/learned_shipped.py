"""The shipped learned model on the real recordings, as docs/learned.md's shipped-model tables report it.

Two tables for one or more model files (default: the shipped one), beside the paper's cascade:

- `as-is`: the fraction of each real recording's events kept (no noise injected, so no truth: the
  cascade is the yardstick), and whether the recording is in the model's training data;
- `noise`: labelled noise injected into the real recordings the model was not trained on (their hot
  pixels set aside; seed 0; events after the first 50 ms, or 30 % of a shorter one): mean EDP at
  >= 80 % signal kept, AUC, and at the default operating point (asked 85 %) the signal kept and the
  noise removed.

    python -m benchmarks.learned_shipped
    python -m benchmarks.learned_shipped out/candidate.npz    # the shipped model beside a candidate
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
from pathlib import Path

import numpy as np

from evstream import evaluation, metrics
from evstream.cli.evaluate import read_recordings
from evstream.denoise.learned import LearnedFilter, load
from evstream.events import NoiseClass
from evstream.noise import NoiseSpec, as_signal, inject

from .common import ROOT

REAL = Path(os.environ.get("EVSTREAM_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
SKIP_US = 50_000
NOISE = {"100%": NoiseSpec(noise_ratio=1.0), "200%": NoiseSpec(noise_ratio=2.0), "5Hz": NoiseSpec(ba_rate_hz=5.0)}


def real_recordings() -> dict:
    paths = sorted(str(p) for p in REAL.iterdir() if p.is_file() and p.suffix != ".md")
    with contextlib.redirect_stderr(io.StringIO()):
        return read_recordings(paths, 0.0, "learned_shipped")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="*", help="model files beside the shipped one")
    a = ap.parse_args()
    models = {"shipped": load(None), **{Path(m).stem: load(m) for m in a.models}}
    recs = real_recordings()
    trained = {m: {e["recording"] for e in model.meta.get("trained_on", [])} for m, model in models.items()}
    methods = {"paper": lambda: evaluation.METHODS["paper"](),
               **{m: (lambda model=model: LearnedFilter(model=model)) for m, model in models.items()}}
    print("kept % of each real recording as it is (no noise injected); * = in that model's training data")
    print(f"{'recording':<40}" + "".join(f"{m[:14]:>16}" for m in methods))
    unseen = []
    for name, ev in recs.items():
        bare = ev.replace(label=None, cls=None)
        cells = []
        for m, make in methods.items():
            kept = (make()(bare).cls == NoiseClass.SIGNAL).mean()
            cells.append(f"{100 * kept:15.1f}{'*' if name in trained.get(m, ()) else ' '}")
        print(f"{name[:40]:<40}" + "".join(cells), flush=True)
        if not any(name in t for t in trained.values()):
            unseen.append(name)
    print(f"\nlabelled noise on the {len(unseen)} recordings no model was trained on (seed 0, after "
          f"{SKIP_US // 1000} ms), mean: EDP@80 / AUC / signal kept % at the default point / noise removed %")
    for cond, spec in NOISE.items():
        rows = {m: [] for m in methods}
        for name in unseen:
            sig = as_signal(recs[name])[0]
            noisy = inject(sig, spec, seed=0, t_start_us=int(sig.t[0]), t_stop_us=int(sig.t[-1]) + 1)
            t0, t1 = int(noisy.t[0]), int(noisy.t[-1])
            late = noisy.t >= t0 + min(SKIP_US, int(evaluation.WARMUP_CAP * (t1 - t0)))
            for m, make in methods.items():
                codes, score = make().classify_scored(noisy.replace(label=None))
                lab, sc, kept = noisy.label[late], score[late], codes[late] == NoiseClass.SIGNAL
                is_sig = lab == NoiseClass.SIGNAL
                rows[m].append((metrics.edp_at_tpr(lab, sc, 0.8), metrics.roc_auc(lab, sc),
                                kept[is_sig].mean(), 1 - kept[~is_sig].mean()))
        means = {m: np.mean(v, axis=0) for m, v in rows.items()}
        print(f"{cond:<6}" + "".join(f"  {m}: {e:.1f} / {a:.3f} / {100 * k:.1f} / {100 * r:.1f}"
                                    for m, (e, a, k, r) in means.items()), flush=True)


if __name__ == "__main__":
    main()
