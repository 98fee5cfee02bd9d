"""Labelled noise injection: background activity and hot pixels, each event keeping its true class.

Background activity (BA) is a Poisson process per pixel with random polarity; hot pixels are a fixed
set of pixels firing at 50–2000 Hz. The amount is given either as a physical rate (Hz per pixel, as
the DND21 benchmark does) or as the paper's noise ratio (noise events / signal events), which ties
the noise to the scene's own event rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .events import EventChunk, NoiseClass


@dataclass(frozen=True)
class NoiseSpec:
    """How much noise to add.

    Give `noise_ratio` (total noise events per signal event, e.g. 0.5 for the paper's 50 %), of which
    `hot_share` comes from hot pixels; or give `ba_rate_hz` (per pixel) and `hot_pixels` (a count).
    `ba_spread` > 0 draws each pixel's BA rate from a log-normal of that sigma (real sensors vary).
    """

    noise_ratio: float | None = None
    hot_share: float = 0.1
    ba_rate_hz: float | None = None
    hot_pixels: int = 0
    hot_rate_hz: tuple[float, float] = (50.0, 2000.0)
    ba_spread: float = 0.0

    def __post_init__(self):
        if (self.noise_ratio is None) == (self.ba_rate_hz is None):
            raise ValueError("give exactly one of noise_ratio and ba_rate_hz")
        if self.noise_ratio is not None and self.noise_ratio < 0:
            raise ValueError(f"noise_ratio must be >= 0, got {self.noise_ratio}")
        if self.ba_rate_hz is not None and self.ba_rate_hz < 0:
            raise ValueError(f"ba_rate_hz must be >= 0, got {self.ba_rate_hz}")
        if not 0 <= self.hot_share <= 1:
            raise ValueError(f"hot_share must be in [0, 1], got {self.hot_share}")
        lo, hi = self.hot_rate_hz
        if not 0 < lo <= hi:
            raise ValueError(f"hot_rate_hz must be (low, high) with 0 < low <= high, got {self.hot_rate_hz}")


def inject(signal: EventChunk, spec: NoiseSpec, seed=0, *, t_start_us=None, t_stop_us=None) -> EventChunk:
    """Return `signal` (labelled SIGNAL unless it already has labels) merged in time order with
    labelled noise over [t_start_us, t_stop_us) (default: the signal's span)."""
    rng = np.random.default_rng(seed)
    g = signal.geometry
    t0 = int(signal.t[0]) if t_start_us is None and len(signal) else int(t_start_us or 0)
    t1 = int(signal.t[-1]) + 1 if t_stop_us is None and len(signal) else int(t_stop_us or t0)
    span_s = max(t1 - t0, 0) * 1e-6
    if spec.noise_ratio is not None:
        budget = spec.noise_ratio * len(signal)
        hot_rates = _hot_rates_for_budget(rng, spec, spec.hot_share * budget / span_s if span_s else 0)
        ba_rate = (budget - hot_rates.sum() * span_s) / (g.n_pixels * span_s) if span_s else 0.0
    else:
        hot_rates = rng.uniform(*spec.hot_rate_hz, spec.hot_pixels) if spec.hot_pixels else np.zeros(0)
        ba_rate = spec.ba_rate_hz
    ba = _background(rng, g, t0, t1, max(ba_rate, 0.0), spec.ba_spread)
    hot = _hot_pixels(rng, g, t0, t1, hot_rates)
    label = signal.label if signal.label is not None else np.zeros(len(signal), np.uint8)
    parts = [(signal.t, signal.x, signal.y, signal.p, label), ba, hot]
    t, x, y, p, lab = (np.concatenate(a) for a in zip(*parts))
    order = np.argsort(t, kind="stable")  # signal first among equal timestamps
    return EventChunk.from_arrays(t[order], x[order], y[order], p[order], g, label=lab[order],
                                  t_end=max(signal.t_end, t1 - 1))


def _hot_rates_for_budget(rng, spec: NoiseSpec, rate_budget_hz: float) -> np.ndarray:
    """Draw hot-pixel rates until their sum reaches the budget (at least one pixel if any budget)."""
    rates = []
    while sum(rates) < rate_budget_hz:
        r = float(rng.uniform(*spec.hot_rate_hz))
        rates.append(min(r, rate_budget_hz - sum(rates)) if rates else r)
    return np.array(rates)


def _background(rng, g, t0, t1, rate_hz, spread):
    n_pix = g.n_pixels
    span_s = (t1 - t0) * 1e-6
    if spread > 0:
        weights = rng.lognormal(0.0, spread, n_pix)
        weights /= weights.sum()
        counts = rng.poisson(weights * rate_hz * n_pix * span_s)
        pix = np.repeat(np.arange(n_pix), counts)
    else:
        pix = rng.integers(0, n_pix, rng.poisson(rate_hz * n_pix * span_s))
    return _events(rng, g, t0, t1, pix, NoiseClass.BACKGROUND)


def _hot_pixels(rng, g, t0, t1, rates_hz):
    where = rng.choice(g.n_pixels, size=len(rates_hz), replace=False)
    counts = rng.poisson(rates_hz * (t1 - t0) * 1e-6)
    return _events(rng, g, t0, t1, np.repeat(where, counts), NoiseClass.HOT_PIXEL)


def _events(rng, g, t0, t1, pix, label):
    n = len(pix)
    t = rng.integers(t0, max(t1, t0 + 1), n).astype(np.int64)
    return (t, (pix % g.width).astype(np.uint16), (pix // g.width).astype(np.uint16),
            rng.integers(0, 2, n).astype(np.uint8), np.full(n, label, np.uint8))


# -- conditions and the clean signal they are injected into (evaluation and training share them) --
@dataclass(frozen=True)
class Condition:
    """One noise condition: a ratio (noise events per signal event) or a background rate (Hz/pixel)."""

    noise_ratio: float | None = None
    ba_rate_hz: float | None = None

    @property
    def name(self) -> str:
        if self.noise_ratio is not None:
            return f"{round(100 * self.noise_ratio)}%"
        return f"{self.ba_rate_hz:g}Hz"

    def spec(self) -> NoiseSpec:
        if self.noise_ratio is not None:
            return NoiseSpec(noise_ratio=self.noise_ratio, hot_share=0.1)
        return NoiseSpec(ba_rate_hz=self.ba_rate_hz)


def find_hot_pixels(events: EventChunk, factor: float = 10.0, min_events: int = 20) -> np.ndarray:
    """Flat indices of pixels firing far more than their 8 neighbours: at least `min_events` and more
    than `factor` × (their neighbours' mean + 1). These are a real sensor's own hot pixels."""
    g = events.geometry
    counts = np.bincount(events.y.astype(np.int64) * g.width + events.x, minlength=g.n_pixels)
    img = counts.reshape(g.height, g.width).astype(np.float64)
    padded = np.pad(img, 1)
    nb = sum(padded[1 + dy : 1 + dy + g.height, 1 + dx : 1 + dx + g.width]
             for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)) / 8.0
    hot = (img >= min_events) & (img > factor * (nb + 1.0))
    return np.flatnonzero(hot.reshape(-1))


def as_signal(events: EventChunk, set_aside_hot: bool = True) -> tuple[EventChunk, dict]:
    """The clean signal of a recording, labelled SIGNAL: its SIGNAL-labelled events if it has labels,
    else all its events minus its own hot pixels (set aside, counted in the returned notes)."""
    notes = {"hot_pixels_set_aside": 0, "hot_events_set_aside": 0}
    if events.label is not None:
        events = events[events.label == NoiseClass.SIGNAL]
    elif set_aside_hot and len(events):
        hot = find_hot_pixels(events)
        if len(hot):
            pix = events.y.astype(np.int64) * events.geometry.width + events.x
            drop = np.isin(pix, hot)
            notes = {"hot_pixels_set_aside": int(len(hot)), "hot_events_set_aside": int(drop.sum())}
            events = events[~drop]
    events = events.replace(label=np.zeros(len(events), np.uint8), cls=None)
    return events, notes
