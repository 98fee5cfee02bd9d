"""The paper's cascade (Jiang et al., Sensors 2024): density filter, then DC-component hot-pixel filter.

`--denoise paper`. The coarse stage sees every event still SIGNAL; the fine stage sees — and learns
its activity series from — only the events the coarse stage kept, as in the paper.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ..events import EventChunk, NoiseClass
from ..jit import bind, njit
from ..pipeline import register
from .density import DensityFilter
from .timeseries import TimeSeriesFilter

# What the cascade kernel returns: done, or which stage stopped for room (its FIFO full, or the coarse map's
# cells to widen: the caller makes it, `_grow`, and calls again)
DONE, COARSE_FULL, FINE_FULL = 0, 1, 2


@functools.cache
def cascade_kernel(coarse, fine):
    """Both stages in one call: the coarse kernel (`density_kernel`, class only), then the fine one
    (`dc_kernel`, class only) over the same chunk, so that a chunk costs one dispatch from Python, not two
    (a call's keying of its arguments and the ahead-of-time function's unboxing, ~3 µs each)."""

    @njit(cache=True, nogil=True)
    def kernel(t, x, y, p, codes, progress, c_code, hsum, c_width, fifo_t, c_pos, fifo_x, fifo_y, c_state, per_pol,
               cell_max, window_us, density_hz, rho_rel, width, height, f_code, live, pixel, rowsum, f_width,
               f_pos, per_bin, f_state, bin_us, n_bins, lam, above, span_x, span_y):
        """`progress` = [the coarse stage's next event, whether the fine one resumes]: both 0 on a new
        chunk, left where a full FIFO stopped a stage. Returns DONE, COARSE_FULL or FINE_FULL."""
        n = len(t)
        no_score = np.empty(0, np.float64)
        if progress[0] < n:
            i = coarse(t, x, y, p, progress[0], codes, c_code, hsum, c_width, fifo_t, c_pos, fifo_x, fifo_y, c_state,
                       per_pol, cell_max, window_us, density_hz, rho_rel, width, height, no_score)
            progress[0] = i
            if i < n:
                return COARSE_FULL
        if not fine(t, x, y, progress[1] != 0, codes, f_code, live, pixel, rowsum, f_width, f_pos, per_bin, f_state,
                    bin_us, n_bins, lam, above, span_x, span_y, no_score):
            progress[1] = 1
            return FINE_FULL
        return DONE

    return kernel


@register("stage", "paper")
@dataclass
class PaperCascade:
    """Coarse (BACKGROUND) then fine (HOT_PIXEL) classification; parameters are the two stages'.

    Construct with keyword dicts, e.g. `PaperCascade(coarse={"window_us": 10_000}, fine={"lam": 0.2})`
    or in TOML: `[[stage]] kind = "paper"  coarse = { mode = "absolute" }`.
    """

    coarse: dict = field(default_factory=dict)
    fine: dict = field(default_factory=dict)
    _stages: tuple = field(default=(), init=False, repr=False)
    _call: tuple = field(default=(), init=False, repr=False)  # (coarse args, fine args, all_live, bound kernel)
    # A larger chunk runs through both stages block by block: the fine stage then reads each block's
    # events from cache, not memory (a 10 M-event call ran 0.74x the speed of 100k chunks; 1M-event
    # blocks measured best at both sensor sizes).
    block_events: ClassVar[int] = 1 << 20

    def __post_init__(self):
        self._stages = (DensityFilter(**self.coarse), TimeSeriesFilter(**self.fine))

    @property
    def density(self) -> DensityFilter:
        return self._stages[0]

    @property
    def timeseries(self) -> TimeSeriesFilter:
        return self._stages[1]

    @property
    def parts(self) -> dict:
        """The two stages by parameter name (listings show `coarse.window_us`, `--set` reaches them)."""
        return {"coarse": self.density, "fine": self.timeseries}

    @property
    def history_us(self) -> int:
        """Warm-up before decisions are at full strength: Δt plus n/fs."""
        return self.density.window_us + self.timeseries.history_us

    def __call__(self, chunk: EventChunk) -> EventChunk:
        if chunk.cls is None:
            codes, all_live = np.zeros(len(chunk), np.uint8), True
        else:
            codes = chunk.cls.copy()
            all_live = not np.count_nonzero(codes)
        n = len(chunk)
        if n <= self.block_events:  # each skips what an earlier one rejected: no gather, no copy
            self._both(chunk, codes, all_live)
        else:  # both stages are chunk-invariant: the same classes, with the block still in cache for the fine one
            for a in range(0, n, self.block_events):
                self._both(chunk[a : a + self.block_events], codes[a : a + self.block_events], all_live)
        return chunk.with_classes(codes)

    def _both(self, chunk: EventChunk, codes: np.ndarray, all_live: bool) -> None:
        """Both stages over `chunk` (at most `block_events` long) in one kernel call, more when a stage
        needs room."""
        coarse, fine = self._stages
        coarse._ready(chunk)
        fine._ready(chunk, len(chunk))
        progress = np.zeros(2, np.int64)
        while True:
            c = self._call
            if not c or c[0] is not coarse._args or c[1] is not fine._args or c[2] is not all_live:
                kernel = cascade_kernel(coarse._kernel(False, all_live), fine._kernel(False))
                c = self._call = (coarse._args, fine._args, all_live, bind(kernel, 6, coarse._args + fine._args))
            status = c[3](chunk.t, chunk.x, chunk.y, chunk.p, codes, progress)
            if status == DONE:
                break
            (coarse if status == COARSE_FULL else fine)._grow()
        fine._release()
        if self._call[1] is not fine._args:  # the bound call would keep a long chunk's live buffer alive
            self._call = ()

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        """Class codes and one signal-likeness score per event of an unclassified chunk, for ROC
        analysis: the coarse score relative to its threshold (>= 1 passes), or -1 for events the fine
        stage calls hot. Sweeping a threshold on it traces the coarse threshold with the fine stage at
        its operating point (the fine stage's history follows the default coarse decisions, so away
        from the operating point this ROC is an approximation)."""
        d, f = self.density, self.timeseries
        codes = np.zeros(len(chunk), np.uint8)
        s_coarse = d._run(chunk, codes, want_score=True)
        thr = d.density_hz if d.mode == "absolute" else d.rho_rel
        score = s_coarse / thr if thr > 0 else s_coarse
        f._run(chunk, codes, want_score=False)
        score[codes == NoiseClass.HOT_PIXEL] = -1.0
        return codes, score

    def classify(self, chunk: EventChunk) -> np.ndarray:
        return self(chunk.replace(cls=None)).cls

    def params(self) -> dict:
        return {"coarse": self.density.params(), "fine": self.timeseries.params()}
