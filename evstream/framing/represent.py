"""Representations for learning, as framers: time surface, voxel grid, two-channel histogram, event-count
and last-timestamp images, each a float32 (C, H, W) array per window.

The windows are the existing framers' (`window` = fw, fn, oa or adaptive, with their parameters): a
representation framer drives one of them and turns each frame it emits into a `Representation`, the
same frame with a `data` array beside its counts. So the windows (times, closing on the watermark,
empty frames, the paper's adaptive overlap) are exactly those of `evstream frames --framer KIND`.

Per window [t_start, t_end) holding n counted events (SIGNAL ones unless `all_events`):
- `histogram` (2 channels, OFF then ON): events per pixel and polarity (the frame's counts, which
  saturate at 65535 per pixel and window);
- `count` (1 channel): events per pixel, both polarities;
- `timestamp` (2 channels, OFF then ON): the newest event of the window per pixel and polarity, as
  (t − t_start + 1) / (t_end − t_start) in (0, 1]; 0 where the pixel had no event in the window;
- `timesurface` (2 channels, OFF then ON): exp(−(t_end − t_last) / τ), t_last the newest event at that
  pixel and polarity before t_end over the whole stream so far (not only this window), 0 where none;
- `voxel` (B channels): Zhu et al. (2019)'s voxel grid, V_b = Σ p_i · max(0, 1 − |b − t*_i|) with
  p_i = ±1 and t*_i = (B − 1)(t_i − t_start) / (t_end − 1 − t_start): bilinear in time over the
  window's span (for fixed-count windows t_start and t_end − 1 are the first and last events, as in
  the paper and tonic).

Over fixed time and overlapping windows (whose span is known when they open) the voxel grid and the last
timestamp add each event to its window's array as it arrives (an overlapping window opens with the
events it shares with the previous one, taken from the windowing framer's own buffer); over fixed-count
windows (whose span is known only when they close) an array is computed when its window closes, from
the window's events buffered in stream order (times and flat pixel indices). The time
surface buffers no events, only the newest time per pixel and polarity (int32 from a moving base, or
int64 for long τ). Memory O(W·H + events per window), never the stream. Events are always taken in
stream order, so every array is bit-identical however the stream was chunked. Arrays are fresh,
C-contiguous float32: `torch.from_numpy(rep.data)` shares them without a copy.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..events import EventChunk, Frame, shown
from ..jit import njit
from ..nowrap import ix
from ..pipeline import build, register
from .base import COUNT_MAX, FramerBase, check_positive_int
from .fixed import accumulate
from .overlap import add_flat, buffer_events, flat_index, flat_index_of, frame_part, slide_kernel

WINDOWS = ("fw", "fn", "oa", "adaptive")
# The windowing framers' parameters a representation passes on (None: the window's default).
WINDOW_PARAMS = ("window_us", "stride_us", "n_events", "max_window_us", "n_base", "k_us_per_event",
                 "overlap_max_us", "overlap_init_us", "max_empty_frames")
NEVER_US = -(1 << 62)  # "no event yet": exp(−(t − NEVER_US)/τ) is exactly 0 for any τ we accept
MAX_TAU_US = 1 << 40
REBASE_US = 1 << 30  # time surface: int32 times move their base once an event is this far past it
VOXEL_TABLE_MAX_US = 1 << 16  # voxel grid: the largest window span given a table (32 bytes per µs)


@dataclass(frozen=True, eq=False)
class Representation(Frame):
    """A frame with its representation: `data` float32 (C, H, W), C-contiguous, owned by this object;
    `kind` names the representation, `channels` its channels. `counts` are the window's event counts."""

    kind: str
    channels: tuple
    data: np.ndarray


# -- kernels --------------------------------------------------------------------------------------
# Each loops over range(len(...)) of slices given by the caller: over range(a, b) numba cannot tell an
# index is not negative, and its wrap-around test on every array access costs ~30 % here (and stops
# the vectorisation of `surface_exponent`).
# A voxel grid is not zero-filled when its window opens: each bin is zeroed when the window's first
# event reaches it, and the bins no event reached when the window closes (`_Grid.done`). Events come in
# time order, so the bins fill one after the other: a window's events touch two bins at a time (0.7 MB at
# 346x260), which stay in cache, instead of a 1.8 MB zero-fill whose first bins have left the cache when
# the events reach them (measured: 1.6 ns an event less at 50 k events a window). `ready` is how many
# elements of the flat grid are written (zeros or sums): the kernels take it and return it. Each kernel
# tests it inline and calls `_zero_bins` only when an event reaches a new bin: a helper that takes the
# grid, branches and returns, inlined into the loop, ran 2.5-8x slower (numba then counts references to
# the grid on every event).
@njit(cache=True, nogil=True)
def _zero_bins(out, ready, end):
    """Zero out[ready:end] (end clipped to the grid): the bins an event reached, and any it skipped, not
    yet written. Returns the new `ready`. A loop: numba's out[a:b] = 0 was slower."""
    end = min(end, len(out))
    for k in range(ready, end):
        out[ix(k)] = 0
    return end


@njit(cache=True, nogil=True, inline="always")
def _bin_of(dt, scale):
    """t* = dt·scale: its bin lo = ⌊t*⌋ and the weight of the bin after it, t* − lo, in float32."""
    tn = dt * scale
    lo = np.intp(tn)
    return lo, np.float32(tn - lo)


@njit(cache=True, nogil=True, inline="always")
def _voxel_add(out, pix, on, lo, w_hi, last, hw):
    """Add polarity ±1 (`on`) of one event to the flat voxel grid `out` (bins·H·W), shared bilinearly
    between bin lo (weight 1 − w_hi) and lo + 1 (w_hi); the last bin has no bin after it."""
    v = np.float32(2 * on - 1)
    k = lo * hw + pix  # >= 0: dt >= 0 (the event is in the window)
    out[ix(k)] += v - v * w_hi
    if lo < last:
        out[ix(k + hw)] += v * w_hi


@njit(cache=True, nogil=True)
def voxel_kernel(buf_t, buf_f, t_start, t_end, bins, hw, out, ready):
    """Add buffered events (time, flat index p·H·W + y·W + x), all in [t_start, t_end), to the flat voxel
    grid `out` (its first `ready` elements written; returns the new `ready`): t* = (bins − 1)(t − t_start)
    / (t_end − 1 − t_start). Polarity and pixel come from the flat index without a branch (they are random
    per event)."""
    scale = (bins - 1) / max(1, t_end - 1 - t_start)
    for j in range(len(buf_t)):
        f = np.intp(buf_f[j])
        on = np.intp(f >= hw)
        lo, w = _bin_of(buf_t[j] - t_start, scale)
        if (lo + 1) * hw >= ready:
            ready = _zero_bins(out, ready, (lo + 2) * hw)
        _voxel_add(out, f - hw * on, on, lo, w, bins - 1, hw)
    return ready


@njit(cache=True, nogil=True)
def voxel_count_kernel(buf_t, buf_f, t_start, t_end, bins, hw, counts, out, ready):
    """`add_flat` (the frame's saturating counts) and `voxel_kernel` over the same buffered events, in one
    pass (fixed-count windows, whose framer leaves the counts to it). Returns `ready`."""
    scale = (bins - 1) / max(1, t_end - 1 - t_start)
    for j in range(len(buf_t)):
        f = np.intp(buf_f[j])
        if counts[f] != COUNT_MAX:
            counts[f] += 1
        on = np.intp(f >= hw)
        lo, w = _bin_of(buf_t[j] - t_start, scale)
        if (lo + 1) * hw >= ready:
            ready = _zero_bins(out, ready, (lo + 2) * hw)
        _voxel_add(out, f - hw * on, on, lo, w, bins - 1, hw)
    return ready


@njit(cache=True, nogil=True)
def voxel_of_chunk(t, x, y, p, cls, use_cls, t_start, t_end, bins, width, hw, out, ready):
    """`voxel_kernel` straight from a chunk's events (the counted ones: `cls` 0 when `use_cls`), for
    windows whose span is known when they open (fixed time windows): the same arithmetic per event."""
    scale = (bins - 1) / max(1, t_end - 1 - t_start)
    for j in range(len(t)):
        if use_cls and cls[j] != 0:
            continue
        lo, w = _bin_of(t[j] - t_start, scale)
        if (lo + 1) * hw >= ready:
            ready = _zero_bins(out, ready, (lo + 2) * hw)
        _voxel_add(out, np.intp(y[j]) * width + np.intp(x[j]), np.intp(p[j]), lo, w, bins - 1, hw)
    return ready


# Windows of one span (fixed time and overlapping ones) share each µs's arithmetic: a table of it, made
# once, replaces five float conversions and three products per event by three loads (~20 % of the
# voxel kernel). Its entries are computed exactly as `_voxel_add` computes them, so the grid is the same
# to the bit: v − v·w for v = −1 is −(1 − w) exactly, and adding a weight of ±0 changes no sum (a sum
# starting at +0 is never −0). So every event adds to two bins, without a test: at t* = B − 1 (the
# last bin, which has no bin after it) the table gives bins B − 2 and B − 1 with weights +0 and v, the
# same sums as v in bin B − 1 alone. Tables need B >= 2.
# The table kernels zero the bins their events reach before the loop, up to the bin after that of the
# latest event (the events of one call span a chunk's or an overlap's time, a bin or two): the loop
# then has no test and no call (with them, numba kept half the loop's values on the stack).
@njit(cache=True, nogil=True)
def voxel_table(span_us, bins, hw, lo_at, w_lo, w_hi):
    """For each dt in [0, span_us) and polarity `on`, at e = 2·dt + on: lo_at[e] = lo·H·W − on·H·W (lo =
    ⌊t*⌋, t* = dt·scale as in `voxel_kernel`), so that lo_at[e] + f is the grid offset of an event of
    flat index f = on·H·W + y·W + x in bin lo; w_lo[e] and w_hi[e] the weights of polarity ±1 in bins lo
    and lo + 1. At the last bin (t* = B − 1): lo = B − 2 and weights +0 and ±1. `bins` >= 2."""
    scale = (bins - 1) / max(1, span_us - 1)
    last = bins - 1
    for d in range(len(lo_at) // 2):  # lo_at, w_lo, w_hi: 2·span_us long
        lo, w = _bin_of(d, scale)
        if lo == last:
            lo, w = last - 1, np.float32(1)
        for on in range(2):
            v = np.float32(2 * on - 1)
            lo_at[2 * d + on] = (lo - on) * hw
            w_lo[2 * d + on] = v - v * w
            w_hi[2 * d + on] = v * w


@njit(cache=True, nogil=True, inline="always")
def _voxel_add_table(out, f, on, dt, hw, lo_at, w_lo, w_hi):
    """`_voxel_add` through the table, for an event of flat index f = on·H·W + y·W + x at dt in the window."""
    e = ix(2 * dt + on)
    k = ix(lo_at[e] + f)
    out[k] += w_lo[e]
    out[k + ix(hw)] += w_hi[e]


@njit(cache=True, nogil=True)
def _zero_for(t, t_start, hw, lo_at, out, ready):
    """`_zero_bins` for events at times `t` (in the window): the bins up to the one after the latest
    event's lower bin. Returns `ready`."""
    if len(t) == 0:
        return ready
    end = lo_at[ix(2 * (t.max() - t_start))] + 2 * hw
    return _zero_bins(out, ready, end) if end > ready else ready


@njit(cache=True, nogil=True)
def voxel_table_kernel(buf_t, buf_f, t_start, hw, lo_at, w_lo, w_hi, out, ready):
    """`voxel_kernel` through the table of the window's span (`voxel_table`)."""
    ready = _zero_for(buf_t, t_start, hw, lo_at, out, ready)
    for j in range(len(buf_t)):
        f = np.intp(buf_f[j])
        _voxel_add_table(out, f, np.intp(f >= hw), buf_t[j] - t_start, hw, lo_at, w_lo, w_hi)  # dt in [0, span)
    return ready


@njit(cache=True, nogil=True)
def voxel_table_of_chunk(t, x, y, p, cls, use_cls, t_start, width, hw, lo_at, w_lo, w_hi, out, ready):
    """`voxel_of_chunk` through the table of the window's span (`voxel_table`)."""
    ready = _zero_for(t, t_start, hw, lo_at, out, ready)
    for j in range(len(t)):
        if use_cls and cls[j] != 0:
            continue
        on = np.intp(p[j])
        _voxel_add_table(out, on * hw + np.intp(y[j]) * width + np.intp(x[j]), on, t[j] - t_start, hw, lo_at, w_lo,
                         w_hi)
    return ready


# Fixed time and overlapping windows count their events for the frame as they add them to the voxel grid.
# A chunk's events in one pass (each flat index computed once; two passes measured ~15 % slower over
# fixed time windows); buffered events, whose flat indices are at hand, in two (~3 % faster).
@njit(cache=True, nogil=True)
def voxel_count_of_chunk(t, x, y, p, cls, use_cls, a, b, t_start, width, hw, lo_at, w_lo, w_hi, counts, out,
                         ready):
    """`accumulate` (the frame's saturating counts of the counted events [a, b)) and `voxel_table_of_chunk`
    over the same events, in one pass. Returns (how many counted, `ready`)."""
    ready = _zero_for(t[a:b], t_start, hw, lo_at, out, ready)
    added = 0
    for k in range(a, b):
        i = ix(k)
        if use_cls and cls[i] != 0:
            continue
        on = np.intp(p[i])
        f = on * hw + np.intp(y[i]) * width + np.intp(x[i])
        if counts[ix(f)] != COUNT_MAX:
            counts[ix(f)] += 1
        added += 1
        _voxel_add_table(out, f, on, t[i] - t_start, hw, lo_at, w_lo, w_hi)
    return added, ready


@njit(cache=True, nogil=True)
def voxel_count_flat(buf_t, buf_f, t_start, hw, lo_at, w_lo, w_hi, counts, out, ready):
    """`add_flat` (saturating counts) and `voxel_table_kernel` over the same buffered events, in one call.
    Returns `ready`."""
    add_flat(counts, buf_f, 0, len(buf_f))
    return voxel_table_kernel(buf_t, buf_f, t_start, hw, lo_at, w_lo, w_hi, out, ready)


@njit(cache=True, nogil=True)
def voxel_take(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail, t_start, lo_at, w_lo,
               w_hi, out, ready):
    """An overlapping window's part of a chunk in one call (`SlidingFramer.follower.take`): what
    `slide_kernel` does (count the events from i up to `end`, buffer those at or after keep_t), each event
    also added to the window's voxel grid, through the table, in stream order. Returns (stop, the new
    tail, how many counted, `ready`), or (stop, −1, the room needed, `ready`) doing nothing, as it."""
    stop, mid = frame_part(t, i, end, keep_t)
    if tail + stop - mid > len(buf_t):
        return stop, -1, stop - mid, ready
    added, ready = voxel_count_of_chunk(t, x, y, p, cls, use_cls, i, mid, t_start, width, hw, lo_at, w_lo, w_hi,
                                        counts, out, ready)
    k = buffer_events(t, x, y, p, cls, use_cls, mid, stop, width, hw, buf_t, buf_f, tail)
    ready = voxel_count_flat(buf_t[tail : tail + k], buf_f[tail : tail + k], t_start, hw, lo_at, w_lo, w_hi, counts,
                             out, ready)
    return stop, tail + k, added + k, ready


@njit(cache=True, nogil=True)
def timestamp_kernel(buf_t, buf_f, t_start, t_end, out):
    """out[f] = (t − t_start + 1) / (t_end − t_start) of the newest buffered event at each flat index f
    (events are in time order, so the last write wins)."""
    inv = 1.0 / (t_end - t_start)
    for j in range(len(buf_t)):
        out[buf_f[j]] = (buf_t[j] - t_start + 1) * inv


@njit(cache=True, nogil=True)
def timestamp_of_chunk(t, x, y, p, cls, use_cls, t_start, t_end, width, hw, out):
    """`timestamp_kernel` straight from a chunk's (counted) events, for fixed time windows."""
    inv = 1.0 / (t_end - t_start)
    for j in range(len(t)):
        if use_cls and cls[j] != 0:
            continue
        out[np.intp(p[j]) * hw + np.intp(y[j]) * width + np.intp(x[j])] = (t[j] - t_start + 1) * inv


@njit(cache=True, nogil=True)
def last_time_of(t, x, y, p, cls, use_cls, width, hw, base, last_t):
    """last_t[p·H·W + y·W + x] = t − base of the newest (counted) event of a chunk at each pixel; `last_t`
    int32 or int64 (a time too old for int32 is stored as its smallest value, "never")."""
    floor = np.iinfo(last_t.dtype).min
    for i in range(len(t)):
        if use_cls and cls[i] != 0:
            continue
        last_t[np.intp(p[i]) * hw + np.intp(y[i]) * width + np.intp(x[i])] = max(t[i] - base, floor)


@njit(cache=True, nogil=True)
def last_time_count_of(t, x, y, p, cls, use_cls, width, hw, base, last_t, counts):
    """`last_time_of` and `accumulate` (the frame's saturating counts) in one pass over the events."""
    floor = np.iinfo(last_t.dtype).min
    for i in range(len(t)):
        if use_cls and cls[i] != 0:
            continue
        f = np.intp(p[i]) * hw + np.intp(y[i]) * width + np.intp(x[i])
        last_t[f] = max(t[i] - base, floor)
        if counts[f] != COUNT_MAX:
            counts[f] += 1


@njit(cache=True, nogil=True)
def last_time_take(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail, base, last_t):
    """An overlapping window's part of a chunk in one call (`SlidingFramer.follower.take`): what
    `slide_kernel` does (count the events from i up to `end`, buffer those at or after keep_t), each event
    also made its pixel's newest time as `last_time_of` does. Returns (stop, the new tail, how many
    counted), or (stop, −1, the room needed) doing nothing, as it."""
    stop, mid = frame_part(t, i, end, keep_t)
    if tail + stop - mid > len(buf_t):
        return stop, -1, stop - mid
    floor = np.iinfo(last_t.dtype).min
    added = 0
    for k in range(i, mid):
        j = ix(k)
        if use_cls and cls[j] != 0:
            continue
        f = ix(np.intp(p[j]) * hw + np.intp(y[j]) * width + np.intp(x[j]))
        if counts[f] != COUNT_MAX:
            counts[f] += 1
        last_t[f] = max(t[j] - base, floor)
        added += 1
    n = buffer_events(t, x, y, p, cls, use_cls, mid, stop, width, hw, buf_t, buf_f, tail)
    for k in range(tail, tail + n):
        f = ix(buf_f[ix(k)])
        if counts[f] != COUNT_MAX:
            counts[f] += 1
        last_t[f] = max(buf_t[ix(k)] - base, floor)
    return stop, tail + n, added + n


@njit(cache=True, nogil=True)
def rebase(last_t, delta):
    """last_t −= delta (>= 0: the base only moves forward), those that fall below the dtype's range
    becoming its smallest value ("never")."""
    floor = np.iinfo(last_t.dtype).min
    for f in range(len(last_t)):
        last_t[f] = max(np.int64(last_t[f]) - delta, floor)  # widened: as plain Python (mutation runs) too


EXP_FLOOR = -110.0  # float32 exp underflows to 0 below about −103.97
# Below this exponent the float32 exp is under the smallest normal float32 (2^-126 = exp(−87.34)): the
# surface there is a pixel more than 87 τ old, taken as EXP_FLOOR, 0 (an absolute change under 1.2e-38).
# numpy's exp of a subnormal result runs ~13x slower (890 µs instead of 67 µs for 346x260x2), and every
# pixel that goes quiet passes through 87-104 τ.
EXP_MIN_NORMAL = -87.3


@njit(cache=True, nogil=True)
def surface_exponent(last_t, t_now, inv_tau, out):
    """out[f] = −(t_now − last_t[f]) / τ in float32 (the µs difference taken exactly in int64 first), or
    EXP_FLOOR where that is below EXP_MIN_NORMAL. `surface` then takes numpy's vectorised float32 exp:
    ~10x faster than exp in this loop, which numba does not vectorise."""
    for f in range(len(last_t)):
        e = np.float32((np.int64(last_t[f]) - t_now) * inv_tau)
        out[f] = e if e >= np.float32(EXP_MIN_NORMAL) else np.float32(EXP_FLOOR)


def surface(last_t: np.ndarray, t_now: int, tau_us: float, out: np.ndarray) -> None:
    """out = exp(−(t_now − last_t) / τ) as float32 (t_now on last_t's base); 0 where last_t is "never"."""
    surface_exponent(last_t, t_now, 1.0 / tau_us, out)
    np.exp(out, out=out)


# -- the buffered events of the open windows ------------------------------------------------------
class _EventBuffer:
    """Counted events in stream order (time, flat index p·H·W + y·W + x), addressed by absolute index
    (events since the stream began); `drop_before(k)` forgets those below k by moving a cursor, and
    the held events move to the front only when the space after them runs out (a copy per push would
    move a whole window's events for every chunk). Grows by doubling, keeping half free: bounded by
    the events the open windows still need."""

    def __init__(self, flat_dtype):
        self.t = np.zeros(1 << 12, np.int64)
        self.f = np.zeros(1 << 12, flat_dtype)
        self.origin = 0  # absolute index of slot 0
        self.lo = 0  # held events: slots [lo, hi)
        self.hi = 0

    @property
    def base(self) -> int:
        """Absolute index of the first held event."""
        return self.origin + self.lo

    @property
    def end(self) -> int:
        return self.origin + self.hi

    def append(self, chunk: EventChunk, cls, use_cls: bool, width: int, hw: int) -> None:
        idx = np.flatnonzero(cls == 0) if use_cls else None
        k = len(chunk) if idx is None else len(idx)
        if self.hi + k > len(self.t):
            live = self.hi - self.lo
            if 2 * (live + k) > len(self.t):
                size = max(2 * len(self.t), 2 * (live + k))
                t, f = np.zeros(size, np.int64), np.zeros(size, self.f.dtype)
            else:
                t, f = self.t, self.f
            t[:live] = self.t[self.lo : self.hi]  # the source lies after the target: a forward copy is safe
            f[:live] = self.f[self.lo : self.hi]
            self.t, self.f = t, f
            self.origin += self.lo
            self.lo, self.hi = 0, live
        at = self.hi
        if idx is None:
            self.t[at : at + k] = chunk.t
            flat_index(chunk.x, chunk.y, chunk.p, 0, k, width, hw, self.f, at)
        else:
            self.t[at : at + k] = chunk.t[idx]
            flat_index_of(chunk.x, chunk.y, chunk.p, idx, width, hw, self.f, at)
        self.hi += k

    def index_of_time(self, t: int, low: int) -> int:
        """The absolute index of the first held event at or after `low` with time >= t."""
        a = low - self.origin
        return low + int(np.searchsorted(self.t[a : self.hi], t, side="left"))

    def drop_before(self, k: int) -> None:
        self.lo = min(max(k, self.base), self.end) - self.origin


class _Grid:
    """A window's array while its events are added: `data` (C, H, W) float32, `flat` its flat view, of
    which the first `ready` elements are written; the rest is not initialised yet (voxel grids zero a bin
    when the first event reaches it: `_zeroed_through`). `done()` zeroes the rest and gives `data`."""

    __slots__ = ("data", "flat", "ready")

    def __init__(self, data: np.ndarray, ready: int):
        self.data, self.flat, self.ready = data, data.reshape(-1), ready

    def done(self) -> np.ndarray:
        self.flat[self.ready :] = 0
        self.ready = len(self.flat)
        return self.data


# -- framers --------------------------------------------------------------------------------------
@dataclass(eq=False)
class RepresentationFramer(FramerBase):
    """Base of the representation framers: drives the windowing framer `window` (fw, fn, oa, adaptive)
    with its parameters (None: the window's default; one it does not have is an error) and adds each
    window's representation. Subclasses give `channels_of` and `_compute`."""

    needs_events: ClassVar[bool] = True
    # Over fixed-count windows: `_compute` counts each frame's events into its counts as it makes the
    # array (the windowing framer then only finds the windows: `FixedCount.follower`).
    counts_fn: ClassVar[bool] = False

    window: str = "fw"
    window_us: int | None = None
    stride_us: int | None = None
    n_events: int | None = None
    max_window_us: int | None = None
    n_base: int | None = None
    k_us_per_event: float | None = None
    overlap_max_us: int | None = None
    overlap_init_us: int | None = None
    max_empty_frames: int | None = None
    all_events: bool = False

    def params(self) -> dict:
        """The parameters given (a window parameter left at None takes the window's default)."""
        return {k: v for k, v in super().params().items() if v is not None}

    # -- construction --------------------------------------------------------------------------
    def _window_spec(self) -> dict:
        if self.window not in WINDOWS:
            raise ValueError(f"{self.kind}: window must be one of {', '.join(WINDOWS)}, got {shown(self.window)}")
        spec = {"kind": self.window, "all_events": self.all_events}
        given = {name: getattr(self, name) for name in WINDOW_PARAMS if getattr(self, name) is not None}
        accepted = {f.name for f in dataclasses.fields(build("framer", {"kind": self.window}))}
        wrong = sorted(set(given) - accepted)
        if wrong:
            raise ValueError(f"{self.kind}: {wrong[0]} does not apply to window {self.window!r} "
                             f"(its parameters: {', '.join(sorted(accepted - {'all_events'}))})")
        return {**spec, **given}

    def _setup(self) -> None:
        if not isinstance(self.all_events, (bool, np.bool_)):
            raise ValueError(f"{self.kind}: all_events must be true or false, got {shown(self.all_events)}")
        self._spec = self._window_spec()
        build("framer", self._spec)  # check the window's parameters now, not at the first event
        self._reset()

    def _reset(self) -> None:
        self.inner = build("framer", self._spec)
        self.geometry = None
        self._buf: _EventBuffer | None = None
        self._assigned = 0  # fn: absolute index of the first buffered event no emitted window holds
        # Windows whose span is known when they open (fixed time and overlapping ones): a subclass with
        # `_add` adds each event to its window's array as the windowing framer counts it (no buffer of
        # its own, no second pass). Arrays by window start. Fixed-count windows learn their span only
        # when they close: they buffer.
        self._direct = self.window != "fn" and type(self)._add is not RepresentationFramer._add
        if self._direct:
            self.inner.follower = self  # it calls `add` and `add_flat` as it counts
        elif self.window == "fn" and self.counts_fn:
            self.inner.follower = self  # it leaves each frame's counts to `_compute`
        self._open: dict[int, _Grid] = {}

    def frame_step(self) -> tuple[int | None, int | None]:
        return self.inner.frame_step()

    def pause_step_us(self) -> int | None:
        return self.inner.pause_step_us()

    def frame_bytes(self, n_pixels: int) -> int:
        """The window's counts and the representation's float32 channels."""
        return super().frame_bytes(n_pixels) + len(self.channels) * n_pixels * 4

    @property
    def channels(self) -> tuple:
        return self.channels_of()

    def channels_of(self) -> tuple:
        raise NotImplementedError

    # -- streaming ------------------------------------------------------------------------------
    def push(self, chunk: EventChunk) -> list[Representation]:
        if len(chunk) or self.geometry is not None:
            self._geometry(chunk)
            if self.needs_events and not self._direct:
                cls, use_cls = self._cls(chunk)
                self._buf.append(chunk, cls, use_cls, self._width, self._hw)
        out = self._represent(self.inner.push(chunk))
        self._forget()
        return out

    def add(self, chunk: EventChunk, cls, use_cls: bool, a: int, b: int, t_start: int, t_end: int, counts) -> int:
        """Called by the fixed time windowing framer as it counts (`FixedWindow.follower`): the
        chunk's events [a, b) go into the window [t_start, t_end) and its `counts`; returns how many
        counted."""
        grid = self._window_grid(t_start)
        n = self._count_add(chunk, cls, use_cls, a, b, t_start, t_end, counts, grid)
        if n is not None:
            return n
        self._add(chunk.t[a:b], chunk.x[a:b], chunk.y[a:b], chunk.p[a:b], cls[a:b], use_cls, t_start, t_end, grid)
        return accumulate(chunk.x, chunk.y, chunk.p, cls, use_cls, a, b, counts, self._width, self._hw)

    def take(self, chunk: EventChunk, cls, use_cls: bool, i: int, t_start: int, t_end: int, keep_t: int, counts,
             buf_t, buf_f, tail: int) -> tuple[int, int, int]:
        """Called by an overlapping windowing framer (`SlidingFramer.follower`): `slide_kernel` (count the
        chunk's events from i up to t_end, buffer those at or after keep_t) for the window [t_start, t_end),
        the events also added to its array. Returns what `slide_kernel` returns."""
        grid = self._window_grid(t_start)
        got = self._count_take(chunk, cls, use_cls, i, t_start, t_end, keep_t, counts, buf_t, buf_f, tail, grid)
        if got is not None:
            return got
        stop, end, added = slide_kernel(chunk.t, chunk.x, chunk.y, chunk.p, cls, use_cls, i, t_end, keep_t,
                                        self._width, self._hw, counts, buf_t, buf_f, tail)
        if end < 0:  # no room: nothing done
            return stop, end, added
        mid = i + int(np.searchsorted(chunk.t[i:stop], keep_t))
        if mid > i:
            self._add(chunk.t[i:mid], chunk.x[i:mid], chunk.y[i:mid], chunk.p[i:mid], cls[i:mid], use_cls, t_start,
                      t_end, grid)
        self._add_flat(buf_t[tail:end], buf_f[tail:end], t_start, t_end, grid)
        return stop, end, added

    def _count_take(self, chunk, cls, use_cls, i, t_start, t_end, keep_t, counts, buf_t, buf_f, tail,
                    grid) -> tuple[int, int, int] | None:
        """`take` in one kernel call where a subclass has a kernel for it, else None."""
        return None

    def add_flat(self, t: np.ndarray, f: np.ndarray, t_start: int, t_end: int, counts) -> None:
        """Overlapping windows (called by the windowing framer): counted events (times, flat indices, in
        stream order) go into the window [t_start, t_end) and its `counts`: those it buffers, and those a
        window opens with."""
        grid = self._window_grid(t_start)
        if not self._count_add_flat(t, f, t_start, t_end, counts, grid):
            self._add_flat(t, f, t_start, t_end, grid)
            add_flat(counts, f, 0, len(f))

    def closed(self, fr: Frame) -> None:
        """Called by an overlapping windowing framer as it emits `fr` (`SlidingFramer.follower`)."""

    def _window_grid(self, t_start: int) -> _Grid:
        """The array of the window starting at t_start (new at its first event)."""
        grid = self._open.get(t_start)
        if grid is None:
            grid = self._open[t_start] = self._new_grid()
        return grid

    def _count_add(self, chunk, cls, use_cls, a, b, t_start, t_end, counts, grid) -> int | None:
        """`add` in one pass where a subclass has a kernel for it (how many counted), else None."""
        return None

    def _count_add_flat(self, t, f, t_start, t_end, counts, grid) -> bool:
        """`add_flat` in one pass where a subclass has a kernel for it (True), else False."""
        return False

    def _add(self, t, x, y, p, cls, use_cls: bool, t_start: int, t_end: int, grid: _Grid) -> None:
        """Add events (slices of a chunk's fields, all in the window [t_start, t_end)) to its `grid`: the
        counted ones, `cls` 0, when `use_cls`."""

    def _add_flat(self, t, f, t_start: int, t_end: int, grid: _Grid) -> None:
        """Add counted events (times, flat indices p·H·W + y·W + x), all in [t_start, t_end), to `grid`."""

    def finish(self) -> list[Representation]:
        out = self._represent(self.inner.finish())
        self._reset()
        return out

    def _geometry(self, chunk: EventChunk) -> None:
        if self.geometry is None:
            super()._reset()
            super()._geometry(chunk)
            if self.needs_events and not self._direct:
                self._buf = _EventBuffer(np.uint32 if 2 * self._hw < 2**32 else np.int64)
            self._on_geometry()

    def _on_geometry(self) -> None:
        """Allocate per-sensor state (subclasses)."""

    def _represent(self, frames: list[Frame]) -> list[Representation]:
        out = []
        for fr in frames:
            if self._direct:
                grid = self._open.pop(fr.t_start, None)
                data = self._new_data(len(self.channels)) if grid is None else grid.done()  # None: no event
                out.append(Representation(fr.t_start, fr.t_end, fr.n_events, fr.counts, self.kind,
                                          self.channels, data))
                continue
            a = b = 0
            if self.needs_events:
                a, b = self._events_of(fr)
            data = self._compute(fr, a, b)
            out.append(Representation(fr.t_start, fr.t_end, fr.n_events, fr.counts, self.kind,
                                      self.channels, data))
        return out

    def _events_of(self, fr: Frame) -> tuple[int, int]:
        """Absolute buffer indices [a, b) of the frame's events: by count for fixed-count windows (an
        event at the closing time may belong to the next one), by time for the others."""
        buf = self._buf
        if self.window == "fn":
            a = self._assigned
            self._assigned = a + fr.n_events
            return a, a + fr.n_events
        a = buf.index_of_time(fr.t_start, buf.base)
        return a, buf.index_of_time(fr.t_end, a)

    def _forget(self) -> None:
        """Drop the buffered events no open or future window can hold (windows whose events go straight
        into their arrays: the arrays of windows the framer has passed without emitting them, which
        held no counted event)."""
        if self._direct:
            start = self.inner.start
            for s in [s for s in self._open if start is None or s < start]:
                del self._open[s]
            return
        buf = self._buf
        if buf is None:
            return
        if self.window == "fn":
            keep = self._assigned
        else:
            start = getattr(self.inner, "start", None)
            keep = buf.end if start is None else buf.index_of_time(start, buf.base)
        buf.drop_before(keep)

    def _compute(self, fr: Frame, a: int, b: int) -> np.ndarray:
        raise NotImplementedError

    def _new_data(self, channels: int) -> np.ndarray:
        g = self.geometry
        return np.zeros((channels, g.height, g.width), np.float32)

    def _new_grid(self) -> _Grid:
        """A new window's array (zeroed: subclasses whose kernels zero as they go override it)."""
        data = self._new_data(len(self.channels))
        return _Grid(data, data.size)

    def _local(self, a: int, b: int) -> tuple[int, int]:
        base = self._buf.origin
        return a - base, b - base


@register("framer", "histogram")
@dataclass(eq=False)
class Histogram(RepresentationFramer):
    """Two-channel event histogram (OFF, ON): events per pixel and polarity in each window."""

    needs_events: ClassVar[bool] = False

    def __post_init__(self):
        self._setup()

    def channels_of(self) -> tuple:
        return ("off", "on")

    def _compute(self, fr: Frame, a: int, b: int) -> np.ndarray:
        return np.ascontiguousarray(fr.counts, dtype=np.float32)


@register("framer", "count")
@dataclass(eq=False)
class CountImage(RepresentationFramer):
    """Event-count image (one channel): events per pixel in each window, both polarities."""

    needs_events: ClassVar[bool] = False

    def __post_init__(self):
        self._setup()

    def channels_of(self) -> tuple:
        return ("events",)

    def _compute(self, fr: Frame, a: int, b: int) -> np.ndarray:
        out = np.empty((1, *fr.counts.shape[1:]), np.float32)
        np.add(fr.counts[0], fr.counts[1], out=out[0], dtype=np.float32)
        return out


@register("framer", "timestamp")
@dataclass(eq=False)
class TimestampImage(RepresentationFramer):
    """Last-timestamp image (OFF, ON): the newest event of the window per pixel, as (t − t_start + 1) /
    (t_end − t_start) in (0, 1]; 0 where none."""


    def __post_init__(self):
        self._setup()

    def channels_of(self) -> tuple:
        return ("off", "on")

    def _add(self, t, x, y, p, cls, use_cls, t_start, t_end, grid):
        timestamp_of_chunk(t, x, y, p, cls, use_cls, t_start, t_end, self._width, self._hw, grid.flat)

    def _add_flat(self, t, f, t_start, t_end, grid):
        timestamp_kernel(t, f, t_start, t_end, grid.flat)

    def _compute(self, fr: Frame, a: int, b: int) -> np.ndarray:
        grid = self._new_grid()
        la, lb = self._local(a, b)
        self._add_flat(self._buf.t[la:lb], self._buf.f[la:lb], fr.t_start, fr.t_end, grid)
        return grid.done()


@register("framer", "voxel")
@dataclass(eq=False)
class VoxelGrid(RepresentationFramer):
    """Voxel grid (Zhu et al. 2019): `bins` temporal bins per window, polarity ±1 shared bilinearly in
    time between the two nearest bins."""

    bins: int = 5
    counts_fn: ClassVar[bool] = True

    def __post_init__(self):
        check_positive_int(self, "bins")
        self._setup()

    def channels_of(self) -> tuple:
        return tuple(f"bin{b}" for b in range(self.bins))

    def _on_geometry(self) -> None:
        self._tab, self._tab_span = None, None

    def _new_grid(self) -> _Grid:
        g = self.geometry
        return _Grid(np.empty((self.bins, g.height, g.width), np.float32), 0)  # bins zeroed as events reach them

    def _add(self, t, x, y, p, cls, use_cls, t_start, t_end, grid):
        table = self._table(t_end - t_start)
        if table is None:
            grid.ready = voxel_of_chunk(t, x, y, p, cls, use_cls, t_start, t_end, self.bins, self._width, self._hw,
                                        grid.flat, grid.ready)
        else:
            grid.ready = voxel_table_of_chunk(t, x, y, p, cls, use_cls, t_start, self._width, self._hw, *table,
                                              grid.flat, grid.ready)

    def _add_flat(self, t, f, t_start, t_end, grid):
        table = self._table(t_end - t_start)
        if table is None:
            grid.ready = voxel_kernel(t, f, t_start, t_end, self.bins, self._hw, grid.flat, grid.ready)
        else:
            grid.ready = voxel_table_kernel(t, f, t_start, self._hw, *table, grid.flat, grid.ready)

    def _count_add(self, chunk, cls, use_cls, a, b, t_start, t_end, counts, grid):
        table = self._table(t_end - t_start)
        if table is None:
            return None
        n, grid.ready = voxel_count_of_chunk(chunk.t, chunk.x, chunk.y, chunk.p, cls, use_cls, a, b, t_start,
                                             self._width, self._hw, *table, counts, grid.flat, grid.ready)
        return n

    def _count_take(self, chunk, cls, use_cls, i, t_start, t_end, keep_t, counts, buf_t, buf_f, tail, grid):
        table = self._table(t_end - t_start)
        if table is None:
            return None
        stop, end, added, grid.ready = voxel_take(chunk.t, chunk.x, chunk.y, chunk.p, cls, use_cls, i, t_end, keep_t,
                                                  self._width, self._hw, counts, buf_t, buf_f, tail, t_start, *table,
                                                  grid.flat, grid.ready)
        return stop, end, added

    def _count_add_flat(self, t, f, t_start, t_end, counts, grid):
        table = self._table(t_end - t_start)
        if table is None:
            return False
        grid.ready = voxel_count_flat(t, f, t_start, self._hw, *table, counts, grid.flat, grid.ready)
        return True

    def _table(self, span_us: int):
        """The arithmetic table of windows `span_us` long (`voxel_table`), for windows whose span is known
        when they open (all of one span); None for fixed-count windows, spans over VOXEL_TABLE_MAX_US and one bin."""
        if self.window == "fn" or span_us > VOXEL_TABLE_MAX_US or self.bins < 2:
            return None
        if self._tab_span != span_us:
            lo_at = np.empty(2 * span_us, np.intp)
            w_lo, w_hi = np.empty(2 * span_us, np.float32), np.empty(2 * span_us, np.float32)
            voxel_table(span_us, self.bins, self._hw, lo_at, w_lo, w_hi)
            self._tab, self._tab_span = (lo_at, w_lo, w_hi), span_us
        return self._tab

    def _compute(self, fr: Frame, a: int, b: int) -> np.ndarray:
        """Fixed-count windows: the array and the frame's counts, from the window's buffered events."""
        grid = self._new_grid()
        la, lb = self._local(a, b)
        grid.ready = voxel_count_kernel(self._buf.t[la:lb], self._buf.f[la:lb], fr.t_start, fr.t_end, self.bins,
                                        self._hw, fr.counts.reshape(-1), grid.flat, grid.ready)
        return grid.done()


@register("framer", "timesurface")
@dataclass(eq=False)
class TimeSurface(RepresentationFramer):
    """Time surface (OFF, ON) at each window's end: exp(−(t_end − t_last)/`tau_us`), t_last the newest
    event at that pixel and polarity so far in the stream; 0 where none yet.

    It buffers no events: the newest time per pixel is brought up to each emitted window's end straight
    from the chunk (the events before the end, or for fixed-count windows up to the window's last
    counted event), then the rest of the chunk is applied. That is exact: a window emitted by a later
    push ends after every event of this chunk (it would have closed on this chunk's watermark
    otherwise), and an open fixed-count window holds every counted event after the emitted ones.
    Over fixed time windows it counts the frames' events too, in the same pass (the windowing framer leaves
    them to it: `FixedWindow.follower`; over fixed-count windows that measured ~3 % slower than letting
    the framer count, as it does). Over overlapping windows the windowing framer hands it each window's
    part of a chunk (`take`: counts, buffer and newest times in one kernel call, `last_time_take`) and
    each window as it closes, before any later event is applied (`closed`: its surface then)."""

    tau_us: float = 50_000.0
    needs_events: ClassVar[bool] = False

    def __post_init__(self):
        tau = self.tau_us
        if isinstance(tau, bool) or not isinstance(tau, (int, float, np.number)) or not 0 < tau <= MAX_TAU_US:
            raise ValueError(f"timesurface: tau_us must be a number in (0, 2^40] µs, got {shown(tau)}")
        self.tau_us = float(tau)
        self._setup()

    def channels_of(self) -> tuple:
        return ("off", "on")

    def _reset(self) -> None:
        super()._reset()
        if self.window != "fn":
            self.inner.follower = self  # fw: `add` below (the counts are left to `_surfaces`); oa, adaptive: `take`
        self._counting = self.window == "fw"  # `_apply` counts the frames' events
        self._sliding = self.window in ("oa", "adaptive")  # surfaces made as the windows close: `closed`
        self._made: list[np.ndarray] = []  # oa, adaptive: the surfaces of the windows closed in this push
        self._last_t = None
        self._counted = 0  # counted events in the chunks before this one
        self._emitted = 0  # fn: counted events in the windows emitted so far

    def take(self, chunk: EventChunk, cls, use_cls: bool, i: int, t_start: int, t_end: int, keep_t: int, counts,
             buf_t, buf_f, tail: int) -> tuple[int, int, int]:
        """Overlapping windows (`SlidingFramer.follower`): `slide_kernel` and the newest times of the same
        events (those before t_end: each window's surface is made as it closes, `closed`), in one call."""
        last = self._last_t
        t_hi = min(t_end - 1, int(chunk.t[-1]))  # the latest event this call can apply
        if last.dtype == np.int32 and t_hi - self._base >= REBASE_US:
            rebase(last, t_hi - self._base)  # as `_apply`; every window still to close ends after t_hi
            self._base = t_hi
        return last_time_take(chunk.t, chunk.x, chunk.y, chunk.p, cls, use_cls, i, t_end, keep_t, self._width,
                              self._hw, counts, buf_t, buf_f, tail, self._base, last)

    def add_flat(self, t: np.ndarray, f: np.ndarray, t_start: int, t_end: int, counts) -> None:
        """Overlapping windows: the events a window opens with are counted (their newest times are applied)."""
        add_flat(counts, f, 0, len(f))

    def closed(self, fr: Frame) -> None:
        """Overlapping windows: `fr` closes with every event before its end applied, none after: its surface."""
        self._made.append(self._surface_at(fr.t_end))

    def _surface_at(self, t_end: int) -> np.ndarray:
        if self._last_t is None:
            return self._new_data(2)
        g = self.geometry
        data = np.empty((2, g.height, g.width), np.float32)  # every pixel is written
        surface(self._last_t, t_end - self._base, self.tau_us, data.reshape(-1))
        return data

    def _with_surfaces(self, frames: list[Frame]) -> list[Representation]:
        """Overlapping windows: the frames with the surfaces `closed` made, in order."""
        made, self._made = self._made, []
        return [Representation(fr.t_start, fr.t_end, fr.n_events, fr.counts, self.kind, self.channels, data)
                for fr, data in zip(frames, made, strict=True)]

    def add(self, chunk: EventChunk, cls, use_cls: bool, a: int, b: int, t_start: int, t_end: int, counts) -> int:
        """Fixed time windows (called by the windowing framer): how many of the events [a, b) count. They are
        counted into the frame's counts by `_surfaces` as it applies them, before the frame is handed on."""
        return b - a if not use_cls else int(np.count_nonzero(cls[a:b] == 0))

    def _on_geometry(self) -> None:
        # int32 times (relative to `_base`) halve the memory each event and each window touch. A pixel
        # whose time no longer fits at a rebase is at least 2^31 µs >= 128 τ old: its surface is
        # exp(<= −128) = 0 in float32 already, so "never" is exact. Longer τ keep absolute int64 times.
        if self.tau_us * 128 <= 1 << 31:
            self._last_t = np.full(2 * self._hw, np.iinfo(np.int32).min, np.int32)
        else:
            self._last_t = np.full(2 * self._hw, NEVER_US, np.int64)
        self._base = 0

    def _apply(self, chunk: EventChunk, cls, use_cls: bool, a: int, b: int, counts) -> None:
        """Bring the newest times up to date with the chunk's events [a, b), and count them into the flat
        `counts` of the frame that holds them (None: the windowing framer counted them)."""
        last = self._last_t
        if last.dtype == np.int32 and int(chunk.t[b - 1]) - self._base >= REBASE_US:
            new_base = int(chunk.t[b - 1])  # events up to 2^31 µs older still fit; older ones become "never"
            rebase(last, new_base - self._base)
            self._base = new_base
        if counts is None:
            last_time_of(chunk.t[a:b], chunk.x[a:b], chunk.y[a:b], chunk.p[a:b], cls[a:b], use_cls, self._width,
                         self._hw, self._base, last)
        else:
            last_time_count_of(chunk.t[a:b], chunk.x[a:b], chunk.y[a:b], chunk.p[a:b], cls[a:b], use_cls,
                               self._width, self._hw, self._base, last, counts)

    def push(self, chunk: EventChunk) -> list[Representation]:
        if len(chunk) or self.geometry is not None:
            self._geometry(chunk)
        if self._sliding:
            return self._with_surfaces(self.inner.push(chunk))
        return self._surfaces(self.inner.push(chunk), chunk)

    def finish(self) -> list[Representation]:
        frames = self.inner.finish()
        out = self._with_surfaces(frames) if self._sliding else self._surfaces(frames, None)  # all applied already
        self._reset()
        return out

    def _surfaces(self, frames: list[Frame], chunk: EventChunk | None) -> list[Representation]:
        n = 0 if chunk is None else len(chunk)
        cls, use_cls = self._cls(chunk) if n else (None, False)
        where = None  # fn with classes: the chunk positions of its counted events
        i = 0  # chunk events applied so far
        out = []
        for fr in frames:
            if n:
                if self.window == "fn":
                    self._emitted += fr.n_events
                    k = self._emitted - self._counted  # this chunk's counted events in or before the window
                    if use_cls and k > 0:
                        where = np.flatnonzero(cls == 0) if where is None else where
                        j = int(where[k - 1]) + 1
                    else:
                        j = max(k, 0)
                else:
                    j = i + int(np.searchsorted(chunk.t[i:], fr.t_end, side="left"))
                if j > i:  # a window of uncounted events only is empty: its counts are the shared read-only zeros
                    counting = self._counting and fr.n_events > 0
                    self._apply(chunk, cls, use_cls, i, j, fr.counts.reshape(-1) if counting else None)
                    i = j
            data = self._surface_at(fr.t_end)
            out.append(Representation(fr.t_start, fr.t_end, fr.n_events, fr.counts, self.kind, self.channels, data))
        if n:
            if i < n:  # the open window's events
                self._apply(chunk, cls, use_cls, i, n, self.inner.counts if self._counting else None)
            self._counted += n if not use_cls else int(np.count_nonzero(cls == 0))
        return out


REPRESENTATIONS = ("timesurface", "voxel", "histogram", "count", "timestamp")
