"""Refractory filter: a pixel may fire at most once per refractory period.

Event m at pixel (x, y) is HOT_PIXEL iff the same pixel's previous event (whatever its class) came
less than `refractory_us` before it (`t - t_prev < refractory_us`); every event updates the pixel's
timestamp. It caps each pixel's rate at 1 / refractory period, which is what a hot or flickering pixel
breaks, so the events it removes are classed HOT_PIXEL. Default from iniVation's reference
implementation (libcaer `filters/dvs_noise.c`, as in dv-processing's `RefractoryPeriodFilter`):
100 µs, a 10 kHz cap.

Score: `t - t_prev` in µs (+inf for a pixel's first event); kept iff `score >= refractory_us`. The
state does not depend on the period, so one pass gives the exact ROC curve over it.
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
def refractory_kernel(want_score):
    """The kernel with or without the score (a compile-time constant: `classify` computes none)."""

    @njit(cache=True, nogil=True)
    def kernel(t, x, y, last, refractory_us, out, score):
        """Class codes (0 SIGNAL, 2 HOT_PIXEL) and inter-event intervals; `last` (H, W) updated in place."""
        for i in range(len(t)):
            ti = t[i]
            prev = last[y[i], x[i]]
            dt = ti - prev
            out[i] = 0 if dt >= refractory_us else 2
            if want_score:
                score[i] = np.inf if prev == NEVER_US else float(dt)
            last[y[i], x[i]] = ti

    return kernel


@register("stage", "refractory")
@dataclass
class RefractoryFilter(ScoredClassifier):
    """HOT_PIXEL iff the pixel fired less than `refractory_us` before; else SIGNAL."""

    refractory_us: int = 100

    def __post_init__(self):
        check(is_int(self.refractory_us) and self.refractory_us > 0, "refractory",
              f"refractory_us must be a positive integer, got {shown(self.refractory_us)}")
        self.refractory_us = int(self.refractory_us)
        self._last = None

    @property
    def history_us(self) -> int:
        """Warm-up before decisions are at full strength: one refractory period."""
        return self.refractory_us

    def _allocate(self, g):
        self._last = np.full((g.height, g.width), NEVER_US, np.int64)

    def _run(self, chunk: EventChunk, want_score: bool) -> tuple[np.ndarray, np.ndarray]:
        self._ensure_state(chunk)
        out = np.empty(len(chunk), np.uint8)
        score = np.empty(len(chunk), np.float64) if want_score else NO_SCORE
        refractory_kernel(want_score)(chunk.t, chunk.x, chunk.y, self._last, self.refractory_us, out, score)
        return out, score

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        return self._run(chunk, True)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        return self._run(chunk, False)[0]


assert NoiseClass.HOT_PIXEL == 2  # the kernel writes this code
