"""Throughput and state memory of the learned stage (logistic and MLP models) beside the paper's cascade.

The machine is shared: the stages are timed interleaved in one process (round-robin, best of several
rounds each) in CPU time of this process (`time.process_time`: the stages are single-threaded, so time
spent waiting for a core under load is not counted), and the ratio to the cascade is printed beside the
absolute rate: for the best whole run and for the median one (the figure a user can count on). Under
load a whole run is still slowed by the other processes (each time they take the core they evict the
stages' maps from the caches), the learned stage with its larger state more than the cascade; so a
third figure sums, chunk by chunk, the least CPU time any round took for that chunk (`chunk_min_*`):
on a quiet machine the three agree. Stream as `bench_paper`: the turntable at 346×260
with 3 Hz/pixel background activity and 0.1 % hot pixels, chunks of 10k events.
"""

from __future__ import annotations

import os
import time

import numpy as np

from evstream.denoise.cascade import PaperCascade
from evstream.denoise.learned import LearnedFilter, Model, load
from evstream.denoise.learned.features import N_FEATURES
from evstream.denoise.learned.model import DEFAULT_MODEL
from evstream.denoise.learned.train import KEEP_GRID
from evstream.events import Geometry
from evstream.testing import state_nbytes

from .common import noisy_scene, report


def _model(kind: str, hidden: int) -> Model:
    rng = np.random.default_rng(0)
    rows = hidden if kind == "mlp" else 1
    return Model(w1=rng.normal(0, 1, (rows, N_FEATURES)), b1=np.zeros(rows), w2=rng.normal(0, 1, rows), b2=0.0,
                 mean=np.zeros(N_FEATURES), std=np.ones(N_FEATURES), keep_grid=KEEP_GRID.copy(),
                 threshold_grid=np.zeros(len(KEEP_GRID)), meta={"kind": kind, "hidden": hidden})


ROUNDS = int(os.environ.get("EVSTREAM_BENCH_ROUNDS", "7"))  # under load: 21 or more for steady chunk minima


def run(rounds: int = ROUNDS, chunk: int = 10_000) -> None:
    g = Geometry(346, 260)
    duration = 1_000_000
    s = noisy_scene("turntable", g, duration)
    n = len(s)
    print(f"-- turntable {g}: {n:,} events, chunks of {chunk:,}, {rounds} interleaved rounds")
    makers = {"cascade (paper)": PaperCascade,
              "learned, logistic": lambda: LearnedFilter(model=_model("logistic", 0)),
              "learned, MLP 8 ReLU": lambda: LearnedFilter(model=_model("mlp", 8)),
              "learned, MLP 16 ReLU": lambda: LearnedFilter(model=_model("mlp", 16))}
    if DEFAULT_MODEL.exists():
        makers["learned, shipped model"] = lambda: LearnedFilter(model=load())
    runs = {k: [] for k in makers}  # CPU time of each whole run
    starts = range(0, n, chunk)
    chunk_best = {k: np.full(len(starts), np.inf) for k in makers}
    for make in makers.values():  # compile
        make()(s[:chunk])
    for _ in range(rounds):
        for name, make in makers.items():
            stage = make()
            t0 = time.process_time()
            for j, a in enumerate(starts):
                c0 = time.thread_time()
                stage(s[a : a + chunk])
                chunk_best[name][j] = min(chunk_best[name][j], time.thread_time() - c0)
            runs[name].append(time.process_time() - t0)
            last = stage
            if name.startswith("learned"):
                bytes_pp = state_nbytes(last) / g.n_pixels
    base = n / min(runs["cascade (paper)"])
    median_base = n / np.median(runs["cascade (paper)"])
    chunk_base = n / chunk_best["cascade (paper)"].sum()
    for name in makers:
        eps = n / min(runs[name])
        median_eps = n / np.median(runs[name])
        chunk_eps = n / chunk_best[name].sum()
        report(name, eps, ns_per_event=f"{1e9 / eps:.1f}", vs_cascade=f"{eps / base:.2f}",
               median_run_M_per_s=f"{median_eps / 1e6:.1f}", median_vs_cascade=f"{median_eps / median_base:.2f}",
               chunk_min_M_per_s=f"{chunk_eps / 1e6:.1f}", chunk_min_vs_cascade=f"{chunk_eps / chunk_base:.2f}")
    report("learned state", 0.0, state_bytes_per_pixel=f"{bytes_pp:.1f}")


if __name__ == "__main__":
    run()
