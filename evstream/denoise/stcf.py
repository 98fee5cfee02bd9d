"""STCF, the spatio-temporal correlation filter (Guo & Delbruck, TPAMI 2022): k supporters within τ.

Event m at (x, y, t, p) is SIGNAL iff at least `k` pixels of its (2r+1)² neighbourhood, the pixel
itself excluded, have their latest event at t_j with `t - t_j < tau_us` (and, with `polarity_match`,
that latest event has m's polarity). State: the latest timestamp and polarity of every pixel, padded
by r. Defaults from jAER's `SpatioTemporalCorrelationFilter`, the authors' reference implementation:
correlation time 25 ms, `numMustBeCorrelated` 2, one-pixel radius, polarities not matched, the
pixel's own past not counted (`filterHotPixels`).

Score: `-(age of the k-th newest supporting neighbour)` in µs (-inf with fewer than k). The event is
kept iff `score > -tau_us`, and the state does not depend on tau, so one pass gives the exact ROC
curve over tau at fixed k.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..events import EventChunk, shown
from ..jit import njit
from ..pipeline import register
from .common import NEVER_US, ScoredClassifier, check, is_int


@njit(cache=True, nogil=True)
def stcf_kernel(t, x, y, p, last, last_p, width_padded, radius, offsets, k, tau_us, match, out):
    """Class codes (0 SIGNAL, 1 BACKGROUND) into `out`; stops counting at k supporters. `last` and
    `last_p` are the padded (H+2r)·(W+2r) maps, flattened, updated in place; `offsets` are the flat
    offsets of the neighbours (the pixel itself excluded)."""
    for i in range(len(t)):
        ti = t[i]
        centre = (np.int64(y[i]) + radius) * width_padded + np.int64(x[i]) + radius
        lim = ti - tau_us
        n = 0
        for o in offsets:
            q = centre + o
            if last[q] > lim and (not match or last_p[q] == p[i]):
                n += 1
                if n >= k:
                    break
        out[i] = 0 if n >= k else 1
        last[centre] = ti
        last_p[centre] = p[i]


@njit(cache=True, nogil=True)
def stcf_scored_kernel(t, x, y, p, last, last_p, width_padded, radius, offsets, k, tau_us, match, out, score,
                       newest):
    """As `stcf_kernel`, also writing the score; `newest` is scratch of length k (the k newest
    neighbour timestamps, descending)."""
    for i in range(len(t)):
        ti = t[i]
        centre = (np.int64(y[i]) + radius) * width_padded + np.int64(x[i]) + radius
        for j in range(k):
            newest[j] = NEVER_US
        for o in offsets:
            q = centre + o
            v = last[q]
            if v > newest[k - 1] and (not match or last_p[q] == p[i]):
                j = k - 1  # insert v into the descending top-k list
                while j > 0 and newest[j - 1] < v:
                    newest[j] = newest[j - 1]
                    j -= 1
                newest[j] = v
        kth = newest[k - 1]
        out[i] = 0 if ti - kth < tau_us else 1
        score[i] = -np.inf if kth == NEVER_US else -float(ti - kth)
        last[centre] = ti
        last_p[centre] = p[i]


@register("stage", "stcf")
@dataclass
class SpatioTemporalCorrelationFilter(ScoredClassifier):
    """STCF: SIGNAL iff at least `k` neighbours (self excluded) fired within `tau_us`; else BACKGROUND."""

    tau_us: int = 25_000
    k: int = 2
    radius_px: int = 1
    polarity_match: bool = False

    def __post_init__(self):
        check(is_int(self.tau_us) and self.tau_us > 0, "stcf", f"tau_us must be a positive integer, "
                                                               f"got {shown(self.tau_us)}")
        check(is_int(self.radius_px) and 1 <= self.radius_px <= 8, "stcf",
              f"radius_px must be an integer in 1..8, got {shown(self.radius_px)}")
        n_nb = (2 * int(self.radius_px) + 1) ** 2 - 1
        check(is_int(self.k) and 1 <= self.k <= n_nb, "stcf",
              f"k must be an integer in 1..{n_nb} (neighbours of radius {self.radius_px}), got {shown(self.k)}")
        check(isinstance(self.polarity_match, (bool, np.bool_)), "stcf", "polarity_match must be a bool")
        self.tau_us, self.k, self.radius_px = int(self.tau_us), int(self.k), int(self.radius_px)
        self.polarity_match = bool(self.polarity_match)
        self._last = self._last_p = None
        self._newest = np.empty(self.k, np.int64)

    @property
    def history_us(self) -> int:
        """Warm-up before decisions are at full strength: one correlation time."""
        return self.tau_us

    def _allocate(self, g):
        r = self.radius_px
        self._width_padded = g.width + 2 * r
        self._last = np.full((g.height + 2 * r) * self._width_padded, NEVER_US, np.int64)
        self._last_p = np.zeros(len(self._last), np.uint8)
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        keep = (dy != 0) | (dx != 0)
        self._offsets = (dy[keep] * self._width_padded + dx[keep]).astype(np.int64)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        self._ensure_state(chunk)
        out = np.empty(len(chunk), np.uint8)
        stcf_kernel(chunk.t, chunk.x, chunk.y, chunk.p, self._last, self._last_p, self._width_padded,
                    self.radius_px, self._offsets, self.k, self.tau_us, self.polarity_match, out)
        return out

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        self._ensure_state(chunk)
        out = np.empty(len(chunk), np.uint8)
        score = np.empty(len(chunk), np.float64)
        stcf_scored_kernel(chunk.t, chunk.x, chunk.y, chunk.p, self._last, self._last_p, self._width_padded,
                           self.radius_px, self._offsets, self.k, self.tau_us, self.polarity_match, out, score,
                           self._newest)
        return out, score
