"""Feng et al.'s event-density filter, "YNoise" (Appl. Sci. 2020, 10(6):2024), with its hot-pixel test.

Two tests in one pass:

1. density (background activity): D(m) = the pixels of m's L×L neighbourhood (L = 2r+1, m's own
   pixel included) whose latest event came within `window_us` before t (`t - t_j < window_us`) and,
   with `polarity_match`, had m's polarity — the L1 norm of the paper's binary density matrix.
   BACKGROUND iff D < threshold.
2. hot-pixel ratio (for events that pass 1): over the longer `hot_window_us`, c = past events of m's
   own pixel (the last `count_cap` are kept per pixel) and s = neighbour pixels active in that window.
   HOT_PIXEL iff c >= hot_min_events and c / (c + s) >= hot_ratio: the neighbourhood's activity is
   concentrated on one pixel, which fires again and again.

Test 1 and its defaults follow the E-MLB benchmark's reference implementation (`yang_noise`, Ding et
al. 2023): window 2 ms, radius 1, threshold 1, polarity matched. Test 2 is our reconstruction of the
paper's flicker decision with ratio R (the reference code has no hot-pixel stage and the paper's
constants did not survive in our copy): 50 ms, at least 3 events, ratio 0.5 — it flags a pixel firing
at >= 60 Hz while its neighbours are mostly quiet. Simplification: one state fed by every event the
stage sees (the paper feeds its hot-pixel stage with the density stage's output only).

Score: D for events not flagged hot, -1 for hot ones; kept iff `score >= threshold`, so one pass gives
the exact ROC curve over the density threshold (hot test fixed).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..events import EventChunk, NoiseClass, shown
from ..jit import njit
from ..pipeline import register
from .common import NEVER_US, NO_SCORE, ScoredClassifier, check, is_int


@functools.cache
def ynoise_kernel(want_score):
    """The kernel with or without the score (a compile-time constant: `classify` computes none)."""

    @njit(cache=True, nogil=True)
    def kernel(t, x, y, p, last, last_p, ring, head, radius, window_us, match, threshold, hot_window_us,
               hot_min_events, hot_ratio, out, score):
        """Class codes and scores. `last`/`last_p` (H+2r, W+2r) hold each pixel's latest event, `ring`
        (H+2r, W+2r, K) its last K timestamps, `head` the next ring slot; all updated in place."""
        cap = ring.shape[2]
        for i in range(len(t)):
            ti = t[i]
            pi = p[i]
            r0 = y[i] + radius
            c0 = x[i] + radius
            density = 0
            around = 0
            for r in range(r0 - radius, r0 + radius + 1):
                for c in range(c0 - radius, c0 + radius + 1):
                    age = ti - last[r, c]
                    if age < window_us and (not match or last_p[r, c] == pi):
                        density += 1
                    if age < hot_window_us and (r != r0 or c != c0):
                        around += 1
            if density < threshold:
                out[i] = 1
                if want_score:
                    score[i] = density
            else:
                own = 0
                slot = head[r0, c0]
                for _ in range(cap):  # newest first: the first one past the window ends the count
                    slot = slot - 1 if slot > 0 else cap - 1
                    if ti - ring[r0, c0, slot] >= hot_window_us:
                        break
                    own += 1
                if own >= hot_min_events and own >= hot_ratio * (own + around):
                    out[i] = 2
                    if want_score:
                        score[i] = -1.0
                else:
                    out[i] = 0
                    if want_score:
                        score[i] = density
            h = head[r0, c0]
            ring[r0, c0, h] = ti
            head[r0, c0] = h + 1 if h + 1 < cap else 0
            last[r0, c0] = ti
            last_p[r0, c0] = pi

    return kernel


@register("stage", "ynoise")
@dataclass
class YNoiseFilter(ScoredClassifier):
    """Event-density filter (BACKGROUND if sparse) with a hot-pixel ratio test (HOT_PIXEL)."""

    window_us: int = 2000
    radius_px: int = 1
    threshold: int = 1
    polarity_match: bool = True
    hot_window_us: int = 50_000
    hot_min_events: int = 3
    hot_ratio: float = 0.5
    count_cap: int = 4

    def __post_init__(self):
        def positive_int(name, hi=None):
            v = getattr(self, name)
            ok = is_int(v) and v >= 1 and (hi is None or v <= hi)
            check(ok, "ynoise", f"{name} must be an integer in 1..{hi or 'inf'}, got {shown(v)}")
            setattr(self, name, int(v))

        positive_int("window_us")
        positive_int("radius_px", 8)
        positive_int("count_cap", 64)
        positive_int("threshold")
        positive_int("hot_window_us")
        positive_int("hot_min_events", self.count_cap)
        check(isinstance(self.polarity_match, (bool, np.bool_)), "ynoise", "polarity_match must be a bool")
        check(isinstance(self.hot_ratio, (int, float)) and 0 < self.hot_ratio <= 1, "ynoise",
              f"hot_ratio must be in (0, 1], got {shown(self.hot_ratio)}")
        self.polarity_match, self.hot_ratio = bool(self.polarity_match), float(self.hot_ratio)
        self._last = self._last_p = self._ring = self._head = None

    @property
    def history_us(self) -> int:
        """Warm-up before decisions are at full strength: the longer of the two windows."""
        return max(self.window_us, self.hot_window_us)

    def _allocate(self, g):
        r = self.radius_px
        shape = (g.height + 2 * r, g.width + 2 * r)
        self._last = np.full(shape, NEVER_US, np.int64)
        self._last_p = np.zeros(shape, np.uint8)
        self._ring = np.full((*shape, self.count_cap), NEVER_US, np.int64)
        self._head = np.zeros(shape, np.uint8)

    def _run(self, chunk: EventChunk, want_score: bool) -> tuple[np.ndarray, np.ndarray]:
        self._ensure_state(chunk)
        out = np.empty(len(chunk), np.uint8)
        score = np.empty(len(chunk), np.float64) if want_score else NO_SCORE
        ynoise_kernel(want_score)(chunk.t, chunk.x, chunk.y, chunk.p, self._last, self._last_p, self._ring,
                                  self._head, self.radius_px, self.window_us, self.polarity_match, self.threshold,
                                  self.hot_window_us, self.hot_min_events, self.hot_ratio, out, score)
        return out, score

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        return self._run(chunk, True)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        return self._run(chunk, False)[0]


assert (NoiseClass.BACKGROUND, NoiseClass.HOT_PIXEL) == (1, 2)  # the kernel writes these codes
