"""What the baseline filters share: one pass gives class codes and per-event scores, state sized lazily.

Every baseline implements `classify_scored(chunk) -> (codes, scores)` (uint8 `NoiseClass` codes and a
float64 score per event, higher = more signal-like) with the same state update as `classify`, so one
pass over a labelled stream gives a whole ROC curve (`evstream.metrics.roc_curve`). `classify` may take a
faster path (early exit) but must return the same codes. `score(chunk)` is `classify_scored(chunk)[1]`:
it advances the state exactly like `classify`, so call one of them per chunk, not both.
"""

from __future__ import annotations

import numpy as np

from ..events import EventChunk, Geometry, NoiseClass
from .base import Classifier

# Timestamp of "never fired": far in the past, yet `t - NEVER_US` cannot overflow int64 for |t| < 2**62.
NEVER_US = -(2**62)
# The score argument of a kernel compiled without the score (`classify`): never touched.
NO_SCORE = np.zeros(0, np.float64)


class ScoredClassifier(Classifier):
    """Base of the baselines: parameters checked at construction, state allocated on the first chunk."""

    _geometry: Geometry | None = None

    def scored(self, chunk: EventChunk) -> tuple[EventChunk, np.ndarray]:
        """As `stage(chunk)`, also returning one score per event of the chunk: NaN for events this
        stage did not see (an earlier stage had already classed them noise), which the metrics count
        as never kept. Same interface as the paper's cascade, so evaluation treats all alike."""
        cls = chunk.classes().copy()
        live = np.flatnonzero(cls == NoiseClass.SIGNAL)
        scores = np.full(len(chunk), np.nan)
        if len(live) == len(cls):
            codes, scores = self.classify_scored(chunk)
            cls = np.ascontiguousarray(codes, dtype=np.uint8)
        else:
            cls[live], scores[live] = self.classify_scored(chunk[live])
        return chunk.replace(cls=cls), scores

    def score(self, chunk: EventChunk) -> np.ndarray:
        """Per-event scores (float64, higher = more signal-like); advances the state like `classify`."""
        return self.classify_scored(chunk)[1]

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _ensure_state(self, chunk: EventChunk) -> None:
        """Allocate the state for the chunk's geometry on first use; refuse a change of geometry."""
        if self._geometry is None:
            self._geometry = chunk.geometry
            self._allocate(chunk.geometry)
        elif chunk.geometry != self._geometry:
            raise ValueError(f"{type(self).__name__}: chunk geometry {chunk.geometry} differs from the "
                             f"stream's {self._geometry}")

    def _allocate(self, geometry: Geometry) -> None:
        raise NotImplementedError


def check(cond: bool, stage: str, message: str) -> None:
    """Raise a ValueError naming the stage when a parameter is out of range."""
    if not cond:
        raise ValueError(f"{stage}: {message}")


def is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)
