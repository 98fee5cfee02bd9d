"""DWF, the double window filter (Guo & Delbruck, TPAMI 2022): no time constant, just recent positions.

Two FIFO windows hold the positions of the last `window_events` events judged SIGNAL and of the last
`window_events` judged noise. Event m is SIGNAL iff at least `k` positions in the two windows lie
within Manhattan distance `radius_px` of it (a past event at m's own pixel counts); m then joins the
signal window, else the noise window. Memory is O(window), independent of the sensor size, and the
filter adapts to the event rate by itself. Defaults from the E-MLB benchmark's reference
implementation (`double_window_filter`, Ding et al. 2023): 36 events per window, radius 9, k = 1
(the windows start empty here, not filled with events at pixel (0, 0)).

Score: the number of window positions within `radius_px` (0..2·window_events); kept iff `score >= k`.
Which window an event joins depends on k, so the scores give the exact ROC point at the configured k
only; other thresholds read from the same pass are an approximation.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..events import EventChunk, shown
from ..jit import njit
from ..pipeline import register
from .common import NO_SCORE, ScoredClassifier, check, is_int


@functools.cache
def dwf_kernel(want_score):
    """The kernel with or without the score (a compile-time constant): without it no score is written.
    Both count every window position: stopping at k (a branch per position whose outcome the CPU cannot
    predict, and no vector loop) made the class-only kernel 0.84x the scored one at 346x260 and 0.60x at
    1280x720."""

    @njit(cache=True, nogil=True)
    def kernel(x, y, win_x, win_y, fill, head, radius, k, out, score):
        """Class codes (0 SIGNAL, 1 BACKGROUND) and counts. `win_x`/`win_y` are (2, L) rings (row 0
        signal, row 1 noise) with `fill`/`head` per ring, updated in place."""
        for i in range(len(x)):
            xi = np.int64(x[i])
            yi = np.int64(y[i])
            n = 0
            for w in range(2):
                for j in range(fill[w]):
                    if abs(np.int64(win_x[w, j]) - xi) + abs(np.int64(win_y[w, j]) - yi) <= radius:
                        n += 1
            w = 0 if n >= k else 1
            out[i] = w
            if want_score:
                score[i] = n
            h = head[w]
            win_x[w, h] = xi
            win_y[w, h] = yi
            head[w] = (h + 1) % win_x.shape[1]
            if fill[w] < win_x.shape[1]:
                fill[w] += 1

    return kernel


@register("stage", "dwf")
@dataclass
class DoubleWindowFilter(ScoredClassifier):
    """DWF: SIGNAL iff >= `k` of the recent signal and noise positions lie within `radius_px` (L1)."""

    window_events: int = 36
    radius_px: int = 9
    k: int = 1

    def __post_init__(self):
        check(is_int(self.window_events) and 1 <= self.window_events <= 1_000_000, "dwf",
              f"window_events must be an integer in 1..1000000, got {shown(self.window_events)}")
        check(is_int(self.radius_px) and self.radius_px >= 0, "dwf",
              f"radius_px must be a non-negative integer, got {shown(self.radius_px)}")
        check(is_int(self.k) and 1 <= self.k <= 2 * self.window_events, "dwf",
              f"k must be an integer in 1..2*window_events, got {shown(self.k)}")
        self.window_events, self.radius_px, self.k = int(self.window_events), int(self.radius_px), int(self.k)
        self._win_x = np.zeros((2, self.window_events), np.uint16)
        self._win_y = np.zeros((2, self.window_events), np.uint16)
        self._fill = np.zeros(2, np.int64)
        self._head = np.zeros(2, np.int64)

    @property
    def history_us(self) -> int:
        """No time constant: the warm-up is counted in events (2 · window_events), not time."""
        return 0

    def _allocate(self, g):
        pass  # the windows do not depend on the sensor size

    def _run(self, chunk, want_score):
        self._ensure_state(chunk)
        out = np.empty(len(chunk), np.uint8)
        score = np.empty(len(chunk), np.float64) if want_score else NO_SCORE
        dwf_kernel(want_score)(chunk.x, chunk.y, self._win_x, self._win_y, self._fill, self._head, self.radius_px,
                               self.k, out, score)
        return out, score

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        return self._run(chunk, True)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        return self._run(chunk, False)[0]
