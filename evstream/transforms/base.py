"""What every transform shares: it is a stage that may drop events or change the sensor geometry, and
says which (`drops_events`, `changes_geometry`); `out_geometry(g)` is the geometry of its output.

A transform keeps each surviving event's time, class and label; its output keeps the input chunk's
watermark (`t_end`), so the framers downstream close frames exactly as before. Events are never
reordered: a transform maps coordinates, or drops events, or both.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..events import EventChunk, Geometry


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
        raise ValueError(f"{kind}: {name} must be an integer >= {low}, got {v!r}")
    return int(v)
