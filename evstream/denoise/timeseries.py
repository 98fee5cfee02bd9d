"""Fine stage of Jiang et al. (Sensors 2024): time-sequence (DC component) analysis against hot pixels.

Reconstruction (see docs/method.md). Each pixel has a Boolean activity series sampled at `rate_hz`
(fs): bin k covers [k/fs, (k+1)/fs), anchored at t = 0 — never at a chunk start, so the result does
not depend on chunking. Over the last n bins the DFT's DC component of a Boolean series is the
fraction of active bins, DC ∈ [0, 1]. An event is HOT_PIXEL iff its pixel's DC exceeds the mean DC of
its neighbours by more than λ (`difference` form), or exceeds λ times that mean (`ratio` form).

The activity state is fed by every event this stage sees — in the cascade, the events the coarse stage
kept — including the events it classes HOT_PIXEL (a hot pixel must stay hot). One uint64 bitmask per
pixel holds the last n <= 64 bins; DC is a popcount.

Limits: it needs about n/fs of history before a hot pixel's DC is fully built; and a hot pixel firing
at rate f sets a fraction 1 - exp(-f/fs) of the bins, so pixels slower than about λ·fs are missed
(lower λ or fs for slow hot pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from ..events import EventChunk, NoiseClass
from ..pipeline import register
from .base import InPlaceClassifier

DIFFERENCE, RATIO = 0, 1


@njit(cache=True, nogil=True, inline="always")
def popcount64(v):
    """Number of set bits of a uint64 (SWAR)."""
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True, nogil=True, inline="always")
def _aligned(mask, last_bin, b):
    """A pixel's activity mask shifted so that bit 0 is bin b (bits age out after 64 bins)."""
    shift = b - last_bin
    if shift >= 64:
        return np.uint64(0)
    return mask << np.uint64(shift)


@njit(cache=True, nogil=True)
def dc_kernel(t, x, y, codes, noise_code, masks, last_bin, radius, bin_us, n_bins, lam, form, width, height,
              want_score, out_score):
    """For each event still SIGNAL in `codes`: update its pixel's activity, compare its DC with its
    neighbours' mean, write `noise_code` when hot (and the score if `want_score`).

    `masks`/`last_bin` are (H + 2r, W + 2r), padded with never-active cells, so the neighbourhood loop
    needs no bounds checks; the neighbour count is clipped to the sensor arithmetically. The score is
    DC_m - mean (difference form) or DC_m / mean (ratio form; inf when mean is 0). Without scores, the
    difference form skips the neighbours when DC_m <= λ (the event cannot be hot).
    """
    window = (np.uint64(1) << np.uint64(n_bins)) - np.uint64(1) if n_bins < 64 else ~np.uint64(0)
    L = 2 * radius + 1
    lam_bins = lam * n_bins
    b = np.int64(0)
    bin_start = np.int64(1)  # [bin_start, bin_end) is bin b; empty until the first event
    bin_end = np.int64(0)
    for i in range(len(t)):
        if codes[i] != 0:
            continue
        ti = t[i]
        if ti >= bin_end or ti < bin_start:  # a division only when the bin changes
            b = ti // bin_us
            bin_start = b * bin_us
            bin_end = bin_start + bin_us
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        cy = yi + radius
        cx = xi + radius
        m = (_aligned(masks[cy, cx], last_bin[cy, cx], b) | np.uint64(1)) & window
        masks[cy, cx] = m
        last_bin[cy, cx] = b
        own = popcount64(m)
        if form == DIFFERENCE and not want_score and own <= lam_bins:
            continue  # DC_m <= λ: cannot be hot
        active = 0
        for dy in range(L):
            for dx in range(L):
                if dy != radius or dx != radius:
                    nb = _aligned(masks[yi + dy, xi + dx], last_bin[yi + dy, xi + dx], b)
                    active += popcount64(nb & window)
        n_nb = ((min(xi + radius, width - 1) - max(xi - radius, 0) + 1)
                * (min(yi + radius, height - 1) - max(yi - radius, 0) + 1) - 1)
        # decisions in whole bins (exact): DC_m - mean > λ  <=>  own·n_nb - active > λ·n·n_nb
        if form == DIFFERENCE:
            hot = own * n_nb - active > lam_bins * n_nb if n_nb > 0 else own > lam_bins
        else:
            hot = own * n_nb > lam * active if active > 0 else own > lam  # guard: quiet neighbours
        if want_score:
            dc = own / n_bins
            mean = active / (n_nb * n_bins) if n_nb > 0 else 0.0
            if form == DIFFERENCE:
                score = dc - mean
            else:
                score = dc / mean if mean > 0 else np.inf
        codes[i] = noise_code * hot
        if want_score:
            out_score[i] = score


@register("stage", "dc")
@dataclass
class TimeSeriesFilter(InPlaceClassifier):
    """Hot-pixel filter by the DC component of each pixel's activity series (fine stage).

    `rate_hz` fs: activity sampling rate (bins of 1/fs anchored at t = 0); `n_bins` n <= 64: bins in
    the window (n/fs of history); `lam` λ: the DC margin over the neighbours' mean (difference form) or
    the factor (ratio form); `radius_px`: neighbourhood half-size (1 -> the 8 neighbours).
    Score (`classify_scored`): DC_m - mean (difference; hot iff > λ) or DC_m / mean (ratio).
    """

    rate_hz: float = 250.0
    n_bins: int = 64
    lam: float = 0.1
    form: str = "difference"
    radius_px: int = 1
    noise_class = NoiseClass.HOT_PIXEL
    _state: dict | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        if not (self.rate_hz > 0 and math.isfinite(self.rate_hz)) or 1e6 / self.rate_hz != int(1e6 / self.rate_hz):
            raise ValueError(f"rate_hz must divide 1 MHz (bins of whole µs), got {self.rate_hz}")
        if not isinstance(self.n_bins, int) or not 1 <= self.n_bins <= 64:
            raise ValueError(f"n_bins must be an integer in 1..64 (one uint64 per pixel), got {self.n_bins!r}")
        if self.form not in ("difference", "ratio"):
            raise ValueError(f"form must be 'difference' or 'ratio', got {self.form!r}")
        if not math.isfinite(self.lam) or (self.form == "difference" and not 0 <= self.lam < 1) or self.lam < 0:
            raise ValueError(f"lam must be in [0, 1) for the difference form, >= 0 for ratio; got {self.lam}")
        if not isinstance(self.radius_px, int) or self.radius_px < 1:
            raise ValueError(f"radius_px must be an integer >= 1, got {self.radius_px!r}")

    @property
    def bin_us(self) -> int:
        return int(1e6 / self.rate_hz)

    @property
    def history_us(self) -> int:
        """History the filter needs before a hot pixel's DC is fully built: n / fs."""
        return self.n_bins * self.bin_us

    def _run(self, chunk: EventChunk, codes: np.ndarray, want_score: bool) -> np.ndarray:
        """Classify the events of `chunk` whose `codes` are SIGNAL, in place; returns the scores."""
        s = self._state
        g = chunk.geometry
        if s is None or s["geometry"] != g:
            r = self.radius_px
            shape = (g.height + 2 * r, g.width + 2 * r)
            s = self._state = {"geometry": g, "masks": np.zeros(shape, np.uint64),
                               "last_bin": np.full(shape, np.iinfo(np.int64).min // 2, np.int64)}
        score = np.zeros(len(chunk) if want_score else 0, np.float64)
        dc_kernel(chunk.t, chunk.x, chunk.y, codes, int(self.noise_class), s["masks"], s["last_bin"],
                  self.radius_px, self.bin_us, self.n_bins, float(self.lam),
                  DIFFERENCE if self.form == "difference" else RATIO, g.width, g.height, want_score, score)
        return score
