"""What every transform shares: it is a stage that may drop events or change the sensor geometry, and
says which (`drops_events`, `changes_geometry`); `out_geometry(g)` is the geometry of its output.

A transform keeps each surviving event's time, class and label; its output keeps the input chunk's
watermark (`t_end`), so the framers downstream close frames exactly as before. Events are never
reordered: a transform maps coordinates, or drops events, or both.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..events import EventChunk, Geometry, shown
from ..jit import njit


class Transform:
    """Base of the transforms (subclasses are dataclasses: parameters as fields, units in the names)."""

    drops_events: bool = False
    changes_geometry: bool = False

    def params(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}

    def out_geometry(self, geometry: Geometry) -> Geometry:
        return geometry

    def __call__(self, chunk: EventChunk) -> EventChunk:
        raise NotImplementedError


def select(chunk: EventChunk, keep: np.ndarray, geometry: Geometry, x=None, y=None) -> EventChunk:
    """The events at indices `keep` (in order), with new coordinates `x`, `y` (already selected) if
    given, on `geometry`; the watermark stays the input's."""
    return chunk.replace(
        t=chunk.t[keep], x=chunk.x[keep] if x is None else x, y=chunk.y[keep] if y is None else y,
        p=chunk.p[keep], cls=None if chunk.cls is None else chunk.cls[keep],
        label=None if chunk.label is None else chunk.label[keep], geometry=geometry,
    )


def check_int(kind: str, name: str, v, low: int) -> int:
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < low:
        raise ValueError(f"{kind}: {name} must be an integer >= {low}, got {shown(v)}")
    return int(v)


@njit(cache=True, nogil=True)
def compact(flags, t, x, y, p, out_t, out_x, out_y, out_p, keep):
    """Copy the events whose flag is nonzero to the out arrays (one spare cell each), in order, and
    their indices to `keep`; returns how many. Every event is written and the end advances on a flag
    (no branch): a boolean mask whose values interleave at random costs numpy a misprediction each."""
    k = 0
    for i in range(len(t)):
        out_t[k] = t[i]
        out_x[k] = x[i]
        out_y[k] = y[i]
        out_p[k] = p[i]
        keep[k] = i
        k += flags[i] != 0
    return k


def select_flagged(chunk: EventChunk, flags: np.ndarray) -> EventChunk:
    """The events whose flag is nonzero, in order, with the chunk's geometry and watermark."""
    n = len(chunk)
    out = (np.empty(n + 1, np.int64), np.empty(n + 1, np.uint16), np.empty(n + 1, np.uint16),
           np.empty(n + 1, np.uint8), np.empty(n + 1, np.intp))
    k = compact(flags, chunk.t, chunk.x, chunk.y, chunk.p, *out)
    if k == n:
        return chunk
    keep = out[4][:k]
    return chunk.replace(t=out[0][:k], x=out[1][:k], y=out[2][:k], p=out[3][:k],
                         cls=None if chunk.cls is None else chunk.cls[keep],
                         label=None if chunk.label is None else chunk.label[keep])
