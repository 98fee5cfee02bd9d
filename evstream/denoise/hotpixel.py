"""Online hot-pixel learner: a pixel whose rate over the last learning window was too high is hot.

Time is cut into windows of `window_us` anchored at t = 0 (never at a chunk start, so the result does
not depend on chunking). Each pixel's events are counted per window; during window k+1, an event is
HOT_PIXEL iff its pixel's rate in window k was >= `rate_hz` (a pixel silent in window k, or a gap of
more than one window, counts as rate 0). Learning never stops, so a pixel that turns hot (or heals)
is caught one window later. Every event the stage sees is counted.

iniVation's reference learner (libcaer `filters/dvs_noise.c`) learns once, over 1 s, with a 10 kHz
threshold — tuned for pixels stuck at very high rates. We keep its 1 s window but default to 100 Hz,
so that most of the 50–2000 Hz hot pixels of DVS data sets (and of `evstream.noise`) are caught while
moving edges, which visit a pixel briefly, are not: the busiest signal pixel of our synthetic scenes
at 346×260 fires 34 Hz over 1 s (turntable; bar 11 Hz, ball 30 Hz). Tune `rate_hz` to the scene.

Score: minus the pixel's rate (Hz) in the previous window; kept iff `score > -rate_hz`. The state does
not depend on the threshold, so one pass gives the exact ROC curve over `rate_hz`.
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
def hotpixel_kernel(want_score):
    """The kernel with or without the score (a compile-time constant: `classify` computes none)."""

    @njit(cache=True, nogil=True)
    def kernel(t, x, y, counts, prev, cur_window, window_us, min_count, out, score):
        """Class codes (0 SIGNAL, 2 HOT_PIXEL) and scores. `counts` (H, W) counts the current window,
        `prev` (H, W) the previous one, `cur_window[0]` is the current window index; all in place."""
        window_s = window_us * 1e-6
        for i in range(len(t)):
            w = t[i] // window_us
            if w != cur_window[0]:
                h, wd = counts.shape
                adjacent = w == cur_window[0] + 1
                for r in range(h):
                    for c in range(wd):
                        prev[r, c] = counts[r, c] if adjacent else 0
                        counts[r, c] = 0
                cur_window[0] = w
            n_prev = prev[y[i], x[i]]
            out[i] = 2 if n_prev >= min_count else 0
            if want_score:
                score[i] = -(n_prev / window_s)
            counts[y[i], x[i]] += 1

    return kernel


@register("stage", "hotpixel")
@dataclass
class HotPixelLearner(ScoredClassifier):
    """HOT_PIXEL iff the pixel fired at >= `rate_hz` over the previous `window_us` window."""

    window_us: int = 1_000_000
    rate_hz: float = 100.0

    def __post_init__(self):
        check(is_int(self.window_us) and self.window_us > 0, "hotpixel",
              f"window_us must be a positive integer, got {shown(self.window_us)}")
        check(isinstance(self.rate_hz, (int, float)) and not isinstance(self.rate_hz, bool)
              and self.rate_hz > 0, "hotpixel", f"rate_hz must be a positive number, got {shown(self.rate_hz)}")
        self.window_us, self.rate_hz = int(self.window_us), float(self.rate_hz)
        # rate >= rate_hz  <=>  count >= rate_hz * window_s (counts are integers)
        self._min_count = max(1, int(np.ceil(self.rate_hz * self.window_us * 1e-6 - 1e-9)))
        self._counts = self._prev = None
        self._cur_window = np.array([NEVER_US], np.int64)

    @property
    def history_us(self) -> int:
        """Time before the learner can flag anything: at most two windows (a partial one, then a full one)."""
        return 2 * self.window_us

    def _allocate(self, g):
        self._counts = np.zeros((g.height, g.width), np.int64)
        self._prev = np.zeros((g.height, g.width), np.int64)

    def _run(self, chunk: EventChunk, want_score: bool) -> tuple[np.ndarray, np.ndarray]:
        self._ensure_state(chunk)
        out = np.empty(len(chunk), np.uint8)
        score = np.empty(len(chunk), np.float64) if want_score else NO_SCORE
        hotpixel_kernel(want_score)(chunk.t, chunk.x, chunk.y, self._counts, self._prev, self._cur_window,
                                    self.window_us, self._min_count, out, score)
        return out, score

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        return self._run(chunk, True)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        return self._run(chunk, False)[0]


assert NoiseClass.HOT_PIXEL == 2  # the kernel writes this code
