"""Denoising metrics on labelled events (EDP, ESNR, TPR/FPR, removal per noise class, ROC, AUC) and ESR
for unlabelled recordings.

Conventions: SIGNAL is the positive class. `label` holds the true `NoiseClass` codes; `keep` is either
a boolean array (True = the denoiser kept the event) or class codes (`cls`: kept iff SIGNAL). Hence
TP = signal kept, FP = noise kept, FN = signal removed, TN = noise removed. A `score` is one float per
event, higher = more signal-like; an event is kept at threshold θ iff `score >= θ`. NaN scores mark
events the scoring stage never saw (an earlier stage removed them): they count as removed at every
threshold. Undefined values (a ratio of zero to zero) are NaN, never an exception.
"""

from __future__ import annotations

import math

import numpy as np

from .events import Geometry, NoiseClass

__all__ = [
    "auc", "confusion", "edp", "edp_at_tpr", "esnr", "esr", "fpr", "mean_esr", "operating_point",
    "removal_rates", "roc_auc", "roc_curve", "summary", "tpr",
]


def _kept(keep) -> np.ndarray:
    a = np.asarray(keep)
    return a if a.dtype == bool else a == NoiseClass.SIGNAL


def _ratio(a: float, b: float) -> float:
    return a / b if b else math.nan


def confusion(label, keep) -> dict[str, int]:
    """Counts with SIGNAL as the positive class: tp (signal kept), fp (noise kept), fn, tn."""
    if label is None or keep is None:
        raise ValueError("metrics need ground-truth labels and the denoiser's decisions (got None)")
    label = np.asarray(label)
    kept = _kept(keep)
    if label.shape != kept.shape:
        raise ValueError(f"label has {label.shape[0] if label.ndim else 0} events, keep has "
                         f"{kept.shape[0] if kept.ndim else 0}")
    sig = label == NoiseClass.SIGNAL
    tp = int(np.count_nonzero(sig & kept))
    fp = int(np.count_nonzero(~sig & kept))
    return {"tp": tp, "fp": fp, "fn": int(np.count_nonzero(sig)) - tp, "tn": int(np.count_nonzero(~sig)) - fp}


def edp(label, keep) -> float:
    """Event denoising precision, the seed paper's EDP = 100·TP/(TP+FP) (percent of the kept events that
    are signal); NaN when nothing is kept. Never report it without TPR: removing signal raises it."""
    c = confusion(label, keep)
    return 100.0 * _ratio(c["tp"], c["tp"] + c["fp"])


def _esnr(tp: int, fp: int) -> float:
    if fp == 0:
        return math.inf if tp else math.nan
    return 10.0 * math.log10(tp / fp) if tp else -math.inf


def esnr(label, keep) -> float:
    """Event SNR in dB, the seed paper's ESNR = 10·log10(TP/FP) (signal kept over noise kept).
    +inf when no noise is kept (FP = 0), -inf when no signal is, NaN when nothing is."""
    c = confusion(label, keep)
    return _esnr(c["tp"], c["fp"])


def tpr(label, keep) -> float:
    """Fraction of the signal kept (recall); NaN without signal events."""
    c = confusion(label, keep)
    return _ratio(c["tp"], c["tp"] + c["fn"])


def fpr(label, keep) -> float:
    """Fraction of the noise kept; NaN without noise events."""
    c = confusion(label, keep)
    return _ratio(c["fp"], c["fp"] + c["tn"])


def removal_rates(label, keep) -> dict[str, float]:
    """Fraction of each true class removed: `background`, `hot_pixel`, `noise` (both), and `signal`
    (signal lost, 1 - TPR); NaN for a class with no events."""
    label = np.asarray(label)
    removed = ~_kept(keep)
    out = {}
    for name, mask in (("background", label == NoiseClass.BACKGROUND), ("hot_pixel", label == NoiseClass.HOT_PIXEL),
                       ("noise", label != NoiseClass.SIGNAL), ("signal", label == NoiseClass.SIGNAL)):
        n = int(np.count_nonzero(mask))
        out[name] = _ratio(int(np.count_nonzero(removed & mask)), n)
    return out


def summary(label, keep) -> dict[str, float]:
    """Everything at one operating point: counts, EDP, ESNR, TPR, FPR and removal per class."""
    c = confusion(label, keep)
    out: dict[str, float] = dict(c)
    out.update(edp=edp(label, keep), esnr_db=esnr(label, keep), tpr=tpr(label, keep), fpr=fpr(label, keep))
    out.update({f"removed_{k}": v for k, v in removal_rates(label, keep).items()})
    return out


# -- ROC -----------------------------------------------------------------------------------------
def _roc_counts(label, score):
    """Cumulative (tp, fp) at each distinct score, highest first, and the scores; plus class totals."""
    if label is None or score is None:
        raise ValueError("ROC needs ground-truth labels and per-event scores (got None)")
    label = np.asarray(label)
    score = np.asarray(score, dtype=np.float64)
    if label.shape != score.shape:
        raise ValueError(f"label has {label.size} events, score has {score.size}")
    sig = label == NoiseClass.SIGNAL
    n_pos, n_neg = int(np.count_nonzero(sig)), int(label.size - np.count_nonzero(sig))
    seen = ~np.isnan(score)
    s, pos = score[seen], sig[seen]
    order = np.argsort(-s, kind="stable")
    s, pos = s[order], pos[order]
    tp = np.cumsum(pos, dtype=np.int64)
    fp = np.arange(1, len(s) + 1, dtype=np.int64) - tp
    # the last index of each run of equal scores (== also holds between infinities of one sign)
    last_of_tie = np.flatnonzero(np.append(s[:-1] != s[1:], True)) if len(s) else np.zeros(0, np.int64)
    return tp[last_of_tie], fp[last_of_tie], s[last_of_tie], n_pos, n_neg


def roc_curve(label, score) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(fpr, tpr, thresholds): one point per distinct score, thresholds decreasing; an event is kept at
    threshold θ iff `score >= θ`. The curve starts at (0, 0) with threshold +inf (keep nothing). NaN
    scores are never kept, so the curve may end below (1, 1). FPR (TPR) is NaN without noise (signal)."""
    tp, fp, thr, n_pos, n_neg = _roc_counts(label, score)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.concatenate(([0], tp)) / (n_pos if n_pos else np.nan)
        f = np.concatenate(([0], fp)) / (n_neg if n_neg else np.nan)
    return f, t, np.concatenate(([np.inf], thr))


def auc(fpr: np.ndarray, tpr: np.ndarray) -> float:
    """Area under a curve given by points in order (trapezoids); NaN if any coordinate is NaN."""
    fpr, tpr = np.asarray(fpr, np.float64), np.asarray(tpr, np.float64)
    if len(fpr) < 2 or np.isnan(fpr).any() or np.isnan(tpr).any():
        return math.nan
    return float(np.sum(np.diff(fpr) * (tpr[1:] + tpr[:-1]) / 2))


def roc_auc(label, score) -> float:
    """ROC AUC of the scores, the curve closed to (1, 1) by a straight segment (keeping the unscored
    events at random); 0.5 is chance, 1 a perfect ranking. NaN without signal or without noise."""
    f, t, _ = roc_curve(label, score)
    if len(f) and (f[-1] < 1 or t[-1] < 1):
        f, t = np.append(f, 1.0), np.append(t, 1.0)
    return auc(f, t)


def operating_point(label, score, tpr_target: float) -> dict[str, float]:
    """The highest threshold that keeps at least `tpr_target` of the signal, and the metrics there
    (threshold, tpr, fpr, edp, esnr_db, tp, fp). This is how methods are compared honestly: EDP at
    matched signal kept. NaN metrics if no threshold reaches the target (too much signal scored NaN)."""
    if not 0 < tpr_target <= 1:
        raise ValueError(f"tpr_target must be in (0, 1], got {tpr_target}")
    tp, fp, thr, n_pos, n_neg = _roc_counts(label, score)
    nan = {"threshold": math.nan, "tpr": math.nan, "fpr": math.nan, "edp": math.nan, "esnr_db": math.nan,
           "tp": math.nan, "fp": math.nan}
    if n_pos == 0:
        return nan
    reach = np.flatnonzero(tp >= tpr_target * n_pos - 1e-9)
    if not len(reach):
        return nan
    i = int(reach[0])
    a, b = int(tp[i]), int(fp[i])
    return {"threshold": float(thr[i]), "tpr": a / n_pos, "fpr": _ratio(b, n_neg), "edp": 100.0 * a / (a + b),
            "esnr_db": _esnr(a, b), "tp": a, "fp": b}


def edp_at_tpr(label, score, tpr_target: float) -> float:
    """EDP at the highest threshold keeping at least `tpr_target` of the signal (see `operating_point`)."""
    return operating_point(label, score, tpr_target)["edp"]


# -- ESR (no labels) -----------------------------------------------------------------------------
def esr(x, y, geometry: Geometry) -> float:
    """Event Structural Ratio of one packet of events — Ding et al., E-MLB (IEEE TMM 2023), the
    paper's definition (E-MLB's `EventStructuralRatio`, not its later median-filtered "V2"):

        n_i  = events at pixel i (polarity ignored), N = Σ n_i, K = W·H pixels, M = floor(2N/3)
        NTSS = Σ n_i (n_i − 1) / (N (N − 1))
        L_N  = K − Σ (1 − M/N)^{n_i}
        ESR  = sqrt(NTSS · L_N)

    NTSS rises when events pile up on few pixels (edges), L_N counts the pixels a packet covers. Higher
    is meant to be cleaner; it is a heuristic (noise landing on silent pixels raises L_N), measured to
    fall as background noise is added to our synthetic scenes (tests/test_metrics.py). Compare packets
    of equal N only. NaN for fewer than 2 events."""
    x = np.asarray(x, np.int64)
    y = np.asarray(y, np.int64)
    n_events = len(x)
    if n_events < 2:
        return math.nan
    k = geometry.n_pixels
    n = np.bincount(y * geometry.width + x, minlength=k).astype(np.float64)
    m = (2 * n_events) // 3
    ntss = float(np.sum(n * (n - 1))) / (n_events * (n_events - 1))
    l_n = k - float(np.sum((1.0 - m / n_events) ** n))
    return math.sqrt(max(ntss * l_n, 0.0))


def esr_parts(x, y, geometry: Geometry) -> tuple[float, float, float]:
    """(NTSS, L_N, ESR) of one packet, as `esr` defines them (NaN for fewer than 2 events)."""
    x = np.asarray(x, np.int64)
    y = np.asarray(y, np.int64)
    n_events = len(x)
    if n_events < 2:
        return math.nan, math.nan, math.nan
    n = np.bincount(y * geometry.width + x, minlength=geometry.n_pixels).astype(np.float64)
    m = (2 * n_events) // 3
    ntss = float(np.sum(n * (n - 1))) / (n_events * (n_events - 1))
    l_n = geometry.n_pixels - float(np.sum((1.0 - m / n_events) ** n))
    return ntss, l_n, math.sqrt(max(ntss * l_n, 0.0))


def mean_esr(x, y, geometry: Geometry, packet_events: int = 30_000) -> float:
    """Mean ESR over consecutive packets of `packet_events` events (E-MLB's protocol: 30 000 events, the
    incomplete last packet dropped); NaN when there is not one full packet."""
    if packet_events < 2:
        raise ValueError(f"packet_events must be >= 2, got {packet_events}")
    x, y = np.asarray(x), np.asarray(y)
    n_packets = len(x) // packet_events
    if n_packets == 0:
        return math.nan
    return float(np.mean([esr(x[i * packet_events:(i + 1) * packet_events],
                              y[i * packet_events:(i + 1) * packet_events], geometry)
                          for i in range(n_packets)]))
