"""Leave-one-recording-out on the learned denoiser's feature rows: which features pay, and how well the
calibrated threshold holds the asked signal-kept fraction on a recording the model never saw.

The recordings are recordings/*.npz and the real ones (EVSTREAM_REAL_DATA, default ../shared/data/real).
Their labelled feature rows (`train.samples`, as `evstream eval` draws them for its leave-one-out models)
are computed once and cached under out/ (keyed by the feature version). For each recording R a model is
fitted on the others' rows and scored on R's rows (warm events; no hot-pixel rules):

- `ablate`: mean EDP at >= 80 % signal kept / AUC per condition with each feature group left out
  (zeroed, as `train --without` does);
- `calib`: the signal kept on R at the threshold calibrated for `--keep` (0.85), per recording, and the
  spread over recordings, for the calibration variants (train.fit's own, and with thinned copies).

    python -m benchmarks.learned_loo ablate
    python -m benchmarks.learned_loo calib
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import time
from pathlib import Path

import numpy as np

from evstream import evaluation, metrics
from evstream.cli.evaluate import read_recordings
from evstream.denoise.learned import train
from evstream.denoise.learned.features import FEATURE_VERSION, FEATURES

from .common import ROOT

REAL = Path(os.environ.get("EVSTREAM_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
COND_NAMES = [c.name for c in train.TRAIN_CONDITIONS]
ABLATIONS = {  # name: features zeroed (the shipped model leaves the DC components out of its score)
    "the shipped set (9)": ["dc_own", "dc_nb8"],
    "without the block reference": ["dc_own", "dc_nb8", "log_ref_block"],
    "without the global reference": ["dc_own", "dc_nb8", "log_ref_global"],
    "without the age": ["dc_own", "dc_nb8", "log1p_age_ms"],
    "without the own 20 ms count": ["dc_own", "dc_nb8", "log1p_own_20ms"],
    "all 11": [],
}


def load_samples(thin: tuple[float, ...] = ()) -> train.Samples:
    paths = sorted(str(p) for p in (ROOT / "recordings").glob("*.npz"))
    if REAL.is_dir():
        paths += sorted(str(p) for p in REAL.iterdir() if p.is_file() and p.suffix != ".md")
    with contextlib.redirect_stderr(io.StringIO()):
        recs = read_recordings(paths, 0.25, "learned_loo")
    recs = {n: ev for n, ev in recs.items() if len(evaluation.as_signal(ev)[0]) >= 100}
    tag = "_thin" + "_".join(f"{f:g}" for f in thin) if thin else ""
    cache = ROOT / "out" / f"learned_loo_v{FEATURE_VERSION}{tag}_{len(recs)}.npz"
    if cache.exists():
        z = np.load(cache)
        return train.Samples(z["X"], z["y"], z["group"], z["cond"], list(z["names"]))
    t0 = time.process_time()
    S = train.samples(recs, per_stream=evaluation.LOO_EVENTS_PER_STREAM, thin=thin)
    print(f"-- feature rows of {len(recs)} recordings: {time.process_time() - t0:.0f} s CPU (cached in {cache})")
    cache.parent.mkdir(exist_ok=True)
    np.savez(cache, X=S.X, y=S.y, group=S.group, cond=S.cond, names=np.array(S.names))
    return S


def _zeroed(S: train.Samples, without) -> train.Samples:
    X = S.X.copy()
    X[:, [FEATURES.index(f) for f in without]] = 0.0
    return train.Samples(X, S.y, S.group, S.cond, S.names)


def _edp_auc(score: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    lab = np.where(y == 1, 0, 1).astype(np.uint8)  # 0 signal, 1 noise
    return metrics.edp_at_tpr(lab, score, 0.8), metrics.roc_auc(lab, score)


def ablate(S: train.Samples) -> None:
    n_real = sum(1 for n in S.names if not (ROOT / "recordings" / f"{n}.npz").exists())
    print(f"-- leave-one-recording-out on {len(S.names)} recordings ({n_real} real): EDP@80 / AUC")
    print(f"{'features':<30} " + " ".join(f"{c:>14}" for c in COND_NAMES))
    for name, without in ABLATIONS.items():
        Z = _zeroed(S, without)
        cells = {c: [] for c in range(len(COND_NAMES))}
        for g in range(len(S.names)):
            model = train._fit(Z.subset(Z.group != g), "logistic", 16, 0)
            held = Z.subset(Z.group == g)
            score = model.score(held.X)
            for c in cells:
                sel = held.cond == c
                cells[c].append(_edp_auc(score[sel], held.y[sel]))
        print(f"{name:<30} " + " ".join(f"{np.mean([e for e, _ in v]):6.1f} / {np.mean([a for _, a in v]):.3f}"
                                       for v in cells.values()), flush=True)


def _kept(model, held: train.Samples, keep: float) -> float:
    """Mean over the held-out recording's conditions of the signal kept at the threshold for `keep`."""
    thr = model.threshold(keep)
    score = model.score(held.X)
    return float(np.mean([(score[(held.cond == c) & (held.y == 1)] >= thr).mean()
                          for c in np.unique(held.cond)]))


def calib(keep: float) -> None:
    plain = load_samples()
    variants = {"train.fit (as shipped)": (plain, None)}
    thinned = load_samples(thin=(0.3, 0.1, 0.03))
    n_cond = len(COND_NAMES)
    variants["thinned copies, fit and calibrate"] = (thinned, None)
    variants["thinned copies, calibrate on unthinned"] = (thinned, n_cond)
    print(f"-- signal kept at the threshold for keep = {keep} on the held-out recording's own (unthinned) rows")
    rows = {}
    for vname, (S, calib_conds) in variants.items():
        t0 = time.process_time()
        kept = []
        for g in range(len(S.names)):
            tr = S.subset(S.group != g)
            model = train.fit(tr, keep=keep, calibrate_rows=None if calib_conds is None else tr.cond < calib_conds)
            held = S.subset((S.group == g) & (S.cond < n_cond))
            kept.append(_kept(model, held, keep))
        rows[vname] = kept
        k = np.array(kept)
        print(f"{vname:<40} mean {k.mean():.3f}  min {k.min():.3f}  max {k.max():.3f}  "
              f"spread {k.max() - k.min():.3f}  |mean error| {np.abs(k - keep).mean():.3f}  "
              f"({time.process_time() - t0:.0f} s CPU)", flush=True)
    print(f"{'recording':<16}" + "".join(f"{v[:22]:>24}" for v in rows))
    for g, name in enumerate(plain.names):
        print(f"{name:<16}" + "".join(f"{rows[v][g]:24.3f}" for v in rows))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["ablate", "calib"])
    ap.add_argument("--keep", type=float, default=0.85)
    a = ap.parse_args()
    if a.what == "ablate":
        ablate(load_samples())
    else:
        calib(a.keep)


if __name__ == "__main__":
    main()
