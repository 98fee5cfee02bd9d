"""Fixed time window (FW) and fixed event count (FN) framers, with their numba accumulation kernels.

FW: frames [s, s + window_us) back to back, the first starting at the stream's first event (the
paper's convention); every window yields a frame once the watermark passes its end, empty ones too.
FN: each frame holds `n_events` counted events in stream order; it closes on its n-th event, or, with
`max_window_us`, once that much event time has passed since its first event (so a quiet scene still
shows its last events). FN frames span [first event, last event + 1 µs); a timed-out one ends at
first event + `max_window_us`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..events import EventChunk, Frame
from ..jit import njit
from ..nowrap import ix
from ..pipeline import register
from .base import COUNT_MAX, FramerBase, check_positive_int, watermark

NEVER_US = 1 << 62  # a deadline no stream reaches


@njit(cache=True, nogil=True)
def accumulate(x, y, p, cls, use_cls, a, b, counts, width, hw):
    """Add the counted events [a, b) to the flat counts [p][y][x] (saturating); return how many.

    The caller finds b, the frame's end, by binary search: a loop with no time test runs ~1.5x faster.
    The flat index is widened to intp explicitly: what numba does anyway, and what keeps it right as
    plain Python (tests/mutation.py), where a uint8 times an int stays uint8 under NumPy 2."""
    if use_cls:
        added = 0
        for k in range(a, b):
            i = ix(k)  # unsigned: no negative-index test on each access (~1.5x faster)
            if cls[i] == 0:
                f = np.intp(p[i]) * hw + np.intp(y[i]) * width + x[i]
                if counts[f] != COUNT_MAX:
                    counts[f] += 1
                added += 1
        return added
    for k in range(a, b):
        i = ix(k)
        f = np.intp(p[i]) * hw + np.intp(y[i]) * width + x[i]
        if counts[f] != COUNT_MAX:
            counts[f] += 1
    return b - a


FN_DONE, FN_FULL, FN_TIMEOUT = 0, 1, 2


@njit(cache=True, nogil=True)
def fn_run(t, x, y, p, cls, use_cls, i, counts, width, hw, n_have, n_target, first_t, last_t, max_window_us):
    """Add counted events from index i on until the frame holds n_target events or an event comes at or
    past first_t + max_window_us (while the frame holds any). Returns (i, n_have, first_t, last_t,
    status): FN_FULL (i is past the n-th event), FN_TIMEOUT (event i is past the deadline) or FN_DONE."""
    n = len(t)
    while i < n:
        j = ix(i)  # unsigned, as in `accumulate`
        ti = t[j]
        if n_have > 0 and ti >= first_t + max_window_us:
            return i, n_have, first_t, last_t, FN_TIMEOUT
        if not use_cls or cls[j] == 0:
            if n_have == 0:
                first_t = ti
            f = np.intp(p[j]) * hw + np.intp(y[j]) * width + x[j]
            if counts[f] != COUNT_MAX:
                counts[f] += 1
            n_have += 1
            last_t = ti
            if n_have == n_target:
                return i + 1, n_have, first_t, last_t, FN_FULL
        i += 1
    return i, n_have, first_t, last_t, FN_DONE


@njit(cache=True, nogil=True)
def fn_scan(t, cls, use_cls, i, n_have, n_target, first_t, last_t, max_window_us):
    """`fn_run` without the counts (for a follower that counts the frame's events itself): the same
    windows, reading only times and classes; when every event counts, by arithmetic and one binary search
    for the deadline instead of a look at each event."""
    n = len(t)
    if not use_cls and i < n:
        if n_have == 0:  # the frame's first event: no deadline before it
            first_t = last_t = t[ix(i)]
            n_have = 1
            i += 1
            if n_have == n_target:
                return i, n_have, first_t, last_t, FN_FULL
        late = i + np.searchsorted(t[i:], first_t + max_window_us)  # the first event at or past the deadline
        full = i + n_target - n_have  # just past the n_target-th event
        stop = min(late, full)  # late <= n
        if stop > i:
            n_have += stop - i
            last_t = t[ix(stop - 1)]
        if stop == full:
            return stop, n_have, first_t, last_t, FN_FULL
        return stop, n_have, first_t, last_t, FN_TIMEOUT if stop == late < n else FN_DONE
    while i < n:
        j = ix(i)
        ti = t[j]
        if n_have > 0 and ti >= first_t + max_window_us:
            return i, n_have, first_t, last_t, FN_TIMEOUT
        if not use_cls or cls[j] == 0:
            if n_have == 0:
                first_t = ti
            n_have += 1
            last_t = ti
            if n_have == n_target:
                return i + 1, n_have, first_t, last_t, FN_FULL
        i += 1
    return i, n_have, first_t, last_t, FN_DONE


@register("framer", "fw")
@dataclass(eq=False)
class FixedWindow(FramerBase):
    """FW: a frame every `window_us` of event time (the paper's fixed time window)."""

    window_us: int = 10_000
    all_events: bool = False
    max_empty_frames: int = 1000
    # A representation framer may count the frames' events itself while it adds them to its arrays, in
    # one pass: `follower.add(chunk, cls, use_cls, a, b, start, end, counts)`, as `SlidingFramer.follower`,
    # returns how many of the events [a, b) count, having counted them into `counts` or (the time surface)
    # about to count them in its own pass over the chunk, before it hands the frames on.
    follower = None  # not annotated: a class attribute, not a parameter

    def __post_init__(self):
        check_positive_int(self, "window_us")
        self._check_common()
        self._reset()

    def _reset(self) -> None:
        super()._reset()
        self.start: int | None = None  # current frame [start, end)
        self.end = 0
        self.n = 0
        self.counts = None

    def frame_step(self) -> tuple[int | None, int | None]:
        return self.window_us, None

    def push(self, chunk: EventChunk) -> list[Frame]:
        if self.start is None and not len(chunk):
            return []
        self._geometry(chunk)
        out: list[Frame] = []
        if len(chunk):
            if self.start is None:
                self.start = int(chunk.t[0])
                self.end = self.start + self.window_us
                self.counts = self._new_counts()
            cls, use_cls = self._cls(chunk)
            t = chunk.t
            i = 0
            while True:
                stop = i + int(np.searchsorted(t[i:], self.end, side="left"))
                if self.follower is None:
                    self.n += accumulate(chunk.x, chunk.y, chunk.p, cls, use_cls, i, stop, self.counts,
                                         self._width, self._hw)
                elif stop > i:
                    self.n += self.follower.add(chunk, cls, use_cls, i, stop, self.start, self.end, self.counts)
                i = stop
                if i == len(chunk):
                    break
                self._advance(int(t[i]), out)
        self._advance(watermark(chunk), out)
        return out

    def _advance(self, w: int, out: list[Frame]) -> None:
        """Emit every frame that ends at or before the watermark w."""
        while self.end <= w:
            if self.n:
                out.append(self._frame(self.start, self.end, self.n, self.counts))
                self.counts = self._new_counts()
                self.n = 0
            elif self._may_emit_empty:
                out.append(self._frame(self.start, self.end, 0, None))
            else:  # a long quiet stretch: jump to the frame that holds w, on the same grid
                k = (w - self.end) // self.window_us + 1
                self.start += k * self.window_us
                self.end += k * self.window_us
                return
            self.start = self.end
            self.end += self.window_us

    def finish(self) -> list[Frame]:
        out = [self._frame(self.start, self.end, self.n, self.counts)] if self.n else []
        self._reset()
        return out


@register("framer", "fn")
@dataclass(eq=False)
class FixedCount(FramerBase):
    """FN: a frame every `n_events` counted events; `max_window_us` (None: never) closes a frame that
    has waited that long since its first event."""

    n_events: int = 8000
    max_window_us: int | None = 1_000_000
    all_events: bool = False
    # A representation framer that counts each frame's events into its counts itself, in the pass that
    # makes its array, before it hands the frame on: the frames' counts are then left zeroed here (one
    # pass over the events instead of two; `fn_scan` finds the same windows).
    follower = None  # not annotated: a class attribute, not a parameter

    def __post_init__(self):
        check_positive_int(self, "n_events")
        if self.max_window_us is not None:
            check_positive_int(self, "max_window_us")
        self._check_common()
        self._reset()

    def _reset(self) -> None:
        super()._reset()
        self.n = 0
        self.first_t = 0
        self.last_t = 0
        self.counts = None

    def frame_step(self) -> tuple[int | None, int | None]:
        return self.max_window_us, self.n_events  # full, or timed out

    @property
    def _max_window(self) -> int:
        return NEVER_US if self.max_window_us is None else self.max_window_us

    def push(self, chunk: EventChunk) -> list[Frame]:
        if self.geometry is None and not len(chunk):
            return []
        self._geometry(chunk)
        if self.counts is None:
            self.counts = self._new_counts()
        out: list[Frame] = []
        cls, use_cls = self._cls(chunk)
        i = 0
        while i < len(chunk):
            if self.follower is None:
                i, self.n, self.first_t, self.last_t, status = fn_run(
                    chunk.t, chunk.x, chunk.y, chunk.p, cls, use_cls, i, self.counts, self._width, self._hw,
                    self.n, self.n_events, self.first_t, self.last_t, self._max_window)
            else:
                i, self.n, self.first_t, self.last_t, status = fn_scan(
                    chunk.t, cls, use_cls, i, self.n, self.n_events, self.first_t, self.last_t, self._max_window)
            if status == FN_FULL:
                out.append(self._close(self.last_t + 1))
            elif status == FN_TIMEOUT:
                out.append(self._close(self.first_t + self._max_window))
            else:
                break
        if self.n and watermark(chunk) >= self.first_t + self._max_window:
            out.append(self._close(self.first_t + self._max_window))
        return out

    def _close(self, t_end: int) -> Frame:
        frame = self._frame(self.first_t, t_end, self.n, self.counts)
        self.counts = self._new_counts()
        self.n = 0
        return frame

    def finish(self) -> list[Frame]:
        out = [self._close(self.last_t + 1)] if self.n else []
        self._reset()
        return out
