"""What every framer shares: parameters, which events count, frame allocation, the watermark contract.

Time contract (all framers). A frame covers the half-open interval [t_start, t_end) of event time.
A chunk's `t_end` is its watermark: the source promises that no later event has `t < t_end` (events
*at* `t_end` may still come). So a frame may be emitted once the watermark reaches its end
(`watermark >= t_end`): every event it can hold has arrived. An event at or past a frame's end is a
watermark too (streams are time-ordered). Frames therefore come out on time in quiet periods (empty
frames, when nothing happened), and no frame ever depends on how the stream was cut into chunks.
`finish()` closes what is still open at the end of the stream: the open frames that hold events.
"""

from __future__ import annotations

import collections
import dataclasses

import numpy as np

from ..events import EventChunk, EventError, Frame, Geometry, shown

# Per-pixel counts saturate at 65535 (a 2 kHz hot pixel reaches it after 33 s in one frame); uint16
# halves the memory traffic of dense frames, which dominates at ordinary event rates. `n_events` is exact.
COUNT_DTYPE = np.uint16
COUNT_MAX = int(np.iinfo(COUNT_DTYPE).max)
POOL_BYTES = 64 << 20  # idle count buffers kept for reuse once the frames holding them are dropped


class _Lease:
    """Owns one count buffer while frames use it; when the last of them is dropped, the buffer goes
    back to its framer's pool. Fresh memory for every frame costs a page fault per 4 KiB on first
    touch (several times the accumulation itself at 100 frames/s on 346x260); a warm buffer costs a memset."""

    __slots__ = ("buf", "pool")

    def __init__(self, buf: np.ndarray, pool: collections.deque):
        self.buf, self.pool = buf, pool  # pool: a deque bounded by maxlen

    @property
    def __array_interface__(self):
        return self.buf.__array_interface__

    def __del__(self):
        if len(self.pool) < self.pool.maxlen:
            self.pool.append(self.buf)


class FramerBase:
    """Base of the framers (subclasses are dataclasses: parameters as fields, units in the names).

    `all_events` False (the default) builds frames from the events still classed SIGNAL (`cls` 0, or
    every event when no stage classified them); True counts every event whatever its class.
    `max_empty_frames` bounds the empty frames emitted in a row (a quiet hour at 100 frames/s, or a
    timestamp jump, must not flood the sinks): after that many, empty frames are skipped until an
    event comes; the frame grid is kept.
    """

    all_events: bool
    max_empty_frames: int

    # -- parameters -------------------------------------------------------------------------------
    def params(self) -> dict:
        """The constructor parameters (units in their names), for provenance and TOML round trips."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}

    def _check_common(self) -> None:
        if hasattr(self, "max_empty_frames"):
            _check_int(self, "max_empty_frames", 0)
        if not isinstance(self.all_events, (bool, np.bool_)):
            raise ValueError(f"{self.kind}: all_events must be true or false, got {shown(self.all_events)}")

    def frame_step(self) -> tuple[int | None, int | None]:
        """The least event time (µs) and the fewest counted events from one frame's end to the next's
        (None: not bounded that way); `framing.bound.cut` bounds the frames handed on at once by them."""
        return None, None

    def pause_step_us(self) -> int | None:
        """The most event time between two empty frames in a pause (None: the least step, `frame_step`)."""
        return None

    def frame_bytes(self, n_pixels: int) -> int:
        """The memory one frame of a sensor of `n_pixels` holds: its two count planes."""
        return 2 * n_pixels * np.dtype(COUNT_DTYPE).itemsize

    # -- state --------------------------------------------------------------------------------------
    def _reset(self) -> None:
        self.geometry: Geometry | None = None
        self.empty_run = 0  # empty frames emitted in a row
        self._pool: collections.deque | None = None  # idle count buffers, zeroed on reuse

    def _geometry(self, chunk: EventChunk) -> None:
        if self.geometry is None:
            self.geometry = chunk.geometry
            self._width = chunk.geometry.width
            self._hw = chunk.geometry.n_pixels
            self._zeros = np.zeros((2, chunk.geometry.height, chunk.geometry.width), COUNT_DTYPE)
            self._zeros.flags.writeable = False  # shared by every empty frame
            self._pool = collections.deque(maxlen=max(2, POOL_BYTES // self._zeros.nbytes))
        elif chunk.geometry != self.geometry:
            raise EventError(f"{self.kind} framer: geometry changed from {self.geometry} to {chunk.geometry}")

    def _cls(self, chunk: EventChunk) -> tuple[np.ndarray, bool]:
        """The class array the kernels read, and whether they must read it (False: count all)."""
        if self.all_events or chunk.cls is None:
            return _NO_CLS, False
        return chunk.cls, True

    def _new_counts(self) -> np.ndarray:
        """A zeroed flat count buffer (OFF then ON planes), recycled from dropped frames when it can."""
        try:
            buf = self._pool.pop()
        except IndexError:
            buf = np.empty(2 * self._hw, COUNT_DTYPE)
        buf.fill(0)
        return np.asarray(_Lease(buf, self._pool))

    def _frame(self, t_start: int, t_end: int, n: int, flat: np.ndarray | None) -> Frame:
        """A frame from flat counts (owned by the frame from now on); None or n == 0: empty frame."""
        if n == 0 or flat is None:
            self.empty_run += 1
            return Frame(int(t_start), int(t_end), 0, self._zeros)
        self.empty_run = 0
        g = self.geometry
        return Frame(int(t_start), int(t_end), int(n), flat.reshape(2, g.height, g.width))

    @property
    def _may_emit_empty(self) -> bool:
        return self.empty_run < self.max_empty_frames


_NO_CLS = np.zeros(0, np.uint8)


def watermark(chunk: EventChunk) -> int:
    """What the chunk promises: no later event has t < this (its `t_end`, never before its last event)."""
    return max(int(chunk.t_end), int(chunk.t[-1])) if len(chunk) else int(chunk.t_end)


def _check_int(obj, name: str, low: int) -> None:
    v = getattr(obj, name)
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < low:
        raise ValueError(f"{obj.kind}: {name} must be an integer >= {low}, got {shown(v)}")
    setattr(obj, name, int(v))


def check_positive_int(obj, name: str) -> None:
    _check_int(obj, name, 1)


def check_nonnegative_int(obj, name: str) -> None:
    _check_int(obj, name, 0)
