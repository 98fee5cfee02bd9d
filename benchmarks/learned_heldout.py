"""Held-out generalisation of the learned denoiser, harder than leave-one-recording-out.

Every learned score below comes from a model that never saw the sensor family being scored: the
recordings are grouped by the sensor that made them (recordings/*.npz: synthetic; DVS128; DVXplorer;
ATIS — ../shared/data/real/SOURCES.md), and each family is scored by a model trained (as `evstream
train` does, `train.samples` + `train.fit`) on the other families only. The tests:

- `family-out`: the families' recordings at the paper's noise ratios and the issue's 3 and 5 Hz/pixel;
- `noise`: noise unlike the training conditions — 20 % and 300 %, 0.5 and 10 Hz/pixel, and 3 Hz/pixel
  with each pixel's rate drawn from a log-normal (sigma 1: real sensors' rates vary from pixel to pixel);
- `time`: the recordings slowed down (timestamps × 2) and sped up (× 0.5), 100 % noise;
- `polarity`: the recordings with two thirds of their OFF events dropped (ON share ~75 %), 100 %;
- `size`: the synthetic scenes regenerated at 640×480 and 1280×720 (other seeds, 300 ms) scored by
  the model trained on the real recordings only, 100 % and 3 Hz/pixel.

Per test, mean over recordings (one noise seed, 0): EDP at >= 80 % signal kept for the paper's
cascade (relative and absolute), STCF and learned; learned's AUC and the best rule's; learned's
smallest lead over the best rule on one recording (negative: it loses there), and the signal
learned keeps at its calibrated threshold for keep = 0.85 — mean and [min, max] over recordings —
with the fixed threshold (`Model.threshold`) and with the label-free per-stream calibration
(`train.stream_threshold`: fitted on the stream's first half, without labels, kept reported on the
second half; and fitted on the whole stream, kept reported on all of it after the warm-up: what
`evstream calibrate REC` gives on REC itself, without the scene changing between the two halves).

    python -m benchmarks.learned_heldout     # ~1 minute of CPU (6 minutes' wall under a load of 10)
    python -m benchmarks.learned_heldout --recipe base,aug,shipped
    python -m benchmarks.learned_heldout --recipe shipped,file:out/candidate.npz --families DVS128,DVXplorer,ATIS
    python -m benchmarks.learned_heldout --recipe shipped --only family-out,noise --per-recording

`--families` keeps only those families' recordings (for a trained recipe, also its training data).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import time
from pathlib import Path

import numpy as np

from evstream import evaluation, metrics, synth
from evstream.cli.evaluate import read_recordings
from evstream.denoise.learned import LearnedFilter, load, train
from evstream.events import Geometry, NoiseClass
from evstream.noise import NoiseSpec, as_signal, inject

from .common import ROOT

REAL = Path(os.environ.get("EVSTREAM_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
RULES = ("paper", "paper-abs", "stcf")
KEEP = 0.85
PAPER = {"50%": NoiseSpec(noise_ratio=0.5), "100%": NoiseSpec(noise_ratio=1.0),
         "200%": NoiseSpec(noise_ratio=2.0), "3Hz": NoiseSpec(ba_rate_hz=3.0), "5Hz": NoiseSpec(ba_rate_hz=5.0)}
OTHER_NOISE = {"20%": NoiseSpec(noise_ratio=0.2), "300%": NoiseSpec(noise_ratio=3.0),
               "0.5Hz": NoiseSpec(ba_rate_hz=0.5), "10Hz": NoiseSpec(ba_rate_hz=10.0),
               "3Hz, rates vary per pixel": NoiseSpec(ba_rate_hz=3.0, ba_spread=1.0)}


def family(name: str) -> str:
    """The sensor family of a recording (SOURCES.md)."""
    if (ROOT / "recordings" / f"{name}.npz").exists() or name.startswith("synthetic"):
        return "synthetic"
    for prefix, fam in (("dvs128", "DVS128"), ("dvsgesture", "DVS128"), ("dvxplorer", "DVXplorer"),
                        ("ncaltech", "ATIS"), ("nmnist", "ATIS"), ("ncars", "ATIS"), ("davis", "DAVIS346"),
                        ("prophesee", "Prophesee")):
        if name.startswith(prefix):
            return fam
    return name


def load_recordings() -> dict:
    paths = sorted(str(p) for p in (ROOT / "recordings").glob("*.npz"))
    if REAL.is_dir():
        paths += sorted(str(p) for p in REAL.iterdir() if p.is_file() and p.suffix != ".md")
    with contextlib.redirect_stderr(io.StringIO()):
        recs = read_recordings(paths, 0.25, "learned_heldout")
    return {n: as_signal(ev)[0] for n, ev in recs.items() if len(as_signal(ev)[0]) >= 100}


def off_thinned(signal, keep_off: float, seed: int = 5):
    rng = np.random.default_rng(seed)
    return signal[(signal.p == 1) | (rng.random(len(signal)) < keep_off)]


def _warm(t, stage) -> np.ndarray:
    t0, t1 = int(t[0]), int(t[-1])
    return t >= t0 + min(evaluation.history_us(stage), int(evaluation.WARMUP_CAP * (t1 - t0)))


def score_stream(signal, spec: NoiseSpec, models: dict, seed: int = 0) -> dict:
    """EDP@80 and AUC of every rule and model on `signal` + noise; for models, the signal kept at the
    fixed threshold for KEEP and at the label-free per-stream threshold (fitted on the first half)."""
    noisy = inject(signal, spec, seed=seed, t_start_us=int(signal.t[0]), t_stop_us=int(signal.t[-1]) + 1)
    bare = noisy.replace(label=None)
    out = {}
    stages = {m: evaluation.METHODS[m]() for m in RULES}
    stages.update({m: LearnedFilter(model=model) for m, model in models.items()})
    for m, stage in stages.items():
        _, score = stage.classify_scored(bare)
        warm = _warm(noisy.t, stage)
        lab, sc = noisy.label[warm], score[warm]
        row = {"edp80": metrics.edp_at_tpr(lab, sc, 0.8), "auc": metrics.roc_auc(lab, sc)}
        if m in models:
            sig = noisy.label == NoiseClass.SIGNAL
            half = noisy.t >= (int(noisy.t[0]) + int(noisy.t[-1])) // 2
            row["kept_fixed"] = float((score[sig & half] >= stage.threshold).mean())
            first = bare[~half]
            thr = train.stream_threshold(models[m], first, KEEP)
            row["kept_stream"] = float((score[sig & half] >= thr).mean())
            # calibrated on the whole stream and run on it (`evstream calibrate REC`, then REC): no change of
            # scene between the half calibrated on and the half reported
            row["kept_whole"] = float((score[sig & warm] >= train.stream_threshold(models[m], bare, KEEP)).mean())
        out[m] = row
    return out


def synthetic_sized(size: tuple[int, int]) -> dict:
    g = Geometry(*size)
    return {f"synthetic {sc} {size[0]}x{size[1]}": synth.scene(sc, g, duration_us=300_000, seed=11 + i)
            for i, sc in enumerate(("ball", "bar", "turntable"))}


RECIPES = {  # name: keyword arguments of train.samples (the augmentations)
    "base": {},
    "time": {"time_scale": (0.5, 2.0)},
    "aug": {"time_scale": (0.5, 2.0), "off_keep": (0.33,)},
    "thin": {"thin": (0.3, 0.1, 0.03)},
}


def fold_models(recs: dict, recipe: str) -> dict:
    """{family: model trained on the other families}, and the time it took. Recipe `shipped`: the shipped
    model for every family (trained on the synthetic scenes and two MIT recordings, none of the real
    families here)."""
    t0 = time.process_time()
    if recipe == "shipped" or recipe.startswith("file:"):
        fixed = load(None if recipe == "shipped" else recipe[5:])
        return {fam: fixed for fam in {*map(family, recs), "synthetic"}}
    S = train.samples(recs, per_stream=evaluation.LOO_EVENTS_PER_STREAM, **RECIPES[recipe])
    fams = np.array([family(n) for n in S.names])
    models = {}
    for fam in sorted(set(fams)):
        out_groups = np.flatnonzero(fams == fam)
        fold = S.subset(~np.isin(S.group, out_groups))
        # the threshold's quantiles on the recordings as they are (augmented copies only in the fit)
        models[fam] = train.fit(fold, calibrate_rows=fold.cond < len(train.TRAIN_CONDITIONS))
    print(f"-- recipe {recipe}: features and {len(models)} family-out models, "
          f"{time.process_time() - t0:.0f} s CPU", flush=True)
    return models


def tests(recs: dict) -> list[tuple[str, str, list]]:
    """(group, test name, [(recording, family, signal, spec)])."""
    plain = [(n, family(n), s) for n, s in recs.items()]
    out = [("family-out", k, [(n, f, s, spec) for n, f, s in plain]) for k, spec in PAPER.items()]
    out += [("noise", k, [(n, f, s, spec) for n, f, s in plain]) for k, spec in OTHER_NOISE.items()]
    for factor, what in ((2.0, "slowed ×2"), (0.5, "sped up ×2")):
        out.append(("time", what, [(n, f, train.stretched(s, factor), PAPER["100%"]) for n, f, s in plain]))
    out.append(("polarity", "OFF events ÷3", [(n, f, off_thinned(s, 1 / 3), PAPER["100%"]) for n, f, s in plain]))
    for size in ((640, 480), (1280, 720)):
        sized = synthetic_sized(size)
        for k in ("100%", "3Hz"):
            out.append(("size", f"{size[0]}×{size[1]}, {k}", [(n, "synthetic", s, PAPER[k]) for n, s in sized.items()]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recipe", default="base", help="training recipes to compare, comma-separated: "
                    + ", ".join(RECIPES) + ", shipped (the shipped model) or file:MODEL.npz (a model file, "
                    "for every family)")
    ap.add_argument("--families", default="", help="score only these families' recordings (comma-separated, "
                    "e.g. DVS128,DVXplorer,ATIS: the real ones; the size tests are synthetic)")
    ap.add_argument("--only", default="", help="test groups to run (comma-separated; default all)")
    ap.add_argument("--per-recording", action="store_true", help="also print each recording's EDP (the best "
                    "rule's and each recipe's) and the signal each recipe keeps there (fixed / stream / "
                    "whole-stream threshold)")
    a = ap.parse_args()
    recipes = a.recipe.split(",")
    recs = load_recordings()
    if a.families:
        recs = {n: ev for n, ev in recs.items() if family(n) in a.families.split(",")}
    fams = {n: family(n) for n in recs}
    print(f"-- {len(recs)} recordings: " + ", ".join(f"{n} ({f})" for n, f in fams.items()))
    models = {r: fold_models(recs, r) for r in recipes}
    head = (f"{'group':<11}{'test':<26}" + "".join(f"{m:>10}" for m in RULES)
            + "".join(f"{r[:10]:>11}" for r in recipes) + f"{'AUC rule':>9}"
            + "".join(f"{'AUC ' + r[:5]:>10}" for r in recipes) + f"{'worst lead':>18}"
            + "".join(f"{'kept@.85 fixed ' + r[:6]:>26}{'kept@.85 stream ' + r[:6]:>26}{'kept@.85 whole ' + r[:6]:>26}"
                      for r in recipes))
    print("EDP % at >= 80 % signal kept (mean over recordings; learned: trained without the family scored)")
    print(head)
    only = set(filter(None, a.only.split(",")))
    for group, name, items in tests(recs):
        if only and group not in only:
            continue
        t0 = time.process_time()
        rows = [score_stream(sig, spec, {r: models[r][fam] for r in recipes}) for _, fam, sig, spec in items]
        def mean(m, k, rows=rows):
            return np.nanmean([row[m][k] for row in rows])

        best_auc = max(mean(m, "auc") for m in RULES)
        line = (f"{group:<11}{name:<26}" + "".join(f"{mean(m, 'edp80'):10.1f}" for m in RULES)
                + "".join(f"{mean(r, 'edp80'):11.1f}" for r in recipes) + f"{best_auc:9.3f}"
                + "".join(f"{mean(r, 'auc'):10.3f}" for r in recipes))
        # the first recipe's lowest lead over the best rule on one recording, and which
        leads = [row[recipes[0]]["edp80"] - max(row[m]["edp80"] for m in RULES) for row in rows]
        w = int(np.nanargmin(leads))
        line += f"{leads[w]:+6.1f} {items[w][0].replace('dvs128_lifetime_', '')[:11]:<11}"
        for r in recipes:
            for k in ("kept_fixed", "kept_stream", "kept_whole"):
                v = np.array([row[r][k] for row in rows])
                line += f"{100 * v.mean():12.1f} [{100 * v.min():4.0f}–{100 * v.max():3.0f}]  "
        print(line + f"  ({time.process_time() - t0:.0f} s)", flush=True)
        if a.per_recording:
            for (rec, _, _, _), row in zip(items, rows, strict=True):
                rule = max(RULES, key=lambda m, row=row: row[m]["edp80"])
                print(f"{'':<11}  {rec[:40]:<40}{rule:>10} {row[rule]['edp80']:5.1f}"
                      + "".join(f"{row[r]['edp80']:11.1f}" for r in recipes)
                      + "".join(f"   kept {100 * row[r]['kept_fixed']:3.0f} / {100 * row[r]['kept_stream']:3.0f}"
                                f" / {100 * row[r]['kept_whole']:3.0f}" for r in recipes), flush=True)


if __name__ == "__main__":
    main()
