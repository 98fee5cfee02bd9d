"""The data model: events travel as `EventChunk`s, a struct of arrays that numba kernels read directly.

Sources validate what they read (`validate`); inside the pipeline, stages trust validated chunks.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .jit import njit


def shown(value) -> str:
    """A value as an error message shows it: Python's repr, a NumPy scalar as its plain value (`nan`, `0`;
    not NumPy 2's `np.float64(nan)`, which reads as code, not as what was given)."""
    if isinstance(value, np.generic):
        value = value.item()
    return repr(value)


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """A count with its noun in agreement: '1 array', '2 arrays', '1 event packet' ('wrote 1 arrays' before;
    the commands' counts, the readers' sizes)."""
    return f"{n:,} {noun if n == 1 else plural or noun + 's'}"


__all__ = [
    "EVENT_DTYPE",
    "EventChunk",
    "EventError",
    "Frame",
    "Geometry",
    "NoiseClass",
    "TimestampPolicy",
    "Validator",
    "concat",
]


class NoiseClass(enum.IntEnum):
    """Per-event class codes, shared by `cls` (assigned by stages) and `label` (ground truth)."""

    SIGNAL = 0
    BACKGROUND = 1
    HOT_PIXEL = 2


N_CLASSES = len(NoiseClass)
_UINT8 = np.dtype(np.uint8)

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")])
_FIELD_DTYPES = {"t": np.int64, "x": np.uint16, "y": np.uint16, "p": np.uint8}


class EventError(ValueError):
    """Bad event data, with where it came from (file, offset) and what is wrong."""


@dataclass(frozen=True)
class Geometry:
    """Sensor size in pixels."""

    width: int
    height: int

    def __post_init__(self):
        for name in ("width", "height"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or not 0 < int(v) <= 65535:
                raise ValueError(f"Geometry.{name} must be an integer in 1..65535, got {shown(v)}")
            object.__setattr__(self, name, int(v))

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

    def __str__(self) -> str:
        return f"{self.width}x{self.height}"


@dataclass(frozen=True, eq=False)
class EventChunk:
    """A run of events in stream order.

    `t` int64 µs (non-decreasing), `x`/`y` uint16 pixel column/row, `p` uint8 (1 = ON, 0 = OFF);
    `cls` the noise class assigned by stages, `label` the ground truth, each uint8 or None.
    `t_end` is the watermark: the source promises no later event has `t < t_end`. It defaults to the
    last timestamp (events with the same timestamp may still follow).
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    geometry: Geometry
    cls: np.ndarray | None = None
    label: np.ndarray | None = None
    t_end: int | None = None

    def __post_init__(self):
        for name in ("t", "x", "y", "p", "cls", "label"):  # a 2-D field would pass the length check below
            a = getattr(self, name)
            if a is not None and np.ndim(a) != 1:
                raise EventError(f"EventChunk: field {name!r} has shape {np.shape(a)}: one dimension expected")
        n = len(self.t)
        for name in ("x", "y", "p", "cls", "label"):
            a = getattr(self, name)
            if a is not None and len(a) != n:
                raise EventError(f"EventChunk: field {name!r} has {len(a)} entries, t has {n}")
        if self.t_end is None:
            object.__setattr__(self, "t_end", int(self.t[-1]) if n else np.iinfo(np.int64).min)
        else:
            object.__setattr__(self, "t_end", int(self.t_end))

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_arrays(cls, t, x, y, p, geometry: Geometry, *, cls_=None, label=None, t_end=None):
        """Build a chunk, converting each field to its dtype (no copy when it already matches)."""
        return cls(
            t=np.ascontiguousarray(t, dtype=np.int64),
            x=np.ascontiguousarray(x, dtype=np.uint16),
            y=np.ascontiguousarray(y, dtype=np.uint16),
            p=np.ascontiguousarray(p, dtype=np.uint8),
            geometry=geometry,
            cls=None if cls_ is None else np.ascontiguousarray(cls_, dtype=np.uint8),
            label=None if label is None else np.ascontiguousarray(label, dtype=np.uint8),
            t_end=t_end,
        )

    @classmethod
    def empty(cls, geometry: Geometry, t_end: int | None = None, *, with_cls=False, with_label=False):
        z = np.zeros(0, np.uint8)
        return cls(
            np.zeros(0, np.int64), np.zeros(0, np.uint16), np.zeros(0, np.uint16), z, geometry,
            cls=z if with_cls else None, label=z if with_label else None, t_end=t_end,
        )

    @classmethod
    def from_structured(cls, arr: np.ndarray, geometry: Geometry, t_end=None) -> EventChunk:
        """From a structured array with fields t, x, y, p (and optionally cls, label)."""
        names = arr.dtype.names or ()
        missing = [f for f in "txyp" if f not in names]
        if missing:
            raise EventError(f"structured array lacks field(s) {missing}; has {list(names)}")
        return cls.from_arrays(
            arr["t"], arr["x"], arr["y"], arr["p"], geometry,
            cls_=arr["cls"] if "cls" in names else None,
            label=arr["label"] if "label" in names else None,
            t_end=t_end,
        )

    def to_structured(self) -> np.ndarray:
        """A packed structured array (t, x, y, p, then cls and label where present)."""
        fields = list(EVENT_DTYPE.descr)
        fields += [(f, "u1") for f in ("cls", "label") if getattr(self, f) is not None]
        out = np.empty(len(self), np.dtype(fields))
        for name, _ in fields:
            out[name] = getattr(self, name)
        return out

    # -- access -------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, key) -> EventChunk:
        """Slice (`chunk[a:b]`) or select (boolean mask, index array).

        A contiguous slice of a stream gets the tightest watermark it can promise: the timestamp of
        the first event after it. A selection keeps this chunk's watermark.
        """
        if isinstance(key, slice):
            start, stop, step = key.indices(len(self))
            if step != 1:
                raise IndexError("EventChunk slices must be contiguous (step 1)")
            t_end = int(self.t[stop]) if stop < len(self) else self.t_end
        elif isinstance(key, (int, np.integer)):
            raise IndexError("index an EventChunk with a slice, mask or index array, not an int")
        else:
            t_end = self.t_end
        return dataclasses.replace(
            self,
            t=self.t[key], x=self.x[key], y=self.y[key], p=self.p[key],
            cls=None if self.cls is None else self.cls[key],
            label=None if self.label is None else self.label[key],
            t_end=t_end,
        )

    def of_class(self, c: int) -> EventChunk:
        """The events whose `cls` is `c` (all of them for SIGNAL when unclassified), in stream order,
        with this chunk's watermark. A branch-free gather: ~5x faster than a boolean mask (the classes
        interleave at random)."""
        if self.cls is None:
            return self if c == NoiseClass.SIGNAL else self[np.zeros(0, np.intp)]
        n = len(self)
        has_label = self.label is not None
        out = (np.empty(n + 1, self.t.dtype), np.empty(n + 1, self.x.dtype), np.empty(n + 1, self.y.dtype),
               np.empty(n + 1, self.p.dtype), np.empty(n + 1 if has_label else 0, np.uint8))
        k = _gather_class(self.cls, int(c), self.t, self.x, self.y, self.p,  # int(c): one variant for all
                          self.label if has_label else out[4], has_label, *out)
        return dataclasses.replace(self, t=out[0][:k], x=out[1][:k], y=out[2][:k], p=out[3][:k],
                                   cls=np.full(k, c, np.uint8), label=out[4][:k] if has_label else None)

    def replace(self, **changes) -> EventChunk:
        return dataclasses.replace(self, **changes)

    def with_classes(self, cls: np.ndarray) -> EventChunk:
        """`replace(cls=cls)` without re-checking the other fields (~6 µs a call in a stage): `cls` must
        be a 1-D uint8 array of len(self) events, as every stage writes."""
        if (cls.dtype is not _UINT8 and cls.dtype != _UINT8) or cls.shape != self.t.shape:  # `is`: 0.3 µs less
            raise EventError(f"EventChunk: cls must be uint8 of shape {self.t.shape}, got {cls.dtype} {cls.shape}")
        out = object.__new__(type(self))
        out.__dict__.update(self.__dict__)
        out.__dict__["cls"] = cls
        return out

    def classes(self) -> np.ndarray:
        """`cls`, or all SIGNAL when no stage has classified this chunk."""
        return self.cls if self.cls is not None else np.zeros(len(self), np.uint8)

    def class_counts(self, field: str = "cls") -> np.ndarray | None:
        """Events per noise class (length-3 int64 array) in `cls` or `label`; None if absent."""
        a = getattr(self, field)
        if a is None:
            return None
        # one compare per class: ~10x faster than bincount, which first widens the uint8 codes to int64
        return np.array([np.count_nonzero(a == c) for c in range(N_CLASSES)], np.int64)

    @property
    def duration_us(self) -> int:
        return int(self.t[-1] - self.t[0]) if len(self) else 0

    def __repr__(self) -> str:
        span = f"{self.t[0]}..{self.t[-1]} µs" if len(self) else "empty"
        return f"EventChunk({len(self)} events, {span}, {self.geometry}, t_end={self.t_end})"


@njit(cache=True, nogil=True)
def _gather_class(cls, c, t, x, y, p, label, has_label, out_t, out_x, out_y, out_p, out_label):
    """Copy the events of class `c` to the out arrays, in order; returns how many. Every event is written
    and the end advances on a match (no branch), so the out arrays hold one spare cell."""
    k = 0
    for i in range(len(cls)):
        out_t[k] = t[i]
        out_x[k] = x[i]
        out_y[k] = y[i]
        out_p[k] = p[i]
        if has_label:
            out_label[k] = label[i]
        k += cls[i] == c
    return k


@njit(cache=True, nogil=True)
def _first_invalid(t, x, y, p, width, height, last_t):
    """(first event outside the sensor or with polarity > 1, first whose t is below its predecessor's, the
    first event's predecessor being `last_t`); -1 where none. One pass: ~4x faster than numpy's five."""
    n = len(t)
    if n == 0:
        return -1, -1
    w = np.uint16(min(width, 0xFFFF))
    h = np.uint16(min(height, 0xFFFF))
    wrong = t[0] < last_t
    for i in range(n):  # branch-free, so it vectorises; the loop below finds where
        wrong |= (x[i] >= w) | (y[i] >= h) | (p[i] > 1)
    for i in range(1, n):
        wrong |= t[i] < t[i - 1]
    if not wrong:
        return -1, -1
    back = -1
    prev = last_t
    for i in range(n):
        if x[i] >= width or y[i] >= height or p[i] > 1:
            return i, back
        if t[i] < prev and back < 0:
            back = i
        prev = t[i]
    return -1, back


def concat(chunks: Sequence[EventChunk], geometry: Geometry | None = None) -> EventChunk:
    """Concatenate chunks of one stream; `cls`/`label` survive only where every chunk has them."""
    chunks = list(chunks)
    if not chunks:
        if geometry is None:
            raise ValueError("concat of no chunks needs a geometry")
        return EventChunk.empty(geometry)
    geometry = geometry or chunks[0].geometry
    if any(c.geometry != geometry for c in chunks):
        raise EventError("concat: chunks have different geometries")

    def cat(name):
        parts = [getattr(c, name) for c in chunks]
        return None if any(a is None for a in parts) else np.concatenate(parts)

    return EventChunk(
        cat("t"), cat("x"), cat("y"), cat("p"), geometry,
        cls=cat("cls"), label=cat("label"), t_end=max(c.t_end for c in chunks),
    )


@dataclass(frozen=True, eq=False)
class Frame:
    """Events accumulated over [t_start, t_end): `counts[0]` OFF, `counts[1]` ON, shape (2, H, W)."""

    t_start: int
    t_end: int
    n_events: int
    counts: np.ndarray

    @property
    def image(self) -> np.ndarray:
        """Signed counts ON − OFF, shape (H, W)."""
        return self.counts[1].astype(np.int32) - self.counts[0].astype(np.int32)


# -- validation at the boundary ----------------------------------------------------------------
class TimestampPolicy(str, enum.Enum):
    """What a source does with a timestamp that goes backwards."""

    ERROR = "error"  # raise EventError naming where
    SORT = "sort"  # sort within the chunk; what still goes back past the previous chunk is dropped
    DROP = "drop"  # drop events older than the newest seen so far


class Validator:
    """Checks chunks from one source against a geometry and the stream's time order.

    Errors name `where` (usually a file name) and the absolute event offset. Under the SORT and
    DROP policies, dropped events are counted in `dropped` (and sorted-in-place ones in `reordered`).
    """

    def __init__(self, geometry: Geometry, where: str = "<stream>", policy="error"):
        self.geometry = geometry
        self.where = where
        self.policy = TimestampPolicy(policy)
        self.last_t = np.iinfo(np.int64).min
        self.offset = 0  # events seen so far, for error messages
        self.dropped = 0
        self.reordered = 0

    def __call__(self, chunk: EventChunk) -> EventChunk:
        n = len(chunk)
        base = self.offset
        self.offset += n
        if n == 0:
            return chunk
        g = self.geometry
        bad, first_back = _first_invalid(chunk.t, chunk.x, chunk.y, chunk.p, g.width, g.height, self.last_t)
        if bad >= 0:
            self._check_coords(chunk, base)
            raise EventError(f"{self.where}: event {base + bad}: polarity {chunk.p[bad]} is not 0 or 1")
        if first_back >= 0:
            back = np.flatnonzero(np.diff(chunk.t) < 0)
            chunk = self._fix_order(chunk, base, back, first_back == 0)
        if len(chunk):
            self.last_t = int(chunk.t[-1])
        return chunk

    def _check_coords(self, chunk, base):
        g = self.geometry
        bad = (chunk.x >= g.width) | (chunk.y >= g.height)
        if bad.any():
            i = int(np.argmax(bad))
            raise EventError(
                f"{self.where}: event {base + i}: ({chunk.x[i]}, {chunk.y[i]}) outside the "
                f"{g} sensor ({int(bad.sum())} such events in this chunk)"
            )

    def _fix_order(self, chunk, base, back, first_back):
        if self.policy is TimestampPolicy.ERROR:
            i = 0 if first_back else int(back[0]) + 1
            prev = self.last_t if first_back else chunk.t[i - 1]
            e = EventError(
                f"{self.where}: event {base + i}: timestamp {chunk.t[i]} µs goes back from {prev} µs "
                f"(to accept such streams: --timestamps sort|drop, timestamps=\"sort\" in Python)"
            )
            e.event_index = base + i  # a reader with fixed-size records turns it into a byte offset
            raise e
        if self.policy is TimestampPolicy.SORT and len(back):
            order = np.argsort(chunk.t, kind="stable")
            self.reordered += int(np.count_nonzero(order != np.arange(len(order))))
            chunk = chunk[order]
        running = np.maximum.accumulate(np.concatenate(([self.last_t], chunk.t)))[:-1]
        keep = chunk.t >= running
        self.dropped += int(len(keep) - keep.sum())
        return chunk[keep]
