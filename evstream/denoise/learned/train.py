"""Training the learned denoiser on a user's own recordings (`evstream train`).

1. Each recording's own events are the signal (its real hot pixels set aside, as `evstream eval`
   does; a synthetic recording's SIGNAL-labelled events); labelled noise is injected with the
   project's noise model (`evstream.noise`) at several noise ratios and background rates.
2. The feature kernel runs over each noisy stream (the same kernel the stage scores with); warm-state
   events are subsampled to the same number per recording and condition, so that no recording or
   noise level dominates the fit.
3. Fit, in numpy (no extra dependency; both fits are small and deterministic for a seed): logistic
   regression by Newton's method with a little L2, or a one-hidden-layer ReLU MLP by full-batch Adam.
4. Calibrate the operating point on recordings the scoring model has not seen: with two or more
   recordings, each one is scored by a model fitted on the others, and the threshold keeping a
   fraction k of the signal is taken per (recording, condition) in units of that fold model's
   training-score quantiles; the final model's thresholds are its own training quantiles at the mean
   of those (a threshold fixed on the training data alone keeps less than asked on new recordings).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...events import EventChunk, NoiseClass, shown
from ...noise import Condition, NoiseSpec, as_signal, inject
from .features import FEATURE_VERSION, FEATURES, HISTORY_US, HOT_SCORE, N_FEATURES
from .model import Model

TRAIN_CONDITIONS = (Condition(noise_ratio=0.5), Condition(noise_ratio=1.0), Condition(noise_ratio=2.0),
                    Condition(ba_rate_hz=1.0), Condition(ba_rate_hz=3.0), Condition(ba_rate_hz=5.0))
KEEP_GRID = np.round(np.arange(0.50, 0.991, 0.01), 2)
SEED_BASE = 1000  # training noise seeds: far from the evaluation's 0, 1, ...


@dataclass
class Samples:
    """Feature rows with labels (1 = signal) and the recording and condition each came from."""

    X: np.ndarray
    y: np.ndarray
    group: np.ndarray      # index of the recording
    cond: np.ndarray       # index of the condition
    names: list[str]

    def subset(self, keep: np.ndarray) -> Samples:
        return Samples(self.X[keep], self.y[keep], self.group[keep], self.cond[keep], self.names)


def blank_model() -> Model:
    """A model that scores 0 everywhere: runs the feature kernel for training."""
    return Model(w1=np.zeros((1, N_FEATURES)), b1=np.zeros(1), w2=np.zeros(1), b2=0.0,
                 mean=np.zeros(N_FEATURES), std=np.ones(N_FEATURES), keep_grid=np.array([0.5]),
                 threshold_grid=np.array([0.0]), meta={"kind": "logistic"})


def features_of(noisy: EventChunk) -> np.ndarray:
    from .stage import LearnedFilter

    return LearnedFilter(model=blank_model()).features(noisy.replace(label=None, cls=None))


def samples(recordings: dict[str, EventChunk], conditions: Iterable[Condition] = TRAIN_CONDITIONS,
            seeds: Iterable[int] = (SEED_BASE,), per_stream: int = 20_000, rng_seed: int = 0,
            progress: Callable[[str], None] | None = None, thin: Iterable[float] = (),
            time_scale: Iterable[float] = (), off_keep: Iterable[float] = ()) -> Samples:
    """Labelled feature rows of every recording × condition × seed, `per_stream` warm events each.

    `thin`: each recording also enters with its signal thinned at random to each of these fractions
    (same recording group, so calibration folds keep a recording's copies together): sparser edges,
    as a low-resolution or less sensitive sensor sees them, whose lower scores `train` lets set the
    operating point (docs/learned.md: the shipped model's transfer).
    `time_scale`: copies with the timestamps stretched by each factor (2: a scene twice as slow);
    `off_keep`: copies keeping each fraction of the OFF events (a sensor biased towards ON). Both join
    the recording's group; their condition indices follow the thinned copies'."""
    rng = np.random.default_rng(rng_seed)
    thin_rng = np.random.default_rng([rng_seed, 1])  # apart from `rng`: no thinning, the same samples
    conditions = list(conditions)
    thin = [float(f) for f in thin]
    if any(not 0 < f < 1 for f in thin):
        raise ValueError(f"thin fractions must be in (0, 1), got {thin}")
    Xs, ys, gs, cs = [], [], [], []
    names = list(recordings)
    for gi, (name, events) in enumerate(recordings.items()):
        full, _ = as_signal(events)
        if len(full) < 100:
            raise ValueError(f"{name}: fewer than 100 signal events, nothing to learn from")
        for ti, frac in enumerate([1.0, *thin]):
            signal = full if frac == 1.0 else full[thin_rng.random(len(full)) < frac]
            if len(signal) < 100:
                continue
            _stream_samples(name, signal, conditions, seeds, per_stream, rng, progress, gi,
                            ti * len(conditions), "" if frac == 1.0 else f" thinned to {frac:g}", Xs, ys, gs, cs)
        aug_rng = np.random.default_rng([rng_seed, 2, gi])
        variants = [(f" time x{f:g}", stretched(full, f)) for f in time_scale]
        variants += [(f" OFF kept {k:g}", full[(full.p == 1) | (aug_rng.random(len(full)) < k)]) for k in off_keep]
        for vi, (what, signal) in enumerate(variants):
            if len(signal) >= 100:
                _stream_samples(name, signal, conditions, seeds, per_stream, rng, progress, gi,
                                (1 + len(thin) + vi) * len(conditions), what, Xs, ys, gs, cs)
    return Samples(np.concatenate(Xs), np.concatenate(ys), np.concatenate(gs), np.concatenate(cs), names)


def stretched(signal: EventChunk, factor: float) -> EventChunk:
    """The signal with its time axis stretched by `factor` from its first event (2: twice as slow)."""
    t0 = int(signal.t[0])
    t = t0 + np.round((signal.t - t0) * factor).astype(np.int64)
    return signal.replace(t=t, t_end=int(t[-1]))


def _stream_samples(name, signal, conditions, seeds, per_stream, rng, progress, gi, c0, what, Xs, ys, gs, cs):
    """Feature rows of one signal stream under every condition and seed, appended to the lists."""
    for ci, cond in enumerate(conditions):
        for seed in seeds:
            if progress:
                progress(f"{name}{what} {cond.name} seed {seed}")
            noisy = inject(signal, cond.spec(), seed=seed, t_start_us=int(signal.t[0]),
                           t_stop_us=int(signal.t[-1]) + 1)
            X = features_of(noisy)
            t0, t1 = int(noisy.t[0]), int(noisy.t[-1])
            warm = np.flatnonzero(noisy.t >= t0 + min(HISTORY_US, int(0.3 * (t1 - t0))))
            pick = np.sort(rng.choice(warm, min(per_stream, len(warm)), replace=False))
            Xs.append(X[pick])
            ys.append((noisy.label[pick] == NoiseClass.SIGNAL).astype(np.float64))
            gs.append(np.full(len(pick), gi))
            cs.append(np.full(len(pick), c0 + ci))


# -- fitting ------------------------------------------------------------------------------------------
def _standardise(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = X.mean(axis=0)
    std = X.std(axis=0)
    return mean, np.where(std > 1e-9, std, 1.0)


def fit_logistic(Z: np.ndarray, y: np.ndarray, l2: float = 1e-3, iters: int = 30) -> tuple[np.ndarray, float]:
    """Newton's method (IRLS) on standardised features; returns (w, b)."""
    n, d = Z.shape
    A = np.hstack([Z, np.ones((n, 1))])
    w = np.zeros(d + 1)
    reg = l2 * n * np.eye(d + 1)
    reg[d, d] = 0.0
    for _ in range(iters):
        z = np.clip(A @ w, -30, 30)
        pr = 1.0 / (1.0 + np.exp(-z))
        grad = A.T @ (pr - y) + reg @ w
        H = (A * (pr * (1 - pr))[:, None]).T @ A + reg
        step = np.linalg.solve(H, grad)
        w -= step
        if np.abs(step).max() < 1e-8:
            break
    return w[:d], float(w[d])


def fit_mlp(Z: np.ndarray, y: np.ndarray, hidden: int, seed: int = 0, epochs: int = 60, batch: int = 4096,
            lr: float = 3e-3, l2: float = 1e-5) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """One hidden ReLU layer, logistic loss, minibatch Adam (numpy, seeded); returns (w1, b1, w2, b2)."""
    rng = np.random.default_rng(seed)
    n, d = Z.shape
    params = [rng.normal(0, np.sqrt(2.0 / d), (hidden, d)), np.zeros(hidden),
              rng.normal(0, np.sqrt(1.0 / hidden), hidden), np.zeros(1)]
    m = [np.zeros_like(p) for p in params]
    v = [np.zeros_like(p) for p in params]
    step = 0
    for _ in range(epochs):
        order = rng.permutation(n)
        for a in range(0, n, batch):
            idx = order[a : a + batch]
            zb, yb = Z[idx], y[idx]
            w1, b1, w2, b2 = params
            pre = zb @ w1.T + b1
            h = np.maximum(pre, 0.0)
            out = h @ w2 + b2[0]
            pr = 1.0 / (1.0 + np.exp(-np.clip(out, -30, 30)))
            g_out = (pr - yb) / len(idx)
            g_w2 = h.T @ g_out + l2 * w2
            g_b2 = np.array([g_out.sum()])
            g_h = np.outer(g_out, w2) * (pre > 0)
            g_w1 = g_h.T @ zb + l2 * w1
            g_b1 = g_h.sum(axis=0)
            step += 1
            for k, g in enumerate((g_w1, g_b1, g_w2, g_b2)):
                m[k] = 0.9 * m[k] + 0.1 * g
                v[k] = 0.999 * v[k] + 0.001 * g * g
                mh = m[k] / (1 - 0.9**step)
                vh = v[k] / (1 - 0.999**step)
                params[k] = params[k] - lr * mh / (np.sqrt(vh) + 1e-8)
    w1, b1, w2, b2 = params
    return w1, b1, w2, float(b2[0])


def _fit(S: Samples, kind: str, hidden: int, seed: int) -> Model:
    mean, std = _standardise(S.X)
    Z = (S.X - mean) / std
    if kind == "logistic":
        w, b = fit_logistic(Z, S.y)
        w1, b1, w2, b2 = w[None, :], np.array([b]), np.zeros(1), 0.0
    elif kind == "mlp":
        w1, b1, w2, b2 = fit_mlp(Z, S.y, hidden, seed=seed)
    else:
        raise ValueError(f"model kind must be 'logistic' or 'mlp', got {shown(kind)}")
    # float32 precision on disk and in use: the same bytes on every machine that fits the same numbers
    f32 = lambda a: np.asarray(a, np.float32).astype(np.float64)  # noqa: E731
    return Model(w1=f32(w1), b1=f32(b1), w2=f32(w2), b2=float(np.float32(b2)), mean=f32(mean), std=f32(std),
                 keep_grid=KEEP_GRID.copy(), threshold_grid=np.zeros(len(KEEP_GRID)),
                 meta={"kind": kind, "hidden": hidden if kind == "mlp" else 0})


def _signal_scores(model: Model, S: Samples):
    """The model's scores of the signal events of each (recording, condition) with at least 50 of them."""
    score = model.score(S.X)
    for g in np.unique(S.group):
        for c in np.unique(S.cond):
            sel = (S.group == g) & (S.cond == c) & (S.y == 1)
            if sel.sum() >= 50:
                yield score[sel]


def _fold_levels(model: Model, S: Samples, keeps: np.ndarray) -> np.ndarray:
    """Per (recording, condition) signal scores' thresholds keeping `keeps` of the signal, as rows."""
    return np.array([np.quantile(s, 1 - np.asarray(keeps)) for s in _signal_scores(model, S)])


def _keep_at(model: Model, S: Samples, thresholds: np.ndarray) -> np.ndarray:
    """Mean over (recording, condition) of the signal kept at each threshold."""
    return np.mean([(s[:, None] >= thresholds[None, :]).mean(axis=0) for s in _signal_scores(model, S)], axis=0)


def calibrate(S: Samples, kind: str, hidden: int, seed: int, final: Model,
              rows: np.ndarray | None = None, fit_rows: np.ndarray | None = None,
              progress: Callable[[str], None] | None = None) -> tuple[np.ndarray, dict]:
    """Thresholds of `final` for KEEP_GRID that transfer to recordings it was not fitted on.

    With one recording: the training quantiles themselves. With more: for each recording, a model fitted
    on the others gives the signal kept on it at each of that model's own training thresholds; the
    training level l(k) whose held-out keep averages k is then applied to `final`'s training scores.
    `rows`: the rows whose signal the quantiles are taken on (default all); `fit_rows`: the rows the
    fold models are fitted on (default all; as `final` was). `progress(message)`: called before each
    recording's fit."""
    C = S if rows is None else S.subset(rows)
    F = S if fit_rows is None else S.subset(fit_rows)
    own_levels = np.median(_fold_levels(final, C, KEEP_GRID), axis=0)
    groups = np.unique(S.group)
    if len(groups) < 2:
        return own_levels, {"calibration": "training quantiles (one recording)"}
    fine = np.round(np.arange(0.30, 0.9991, 0.0025), 4)  # training-level keeps to search
    held = []
    for i, g in enumerate(groups):
        if progress:
            progress(f"operating points: {S.names[g]} left out ({i + 1} of {len(groups)} fits)")
        fold = _fit(F.subset(F.group != g), kind, hidden, seed)
        thr = np.median(_fold_levels(fold, C.subset(C.group != g), fine), axis=0)
        held.append(_keep_at(fold, C.subset(C.group == g), thr))
    held_keep = np.mean(held, axis=0)  # held-out keep at each training-level keep in `fine`
    # monotone: a higher training keep never lowers the held-out keep
    held_keep = np.maximum.accumulate(held_keep)
    level = np.interp(KEEP_GRID, held_keep, fine)
    final_thr = np.median(_fold_levels(final, C, level), axis=0)
    info = {"calibration": "cross-fitted over recordings",
            "held_out_keep_at_training_keep": {f"{k:.2f}": round(float(np.interp(k, fine, held_keep)), 4)
                                               for k in (0.8, 0.85, 0.9)}}
    return final_thr, info


def auc(score: np.ndarray, y: np.ndarray) -> float:
    from ...metrics import roc_auc

    return float(roc_auc(np.where(y == 1, 0, 1).astype(np.uint8), score))


def fit(S: Samples, kind: str = "logistic", hidden: int = 16, keep: float = 0.85, seed: int = 0,
        calibrate_folds: bool = True, calibrate_rows: np.ndarray | None = None,
        fit_rows: np.ndarray | None = None, progress: Callable[[str], None] | None = None) -> Model:
    """A model fitted on the samples `fit_rows` (default all), its operating points calibrated (see
    `calibrate`; its quantiles taken on `calibrate_rows`, default all)."""
    model = _fit(S if fit_rows is None else S.subset(fit_rows), kind, hidden, seed)
    if calibrate_folds:
        thr, info = calibrate(S, kind, hidden, seed, model, calibrate_rows, fit_rows, progress)
    else:
        thr, info = np.median(_fold_levels(model, S, KEEP_GRID), axis=0), {"calibration": "training quantiles"}
    model.threshold_grid = np.asarray(thr, np.float32).astype(np.float64)
    model.meta.update({"keep": keep, "feature_version": FEATURE_VERSION, "features": list(FEATURES), **info,
                       "training_auc": round(auc(model.score(S.X), S.y), 4)})
    return model


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def train(recordings: dict[str, EventChunk], *, kind: str = "logistic", hidden: int = 16, keep: float = 0.85,
          seed: int = 0, per_stream: int = 20_000, sources: dict[str, str] | None = None,
          conditions: Iterable[Condition] = TRAIN_CONDITIONS, thin: Iterable[float] = (),
          without: Iterable[str] = (), fit_thinned: bool = False, time_scale: Iterable[float] = (),
          progress: Callable[[str], None] | None = None) -> Model:
    """Inject noise into `recordings` (and their signal thinned to `thin`, see `samples`), compute
    features, fit and calibrate; provenance in `meta`. `without`: features the score leaves out
    (weight 0; the kernel still computes them, e.g. for the hot-pixel rules). The thinned copies set
    the operating point only (also the weights with `fit_thinned`); the `time_scale` copies (timestamps
    stretched by each factor: slower scenes) the weights only."""
    conditions = list(conditions)
    thin = [float(f) for f in thin]
    time_scale = [float(f) for f in time_scale]
    if any(f <= 0 for f in time_scale):
        raise ValueError(f"time scale factors must be positive, got {time_scale}")
    without = list(without)
    unknown = [f for f in without if f not in FEATURES]
    if unknown:
        raise ValueError(f"unknown feature(s) {', '.join(unknown)}; the features are {', '.join(FEATURES)}")
    S = samples(recordings, conditions, seeds=(SEED_BASE + seed,), per_stream=per_stream, rng_seed=seed,
                progress=progress, thin=thin, time_scale=time_scale)
    S.X[:, [FEATURES.index(f) for f in without]] = 0.0  # constant: standardised to 0, Newton keeps w = 0
    if progress:
        progress(f"fitting {kind} on {len(S.y):,} events")
    # the thinned copies set the operating point, the stretched ones the weights (docs/learned.md: fitted
    # on the thinned copies too, the score ranked worse on sensors it never saw; the stretched copies'
    # scores kept the calibration from transferring)
    n_plain, n_thinned = len(conditions), (1 + len(thin)) * len(conditions)  # condition indices, see samples
    fit_rows = None if fit_thinned else (S.cond < n_plain) | (S.cond >= n_thinned)
    model = fit(S, kind, hidden, keep, seed, fit_rows=fit_rows, calibrate_rows=S.cond < n_thinned, progress=progress)
    sources = sources or {}
    model.meta.update({
        "name": "trained",
        "trained_on": [{"recording": n, **({"file": Path(sources[n]).name, "sha256": sha256(sources[n])}
                                           if n in sources else {})} for n in recordings],
        "noise_conditions": [c.name for c in conditions],
        "noise_seed": SEED_BASE + seed,
        **({"signal_thinned_to": thin, "thinned_copies": "fit and operating point" if fit_thinned
            else "operating point only"} if thin else {}),
        **({"signal_time_scaled_by": time_scale} if time_scale else {}),
        **({"features_left_out": without} if without else {}),
        "events_per_stream": per_stream,
        "training_events": int(len(S.y)),
        "signal_share": round(float(S.y.mean()), 4),
    })
    return model


# -- the operating point on a stream the model never saw, without labels ------------------------------
PROBE_RATIO = 0.2  # probe noise injected by `stream_keep_curve`: 20 % of the stream's events
MIN_STREAM_EVENTS = 2_000


def stream_keep_curve(model: Model, events: EventChunk, *, probe_ratio: float = PROBE_RATIO,
                      seed: int = SEED_BASE - 1) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(thresholds, signal kept at each, noise share) on this stream, estimated without labels; None if
    it is too short to say (fewer than 2,000 warm events).

    The stream's events are signal and noise in an unknown mix: F_obs = (1 - pi) F_sig + pi F_noise.
    Probe noise (background activity, `probe_ratio` of the events, labels known) injected into a copy
    shows how noise scores in this scene at this rate: F_noise. Low scores are nearly all noise, so pi
    is the least F_obs(t) / F_noise(t) over the probe's 10-50 % quantiles (a mixture-proportion
    estimate); the signal kept at t is (S_obs(t) - pi S_noise(t)) / (1 - pi), S = 1 - F. Events a
    hot-pixel rule rejects are noise and left out of both."""
    from .stage import LearnedFilter

    if len(events) < MIN_STREAM_EVENTS:
        return None
    bare = events.replace(label=None, cls=None)
    t0, t1 = int(bare.t[0]), int(bare.t[-1])
    probed = inject(bare, NoiseSpec(noise_ratio=probe_ratio, hot_share=0.0), seed=seed,
                    t_start_us=t0, t_stop_us=t1 + 1)
    _, score = LearnedFilter(model=model).classify_scored(probed.replace(label=None))
    ok = (probed.t >= t0 + min(HISTORY_US, int(0.3 * (t1 - t0)))) & (score > HOT_SCORE / 2)
    own = np.sort(score[ok & (probed.label == NoiseClass.SIGNAL)])
    probe = np.sort(score[ok & (probed.label == NoiseClass.BACKGROUND)])
    if len(own) < MIN_STREAM_EVENTS or len(probe) < 200:
        return None
    F_own = lambda t: np.searchsorted(own, t, side="left") / len(own)  # noqa: E731
    F_probe = lambda t: np.searchsorted(probe, t, side="left") / len(probe)  # noqa: E731
    low = np.quantile(probe, np.linspace(0.1, 0.5, 9))
    pi = float(np.clip(np.min(F_own(low) / np.maximum(F_probe(low), 1e-9)), 0.0, 0.95))
    thresholds = np.unique(np.quantile(own, np.linspace(0.0, 0.995, 400)))
    kept = ((1 - F_own(thresholds)) - pi * (1 - F_probe(thresholds))) / (1 - pi)
    return thresholds, np.clip(np.minimum.accumulate(kept), 0.0, 1.0), pi  # never more kept at a higher t


def calibrate_to(model: Model, recordings: dict[str, EventChunk]) -> Model:
    """A copy of `model` whose operating points are calibrated on these recordings, without labels
    (`stream_keep_curve` on each, their kept curves averaged): what `evstream calibrate` writes. The
    model's own thresholds stay where a recording is too short to say anything."""
    found = {name: stream_keep_curve(model, ev) for name, ev in recordings.items()}
    curves = [c for c in found.values() if c is not None]
    out = Model(**{k: getattr(model, k) for k in ("w1", "b1", "w2", "b2", "mean", "std", "keep_grid")},
                threshold_grid=model.threshold_grid.copy(), meta=dict(model.meta))
    if not curves:
        return out
    grid = np.unique(np.concatenate([t for t, _, _ in curves]))
    kept = np.mean([np.interp(grid, t, k) for t, k, _ in curves], axis=0)  # decreasing in the threshold
    # the highest threshold keeping at least each fraction of the signal
    thr = np.array([grid[np.flatnonzero(kept >= k)[-1]] if (kept >= k).any() else grid[0]
                    for k in model.keep_grid])
    out.threshold_grid = np.asarray(thr, np.float32).astype(np.float64)
    out.meta.update({"calibration": "label-free, on the stream(s) it runs on (evstream calibrate)",
                     "calibrated_on": {n: {"noise_share": round(c[2], 4)} if c else "too short: not used"
                                       for n, c in found.items()}})
    return out


def stream_threshold(model: Model, events: EventChunk, keep: float | None = None) -> float:
    """The threshold expected to keep the fraction `keep` of this stream's signal, estimated from the
    stream itself without labels (`calibrate_to`); the model's own threshold if the stream is too short."""
    return calibrate_to(model, {"stream": events}).threshold(keep)
