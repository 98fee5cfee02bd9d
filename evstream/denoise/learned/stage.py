"""The learned denoise stage: the fused feature kernel scoring each event with a trained model.

`--denoise learned` uses the shipped model (trained on the synthetic scenes and permissively licensed
recordings, docs/learned.md); `model = "PATH.npz"` takes one made by `evstream train`. `keep` picks the
operating point: the fraction of the signal the model's calibration expects it to keep (default: the
one it was trained for). Events scored below the threshold are BACKGROUND; an event whose pixel fired
`hot_min` times or more in the last 20 ms, more than a third of its 5×5 box's events, or whose pixel's
DC component exceeds its 8 neighbours' mean by more than `dc_lam` (1: never), is HOT_PIXEL.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...events import EventChunk, NoiseClass, shown
from ...pipeline import register
from ..base import InPlaceClassifier, grow_fifo
from .features import HISTORY_US, N_BINS, N_FEATURES, TABLES, feature_kernel, new_state
from .model import Model, load


@register("stage", "learned")
@dataclass
class LearnedFilter(InPlaceClassifier):
    """A trained per-event score over causal features; SIGNAL iff the score reaches the threshold
    that keeps the fraction `keep` of the signal. Score (`classify_scored`): the model's output."""

    model: str | Model | None = None
    keep: float | None = None
    hot_min: int = 4
    dc_lam: float = 0.2
    noise_class = NoiseClass.BACKGROUND
    _state: dict | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        m = self.model if isinstance(self.model, Model) else load(self.model)
        if self.keep is not None and not (isinstance(self.keep, (int, float)) and 0 < self.keep <= 1):
            raise ValueError(f"learned: keep must be a fraction in (0, 1], got {shown(self.keep)}")
        if not isinstance(self.hot_min, int) or self.hot_min < 1:
            raise ValueError(f"learned: hot_min must be a positive integer, got {shown(self.hot_min)}")
        if not (isinstance(self.dc_lam, (int, float)) and 0 <= self.dc_lam <= 1):
            raise ValueError(f"learned: dc_lam must be in [0, 1] (1: no DC rule), got {shown(self.dc_lam)}")
        self._dc_margin = math.floor(self.dc_lam * 8 * N_BINS)
        self._model = m
        self._weights = m.folded()
        self._n_hidden = m.n_hidden
        self._threshold = m.threshold(self.keep)

    @property
    def history_us(self) -> int:
        """Warm-up before decisions are at full strength: the longest look-back of a feature."""
        return HISTORY_US

    @property
    def threshold(self) -> float:
        return self._threshold

    def params(self) -> dict:
        model = self.model
        if isinstance(model, Model):
            model = model.meta.get("name", "<in memory>")
        return {"model": model, "keep": self.keep, "hot_min": self.hot_min, "dc_lam": self.dc_lam}

    def _run(self, chunk: EventChunk, codes: np.ndarray, want_score: bool,
             features: np.ndarray | None = None) -> np.ndarray:
        s = self._state
        g = chunk.geometry
        if s is None or (s["geometry"] is not g and s["geometry"] != g):
            s = self._state = {**new_state(g.width, g.height), "geometry": g}
        n = len(chunk)
        score = np.zeros(n, np.float64) if want_score else _NO_SCORE
        feats = features if features is not None else _NO_FEATURES
        w1, b1, w2, b2 = self._weights
        all_live = not np.count_nonzero(codes)  # (twice as fast as codes.any())
        kernel = feature_kernel(self._n_hidden, want_score, features is not None, all_live)
        i = 0
        while True:
            i = kernel(chunk.t, chunk.x, chunk.y, chunk.p, i, codes, self._threshold, self.hot_min,
                       self._dc_margin, s["word"], s["block"], s["block_log_scale"], s["width_padded"],
                       s["fifo"], s["fifo_state"], s["bins"], s["clock"], g.width, g.height, w1, b1, w2, b2,
                       score, feats, TABLES)
            if i >= n:
                return score
            grow_fifo(s, ("fifo",), record=2)

    def features(self, chunk: EventChunk) -> np.ndarray:
        """The feature matrix of an unclassified chunk (advances the state like `classify`)."""
        codes = np.zeros(len(chunk), np.uint8)
        out = np.zeros((len(chunk), N_FEATURES))
        self._run(chunk, codes, want_score=False, features=out)
        return out


_NO_SCORE = np.zeros(0, np.float64)  # the kernels compiled without scores or features never touch these
_NO_FEATURES = np.zeros((0, N_FEATURES), np.float64)
