"""Overlapping framers: overlapping accumulation (OA) and the paper's adaptive overlap, with their kernels.

Both emit frames [s_i, s_i + window_us) whose starts advance by less than a window, so consecutive
frames share events. OA advances by a fixed `stride_us`. The adaptive framer (Jiang et al. 2024,
Eq. 5, as reconstructed in DESIGN.md §5) sets the overlap of the next frame from the events n_i in
this one: O_{i+1} = clip(O_i + k·(n_i − N_base), 0, O_max), s_{i+1} = s_i + Δt − O_{i+1}; more
events than the baseline, more overlap, a higher frame rate. O is kept in whole µs (each step's
k·(n_i − N_base) rounded half to even), so frame times are exact integers.

One frame is materialised at a time. Its counted events that a next frame may share (those in its last
`_reach_us`) wait in a buffer (time and flat pixel index), bounded by the events of one window. When
the frame closes, the next one's counts are rebuilt from the buffered events that stay (subtracting
those that leave cannot work: the frame's earlier events are not buffered, and counts saturate). Each
frame's part of a chunk is counted and buffered in one kernel call (`slide_kernel`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..events import EventChunk, Frame, shown
from ..jit import njit
from ..nowrap import ix
from ..pipeline import register
from .base import COUNT_MAX, FramerBase, check_nonnegative_int, check_positive_int, watermark
from .fixed import accumulate

INITIAL_BUFFER_EVENTS = 1 << 14


@njit(cache=True, nogil=True)
def flat_index(x, y, p, a, b, width, hw, out, at):
    """out[at + j] = the flat count index p·H·W + y·W + x of event a + j, for the events [a, b)."""
    for k in range(a, b):
        i = ix(k)  # unsigned: no negative-index test on each access
        out[ix(at + k - a)] = np.intp(p[i]) * hw + np.intp(y[i]) * width + x[i]


@njit(cache=True, nogil=True)
def flat_index_of(x, y, p, idx, width, hw, out, at):
    """out[at + j] = the flat count index of event idx[j]."""
    for j in range(len(idx)):
        i = idx[j]
        out[at + j] = np.intp(p[i]) * hw + np.intp(y[i]) * width + x[i]


@njit(cache=True, nogil=True)
def add_flat(counts, flat, a, b):
    """counts[flat[j]] += 1 for j in [a, b), saturating."""
    for j in range(a, b):
        f = flat[ix(j)]
        if counts[f] != COUNT_MAX:
            counts[f] += 1


@njit(cache=True, nogil=True)
def buffer_events(t, x, y, p, cls, use_cls, a, b, width, hw, buf_t, buf_f, at):
    """Buffer the counted events [a, b) at buf_t/buf_f[at:] (time, flat index p·H·W + y·W + x); returns how
    many. Without classes, two simple passes (a copy and `flat_index`): they run ~2x faster than one loop
    storing to both arrays, which numba cannot prove distinct."""
    if not use_cls:
        for k in range(a, b):
            buf_t[ix(at + k - a)] = t[ix(k)]
        flat_index(x, y, p, a, b, width, hw, buf_f, at)
        return b - a
    j = at
    for k in range(a, b):
        i = ix(k)
        if cls[i] == 0:
            buf_t[ix(j)] = t[i]
            buf_f[ix(j)] = np.intp(p[i]) * hw + np.intp(y[i]) * width + x[i]
            j += 1
    return j - at


@njit(cache=True, nogil=True)
def frame_part(t, i, end, keep_t):
    """(stop, mid): the chunk's events [i, stop) are before the frame's `end`, and [mid, stop) of them at
    or after `keep_t` (those a next frame may also hold). Binary searches, as `np.searchsorted`."""
    stop = i + np.searchsorted(t[i:], end)
    return stop, i + np.searchsorted(t[i:stop], keep_t)


@njit(cache=True, nogil=True)
def slide_kernel(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail):
    """The current frame's part of a chunk in one call: from event i up to the first event at or past `end`
    (`stop`), count the counted events into the flat `counts` (saturating) and buffer those at or after
    `keep_t` at buf_t/buf_f[tail:]. Returns (stop, the new tail, how many counted), or, doing nothing when
    the buffer has no room for the events it may buffer, (stop, −1, how many that is)."""
    stop, mid = frame_part(t, i, end, keep_t)
    if tail + stop - mid > len(buf_t):
        return stop, -1, stop - mid
    added = accumulate(x, y, p, cls, use_cls, i, mid, counts, width, hw)
    k = buffer_events(t, x, y, p, cls, use_cls, mid, stop, width, hw, buf_t, buf_f, tail)
    add_flat(counts, buf_f, tail, tail + k)
    return stop, tail + k, added + k


class SlidingFramer(FramerBase):
    """Shared machinery of OA and adaptive: subclasses give `window_us`, `_next_start` and `_reach_us`,
    the most a next frame can reach back into this one (its events before `end − reach` are never
    needed again, so only the later ones are buffered)."""

    window_us: int
    # A representation framer follows the frames' events (so it needs no buffer of its own) and counts
    # them for the frame in the same pass (one pass over the events instead of two): in stream order,
    # `follower.take(chunk, cls, use_cls, i, start, end, keep_t, counts, buf_t, buf_f, tail)` does what
    # `slide_kernel` does for the frame [start, end) (counts the chunk's events from i up to `end` into
    # its `counts`, buffers those at or after keep_t, returns (stop, tail, how many counted), or (stop,
    # −1, the room it needs) doing nothing) and adds them to its own array; `follower.add_flat(t, f,
    # start, end, counts)` counts buffered events (times, flat indices, all counted) as `add_flat` does:
    # those a new frame starts with when the previous one closes; `follower.closed(frame)` is called as
    # each frame is emitted, before any later event is taken.
    follower = None

    def _reset(self) -> None:
        super()._reset()
        self.start: int | None = None  # current frame [start, end)
        self.end = 0
        self.counts = None
        self.buf_t = np.zeros(0, np.int64)
        self.buf_f = np.zeros(0, np.int64)
        self.head = 0  # buffered events of the current frame (those at or after end − reach): [head, tail)
        self.tail = 0
        self.n = 0  # counted events in the current frame so far

    def _first(self, t0: int) -> None:
        self.start = t0
        self.end = t0 + self.window_us
        self.counts = self._new_counts()
        flat_dtype = np.uint32 if 2 * self._hw < 2**32 else np.int64
        self.buf_t = np.zeros(INITIAL_BUFFER_EVENTS, np.int64)
        self.buf_f = np.zeros(INITIAL_BUFFER_EVENTS, flat_dtype)

    def push(self, chunk: EventChunk) -> list[Frame]:
        if self.start is None and not len(chunk):
            return []
        self._geometry(chunk)
        out: list[Frame] = []
        if len(chunk):
            if self.start is None:
                self._first(int(chunk.t[0]))
            cls, use_cls = self._cls(chunk)
            n = len(chunk)
            i = 0
            while True:  # one kernel call per frame's part of the chunk
                keep_t = self.end - self._reach_us
                if self.follower is None:
                    stop, tail, added = slide_kernel(chunk.t, chunk.x, chunk.y, chunk.p, cls, use_cls, i, self.end,
                                                     keep_t, self._width, self._hw, self.counts, self.buf_t,
                                                     self.buf_f, self.tail)
                else:
                    stop, tail, added = self.follower.take(chunk, cls, use_cls, i, self.start, self.end, keep_t,
                                                           self.counts, self.buf_t, self.buf_f, self.tail)
                if tail < 0:  # no room in the buffer for the `added` events it would buffer: nothing done
                    self._make_room(added)
                    continue
                i, self.tail = stop, tail
                self.n += added
                if i == n:
                    break
                self._advance(int(chunk.t[i]), out)
        self._advance(watermark(chunk), out)
        return out

    def _make_room(self, more: int) -> None:
        """Drop the buffered events no frame needs any more; grow the buffer to take `more`. The buffer
        holds only the current frame's events (and room for those of its last reach in a chunk, which a
        kernel call asks for when it lacks it), so it is bounded by the events of one window."""
        live = self.tail - self.head
        if self.head:
            self.buf_t[:live] = self.buf_t[self.head : self.tail]
            self.buf_f[:live] = self.buf_f[self.head : self.tail]
            self.head, self.tail = 0, live
        if 2 * (live + more) > len(self.buf_t):  # keep half free, so compaction copies rarely
            size = max(2 * len(self.buf_t), 2 * (live + more))
            self.buf_t = np.concatenate((self.buf_t[:live], np.zeros(size - live, np.int64)))
            self.buf_f = np.concatenate((self.buf_f[:live], np.zeros(size - live, self.buf_f.dtype)))

    def _advance(self, w: int, out: list[Frame]) -> None:
        """Emit every frame that ends at or before the watermark w."""
        while self.end <= w:
            if self.n == 0 and not self._may_emit_empty:
                self._skip_empty(w)
                return
            self._close(out)

    def _close(self, out: list[Frame]) -> None:
        """Emit the current frame and make the next one current."""
        n = self.n
        nxt = self._next_start(self.start, n)
        j = self.head + int(np.searchsorted(self.buf_t[self.head : self.tail], nxt, side="left"))
        out.append(self._frame(self.start, self.end, n, self.counts if n else None))  # the frame owns its counts
        if self.follower is not None:
            self.follower.closed(out[-1])
        if n:  # rebuild the next frame's counts from the events that stay
            self.counts = self._new_counts()
            if self.follower is None:
                add_flat(self.counts, self.buf_f, j, self.tail)
            elif j < self.tail:
                self.follower.add_flat(self.buf_t[j : self.tail], self.buf_f[j : self.tail], nxt, nxt + self.window_us,
                                       self.counts)
        self.head = j
        self.n = self.tail - j
        self.start = nxt
        self.end = nxt + self.window_us

    def _skip_empty(self, w: int) -> None:
        """Move past empty frames that end at or before w without emitting them (after
        `max_empty_frames` in a row). The generic version steps frame by frame; subclasses jump."""
        while self.end <= w:
            nxt = self._next_start(self.start, 0)
            self.start, self.end = nxt, nxt + self.window_us

    def finish(self) -> list[Frame]:
        out: list[Frame] = []
        while self.start is not None and self.n:
            self._close(out)
        self._reset()
        return out

    def _next_start(self, start: int, n: int) -> int:
        raise NotImplementedError


@register("framer", "oa")
@dataclass(eq=False)
class OverlapAccumulation(SlidingFramer):
    """OA: frames `window_us` long, one every `stride_us` (stride <= window; equal is FW; default half
    the window)."""

    window_us: int = 10_000
    stride_us: int | None = None
    all_events: bool = False
    max_empty_frames: int = 1000

    def __post_init__(self):
        check_positive_int(self, "window_us")
        if self.stride_us is None:
            self.stride_us = max(1, self.window_us // 2)
        check_positive_int(self, "stride_us")
        if self.stride_us > self.window_us:
            raise ValueError(f"oa: stride_us ({self.stride_us}) must not exceed window_us "
                             f"({self.window_us}): events between frames would be lost")
        self._check_common()
        self._reset()

    def frame_step(self) -> tuple[int | None, int | None]:
        return self.stride_us, None

    def _next_start(self, start: int, n: int) -> int:
        return start + self.stride_us

    @property
    def _reach_us(self) -> int:
        return self.window_us - self.stride_us

    def _skip_empty(self, w: int) -> None:
        k = (w - self.end) // self.stride_us + 1
        self.start += k * self.stride_us
        self.end += k * self.stride_us


@register("framer", "adaptive")
@dataclass(eq=False)
class AdaptiveOverlap(SlidingFramer):
    """The paper's adaptive overlap: slices of `window_us` (Δt) whose overlap O with the previous one
    follows the event count: O += `k_us_per_event`·(n − `n_base`), clamped to [0, `overlap_max_us`].

    Defaults: Δt = 10 ms, N_base = 8000 events (for a 346×260 sensor; scale it with the pixel count
    and the scene), k = 0.001 ms = 1 µs per event (the paper's), O_max = Δt/2 = 5 ms (ours, the default
    for any Δt: frame rate at most 2/Δt, and each event is accumulated at most twice)."""

    window_us: int = 10_000
    n_base: int = 8000
    k_us_per_event: float = 1.0
    overlap_max_us: int | None = None
    overlap_init_us: int = 0
    all_events: bool = False
    max_empty_frames: int = 1000

    def __post_init__(self):
        check_positive_int(self, "window_us")
        check_nonnegative_int(self, "n_base")
        if self.overlap_max_us is None:
            self.overlap_max_us = self.window_us // 2
        check_nonnegative_int(self, "overlap_max_us")
        check_nonnegative_int(self, "overlap_init_us")
        k = self.k_us_per_event
        if isinstance(k, bool) or not isinstance(k, (int, float, np.number)) or not np.isfinite(k) or k < 0:
            raise ValueError(f"adaptive: k_us_per_event must be a finite number >= 0, got {shown(k)}")
        self.k_us_per_event = float(k)
        if self.overlap_max_us >= self.window_us:
            raise ValueError(f"adaptive: overlap_max_us ({self.overlap_max_us}) must be less than "
                             f"window_us ({self.window_us}), or frames would stop advancing")
        if self.overlap_init_us > self.overlap_max_us:
            raise ValueError(f"adaptive: overlap_init_us ({self.overlap_init_us}) must not exceed "
                             f"overlap_max_us ({self.overlap_max_us})")
        self._check_common()
        self._reset()

    def frame_step(self) -> tuple[int | None, int | None]:
        return self.window_us - self.overlap_max_us, None  # the overlap is at most overlap_max_us

    def pause_step_us(self) -> int | None:
        return self.window_us  # no events: the overlap falls towards 0

    def _reset(self) -> None:
        super()._reset()
        self.overlap_us = self.overlap_init_us  # O_i: the current frame's overlap with the previous one

    @property
    def _reach_us(self) -> int:
        return self.overlap_max_us

    def _next_start(self, start: int, n: int) -> int:
        step = round(self.k_us_per_event * (n - self.n_base))
        self.overlap_us = min(max(self.overlap_us + step, 0), self.overlap_max_us)
        return start + self.window_us - self.overlap_us

    def _skip_empty(self, w: int) -> None:
        # With no events the overlap only shrinks (or stays): step until it settles, then jump.
        while self.end <= w:
            before = self.overlap_us
            nxt = self._next_start(self.start, 0)
            self.start, self.end = nxt, nxt + self.window_us
            if self.overlap_us == before:
                stride = self.window_us - self.overlap_us
                if self.end <= w:
                    k = (w - self.end) // stride + 1
                    self.start += k * stride
                    self.end += k * stride
                return
