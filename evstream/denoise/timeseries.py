"""Fine stage of Jiang et al. (Sensors 2024): time-sequence (DC component) analysis against hot pixels.

Reconstruction (see docs/method.md). Each pixel has a Boolean activity series sampled at `rate_hz`
(fs): bin k covers [k/fs, (k+1)/fs), anchored at t = 0 — never at a chunk start, so the result does
not depend on chunking. Over the last n bins the DFT's DC component of a Boolean series is the
fraction of active bins, DC ∈ [0, 1]. An event is HOT_PIXEL iff its pixel's DC exceeds the mean DC of
its neighbours by more than λ (`difference` form), or exceeds λ times that mean (`ratio` form).

The activity state is fed by every event this stage sees — in the cascade, the events the coarse stage
kept — including the events it classes HOT_PIXEL (a hot pixel must stay hot).

Exact and streaming: each pixel's count of active bins among the last n (a pixel's first event in a
bin activates it; a FIFO expires the activation when its bin leaves the window), held in a row-summed
map (`rowsum`) so that the neighbours' total is L reads. 3 bytes per pixel (4 when L·n > 255: the row
sums' type) plus 4 per activation in the window. (A uint64 bitmask per pixel with popcounts of the
neighbours, the obvious layout, is 16 bytes per pixel and measured 1.2–1.4× slower in the cascade.)

Limits: it needs about n/fs of history before a hot pixel's DC is fully built; and a hot pixel firing
at rate f sets a fraction 1 - exp(-f/fs) of the bins, so pixels slower than about λ·fs are missed
(lower λ or fs for slow hot pixels).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..events import EventChunk, NoiseClass, shown
from ..jit import bind, njit
from ..nowrap import ix
from ..pipeline import register
from .base import InPlaceClassifier, fifo_capacity, grow_fifo
from .common import is_int
from .prefetch import FAR_BYTES, prefetch
from .rowsum import MAX_RADIUS_PX, column_sum, padded_map, row_add

DIFFERENCE, RATIO = 0, 1
PREFETCH_EVENTS = 8  # how far ahead `far` kernels prefetch (at 1280×720: fine alone 20.9 -> 16.1 ns/event)


@functools.cache
def dc_kernel(options, want_score):
    """The kernel compiled for one configuration, `options` = (radius, form, far) (compile-time constants;
    `far`: the maps are larger than the L2 cache, so each event prefetches the cells of the live event
    PREFETCH_EVENTS ahead)."""
    radius, form, far = options
    L = 2 * radius + 1

    @njit(cache=True, nogil=True)
    def kernel(t, x, y, resume, codes, noise_code, live, pixel, rowsum, padded_width, fifo_pos, per_bin,
               fifo_state, bin_us, n_bins, lam, above, span_x, span_y, out_score):
        """For each event still SIGNAL in `codes`: mark its pixel active in the event's bin, compare the
        pixel's active bins with its neighbours' mean, write `noise_code` when hot (and the score if
        `want_score`). The events still SIGNAL are gathered once into `live` (length >= len(t)), then
        judged from the next live index and the live count, `fifo_state[3:5]`; returns True when all
        are done, False when the FIFO is full (the caller grows it and calls again with `resume`: no
        re-gather). `live` is state too (no allocation per call): the caller keeps it >= len(t).

        State, indexed like the padded `rowsum` map: `pixel`, a uint16 per pixel holding its count of
        active bins among the last n (low byte) and its last active bin modulo 256 (high byte); `rowsum`
        (row sums of the counts over L columns, `rowsum` module); a FIFO of activations (`fifo_pos`,
        the cell's row position) with `per_bin[k % n]` activations in bin k, expired when the bin
        leaves the window;
        `fifo_state` = [head, size, current bin, next live index, live count].
        """
        cap = len(fifo_pos)
        mask = cap - 1
        head = fifo_state[0]
        size = fifo_state[1]
        b = fifo_state[2]
        bin_start = b * bin_us  # [bin_start, bin_end) is bin b
        bin_end = bin_start + bin_us
        b_slot = b % n_bins  # per_bin[b_slot] counts bin b's activations
        in_bin = per_bin[ix(b_slot)]
        if resume:
            j = fifo_state[3]
            k = fifo_state[4]
        else:  # the events still SIGNAL, gathered without a branch: skipping the others in the loop
            j = 0  # below mispredicts on every other event
            k = 0
            for i in range(len(t)):
                live[ix(k)] = i
                k += codes[ix(i)] == 0
            fifo_state[4] = k
        while j < k:
            stop = min(k, j + cap - size)  # each event pushes at most one activation
            if stop == j:
                break
            while j < stop:
                i = live[ix(j)]
                if far:
                    a = live[ix(min(j + PREFETCH_EVENTS, k - 1))]
                    q = (np.intp(y[ix(a)]) + radius) * padded_width + np.intp(x[ix(a)]) + radius
                    prefetch(pixel, q)
                    for r in range(-radius, radius + 1):
                        prefetch(rowsum, q + r * padded_width)
                j += 1
                ti = t[ix(i)]
                if ti >= bin_end or ti < bin_start:  # a division (and expiry) only on a new bin
                    per_bin[ix(b_slot)] = in_bin
                    nb = ti // bin_us
                    for old in range(max(b - n_bins + 1, nb - 2 * n_bins + 1), nb - n_bins + 1):
                        k_old = old % n_bins  # bins b - n + 1 .. nb - n leave the window
                        for _ in range(per_bin[ix(k_old)]):
                            pos = fifo_pos[ix(head)]
                            pixel[ix(pos + radius)] -= 1  # its count (low byte) is >= 1
                            row_add(rowsum, pos, -1, L)
                            head = (head + 1) & mask
                            size -= 1
                        per_bin[ix(k_old)] = 0
                    b = nb
                    b_slot = b % n_bins
                    in_bin = per_bin[ix(b_slot)]
                    bin_start = b * bin_us
                    bin_end = bin_start + bin_us
                xi = np.intp(x[ix(i)])
                yi = np.intp(y[ix(i)])
                pos = (yi + radius) * padded_width + xi  # the pixel's row of L cells in `rowsum`
                c = pos + radius  # the pixel's own cell
                # first event of this pixel in this bin: one more active bin. Its last active bin equals
                # b modulo 256 either because it is b, or because the pixel has been idle >= 256 > n bins
                # and then has no active bin left (count 0): exact, in one byte
                cell = np.int64(pixel[ix(c)])
                b8 = b & 0xFF
                new = ((cell >> 8) != b8) | ((cell & 0xFF) == 0)
                own = (cell & 0xFF) + new  # <= n: bin b - n left the window before bin b began
                # the neighbourhood read before this event's own update (no store to forward from):
                # the update adds `new` to one cell of this column
                active = column_sum(rowsum, yi * padded_width + xi + radius, padded_width, L) + new - own
                pixel[ix(c)] = (b8 << 8) | own
                row_add(rowsum, pos, new, L)  # branchless: delta 0 when the bin was already active
                slot = (head + size) & mask
                fifo_pos[ix(slot)] = pos
                in_bin += new  # per_bin[b_slot], kept in a register (stored back on a new bin, at the end)
                size += new
                n_nb = span_x[ix(xi)] * span_y[ix(yi)] - 1  # box_area, tabulated per column and row
                # decisions in whole bins (exact): DC_m - mean > λ  <=>  own·n_nb - active > λ·n·n_nb
                if form == DIFFERENCE:
                    # integers only, the table holding floor(λ·n·n_nb) (`above`); n_nb = 0 (a 1×1 sensor, no
                    # neighbour: active = 0) reads own > floor(λ·n)
                    hot = own * max(n_nb, 1) - active > above[ix(n_nb)]
                else:
                    hot = own * n_nb > lam * active if active > 0 else own > lam  # guard: quiet neighbours
                codes[ix(i)] = noise_code * hot
                if want_score:
                    dc = own / n_bins
                    mean = active / (n_nb * n_bins) if n_nb > 0 else 0.0
                    if form == DIFFERENCE:
                        out_score[ix(i)] = dc - mean
                    else:
                        out_score[ix(i)] = dc / mean if mean > 0 else np.inf
        per_bin[ix(b_slot)] = in_bin
        fifo_state[0] = head
        fifo_state[1] = size
        fifo_state[2] = b
        fifo_state[3] = j
        return j >= k

    return kernel


@register("stage", "dc")
@dataclass
class TimeSeriesFilter(InPlaceClassifier):
    """Hot-pixel filter by the DC component of each pixel's activity series (fine stage).

    `rate_hz` fs: activity sampling rate (bins of 1/fs anchored at t = 0); `n_bins` n <= 255: bins in
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
        if not is_int(self.n_bins) or not 1 <= self.n_bins <= 255:
            raise ValueError(f"n_bins must be an integer in 1..255 (a uint8 count per pixel), got {shown(self.n_bins)}")
        if self.form not in ("difference", "ratio"):
            raise ValueError(f"form must be 'difference' or 'ratio', got {shown(self.form)}")
        if not math.isfinite(self.lam) or (self.form == "difference" and not 0 <= self.lam < 1) or self.lam < 0:
            raise ValueError(f"lam must be in [0, 1) for the difference form, >= 0 for ratio; got {self.lam}")
        if not is_int(self.radius_px) or not 1 <= self.radius_px <= MAX_RADIUS_PX:
            raise ValueError(f"radius_px must be an integer in 1..{MAX_RADIUS_PX}, got {shown(self.radius_px)}")
        if (2 * self.radius_px + 1) * self.n_bins > 65535:
            raise ValueError(f"(2 radius_px + 1) · n_bins must fit the uint16 row sums: radius_px {self.radius_px}, "
                             f"n_bins {self.n_bins}")

    @property
    def bin_us(self) -> int:
        return int(1e6 / self.rate_hz)

    @property
    def history_us(self) -> int:
        """History the filter needs before a hot pixel's DC is fully built: n / fs."""
        return self.n_bins * self.bin_us

    def _init(self, g) -> dict:
        r = self.radius_px
        cap = fifo_capacity(g.n_pixels // 4)  # their 64 bins ~n_pixels / 4 activations
        # a row sum is at most L·n (L pixels of at most n active bins): one byte when that is <= 255, as with
        # the defaults (3 · 64), a quarter less state (at 1280×720 the cascade 2–5 % faster)
        sums = np.uint8 if (2 * r + 1) * self.n_bins <= 255 else np.uint16
        return {"geometry": g, "pixel": padded_map(g.width, g.height, r, np.uint16),
                "rowsum": padded_map(g.width, g.height, r, sums), "fifo_pos": np.zeros(cap, np.int32),
                "per_bin": np.zeros(self.n_bins, np.int64), "fifo_state": np.zeros(5, np.int64),
                "live": np.zeros(0, np.int64),
                "span_x": _span(g.width, r), "span_y": _span(g.height, r)}

    def _run(self, chunk: EventChunk, codes: np.ndarray, want_score: bool) -> np.ndarray:
        """Classify the events of `chunk` whose `codes` are SIGNAL, in place; returns the scores. The
        parameters are read when the state is built, on the first chunk."""
        n = len(chunk)
        self._ready(chunk, n)
        score = np.zeros(n, np.float64) if want_score else _NO_SCORE
        t, x, y = chunk.t, chunk.x, chunk.y
        if n <= BLOCK_EVENTS:
            self._judge(want_score, t, x, y, codes, score)
        else:  # the stage is chunk-invariant: blocks keep `live` in cache, with the same classes
            for a in range(0, n, BLOCK_EVENTS):
                b = a + BLOCK_EVENTS
                self._judge(want_score, t[a:b], x[a:b], y[a:b], codes[a:b], score[a:b] if want_score else score)
        self._release()
        return score

    def _ready(self, chunk: EventChunk, n: int) -> None:
        """The state for the chunk's geometry (built on the first chunk), its live buffer for `n` events."""
        s, g = self._state, chunk.geometry
        if s is None or (s["geometry"] is not g and s["geometry"] != g):
            s = self._state = self._init(g)
            self._bind()
        if len(s["live"]) < min(n, BLOCK_EVENTS):  # kept up to KEPT_LIVE: a chunk call allocates nothing
            s["live"] = np.empty(min(max(n, 2 * len(s["live"])), BLOCK_EVENTS), np.int64)  # written before read
            self._bind()

    def _release(self) -> None:
        """A long chunk's live buffer is not kept as state (up to 8 MB)."""
        if len(self._state["live"]) > KEPT_LIVE:
            self._state["live"] = np.zeros(0, np.int64)
            self._bind()

    def _grow(self) -> None:
        """Double the activation FIFO the kernel filled (it returned early) and bind the new array."""
        grow_fifo(self._state, ("fifo_pos",))
        self._bind()

    def _judge(self, want_score, t, x, y, codes, score) -> None:
        resume = False
        more = (score,) if want_score else ()  # the class-only kernel's score argument is bound with the state
        while True:
            call = self._calls.get(want_score) or self._calls.setdefault(want_score, bind(
                self._kernel(want_score), 5, self._args if want_score else (*self._args, _NO_SCORE)))
            if call(t, x, y, resume, codes, *more):
                return
            self._grow()
            resume = True

    def _bind(self) -> None:
        """The kernel's arguments after the codes: state arrays, then parameters as the kernel's types."""
        s, g, r = self._state, self._state["geometry"], self.radius_px
        far = 2 * s["pixel"].nbytes > FAR_BYTES  # as with two-byte row sums (640×480 up; the ahead-of-time build)
        self._options = (r, DIFFERENCE if self.form == "difference" else RATIO, far)
        self._args = (int(self.noise_class), s["live"], s["pixel"], s["rowsum"], g.width + 2 * r, s["fifo_pos"],
                      s["per_bin"], s["fifo_state"], self.bin_us, self.n_bins, float(self.lam), self._above(),
                      s["span_x"], s["span_y"])
        self._calls = {}  # want_score -> the kernel's call with these arguments bound (evstream.jit.bind)

    def _kernel(self, want_score: bool):
        """The kernel compiled for these options and this state (after `_ready`)."""
        return dc_kernel(self._options, want_score)

    def _above(self) -> np.ndarray:
        """The difference form's threshold in whole bins for each neighbour count n_nb: hot iff
        own·n_nb - active > λ·n·n_nb, i.e. (integers) > floor(λ·n·n_nb), the product computed as the
        float it was (exact: the same comparison, without a float per event); n_nb = 0: own > λ·n."""
        lam_bins = float(self.lam) * self.n_bins
        cells = (2 * self.radius_px + 1) ** 2
        return np.array([math.floor(lam_bins * k if k else lam_bins) for k in range(cells)], np.int64)


def _span(size: int, radius: int) -> np.ndarray:
    """For each coordinate, how many of the 2r + 1 around it lie on a sensor of `size` (`box_area`'s factors)."""
    c = np.arange(size, dtype=np.int64)
    return np.minimum(c + radius, size - 1) - np.maximum(c - radius, 0) + 1


_NO_SCORE = np.zeros(0, np.float64)  # the kernels compiled without the score never touch it
# A longer chunk is judged block by block (same classes): its gathered live indices stay in cache
# (a 10 M-event call ran 0.3-0.4x the speed of 100k chunks without this).
BLOCK_EVENTS = 1 << 20
KEPT_LIVE = 1 << 14  # the live indices of chunks up to this long stay allocated between calls (128 KiB)
