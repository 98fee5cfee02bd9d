"""Khodamoradi & Kastner's O(N)-memory filter (IEEE TETC 2018): one memory cell per column and per row.

Instead of a timestamp per pixel (O(W·H)), the filter keeps, for each column x, the latest event that
fell in that column (its row, timestamp, polarity) and, for each row y, the latest event in that row
(its column, timestamp, polarity): O(W + H). Event m at (x, y, t, p) collects one unit of support from
each of the six cells (columns x-1, x, x+1 and rows y-1, y, y+1) whose stored event lies in m's 8-pixel
neighbourhood (m's own pixel excluded), fired within `tau_us` (`t - t_j <= tau_us`) and, with
`polarity_match`, has m's polarity. SIGNAL iff support >= k. Then m is stored in column x and row y.
A neighbour found through both its column and its row counts twice, as in the reference code.
Defaults from the E-MLB benchmark's reference implementation (`khodamoradi_noise`, Ding et al. 2023),
which the seed paper also uses for this filter: tau = 2 ms, k = 1, polarity must match.

Score: the support count (0..6); kept iff `score >= k`. The state does not depend on k, so one pass
gives the exact ROC curve over k (a coarse one: seven points at most).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..events import EventChunk, shown
from ..jit import njit
from ..pipeline import register
from .common import NEVER_US, NO_SCORE, ScoredClassifier, check, is_int


@functools.cache
def khodamoradi_kernel(want_score):
    """The kernel with or without the score (a compile-time constant: `classify` computes none)."""

    @njit(cache=True, nogil=True)
    def kernel(t, x, y, p, col_t, col_y, col_p, row_t, row_x, row_p, tau_us, match, k, out, score):
        """Class codes (0 SIGNAL, 1 BACKGROUND) and support counts; the column cells (`col_*`, length
        W + 2) and row cells (`row_*`, length H + 2) are padded by one and updated in place."""
        for i in range(len(t)):
            ti = t[i]
            pi = p[i]
            xi = np.int64(x[i])
            yi = np.int64(y[i])
            s = 0
            for d in range(-1, 2):
                c = xi + 1 + d  # column cell x+d (padded index): its event must be within a row of y
                if ti - col_t[c] <= tau_us and (not match or col_p[c] == pi):
                    dy = np.int64(col_y[c]) - yi
                    if -1 <= dy <= 1 and (d != 0 or dy != 0):
                        s += 1
                r = yi + 1 + d  # row cell y+d: its event must be within a column of x
                if ti - row_t[r] <= tau_us and (not match or row_p[r] == pi):
                    dx = np.int64(row_x[r]) - xi
                    if -1 <= dx <= 1 and (d != 0 or dx != 0):
                        s += 1
            out[i] = 0 if s >= k else 1
            if want_score:
                score[i] = s
            col_t[xi + 1] = ti
            col_y[xi + 1] = yi
            col_p[xi + 1] = pi
            row_t[yi + 1] = ti
            row_x[yi + 1] = xi
            row_p[yi + 1] = pi

    return kernel


@register("stage", "khodamoradi")
@dataclass
class KhodamoradiFilter(ScoredClassifier):
    """O(W + H)-memory BA filter: SIGNAL iff >= `k` column/row cells hold a neighbour within `tau_us`."""

    tau_us: int = 2000
    k: int = 1
    polarity_match: bool = True

    def __post_init__(self):
        check(is_int(self.tau_us) and self.tau_us > 0, "khodamoradi",
              f"tau_us must be a positive integer, got {shown(self.tau_us)}")
        check(is_int(self.k) and 1 <= self.k <= 6, "khodamoradi", f"k must be an integer in 1..6, got {shown(self.k)}")
        check(isinstance(self.polarity_match, (bool, np.bool_)), "khodamoradi", "polarity_match must be a bool")
        self.tau_us, self.k, self.polarity_match = int(self.tau_us), int(self.k), bool(self.polarity_match)
        self._cols = self._rows = None

    @property
    def history_us(self) -> int:
        """Warm-up before decisions are at full strength: one correlation time."""
        return self.tau_us

    def _allocate(self, g):
        # (timestamp, position along the line, polarity); padded cells never fire
        self._cols = (np.full(g.width + 2, NEVER_US, np.int64), np.zeros(g.width + 2, np.int32),
                      np.zeros(g.width + 2, np.uint8))
        self._rows = (np.full(g.height + 2, NEVER_US, np.int64), np.zeros(g.height + 2, np.int32),
                      np.zeros(g.height + 2, np.uint8))

    def _run(self, chunk: EventChunk, want_score: bool) -> tuple[np.ndarray, np.ndarray]:
        self._ensure_state(chunk)
        out = np.empty(len(chunk), np.uint8)
        score = np.empty(len(chunk), np.float64) if want_score else NO_SCORE
        khodamoradi_kernel(want_score)(chunk.t, chunk.x, chunk.y, chunk.p, *self._cols, *self._rows, self.tau_us,
                                       self.polarity_match, self.k, out, score)
        return out, score

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        return self._run(chunk, True)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        return self._run(chunk, False)[0]
