"""Geometric transforms: crop to a region, flip, rotate by quarter turns, transpose, downsample.

Conventions (x column, y row, y pointing down, as in the sensor's images):
- `flip` axis "x" mirrors left-right (x' = W − 1 − x), "y" up-down (y' = H − 1 − y);
- `rotate` by 90, 180 or 270 degrees counterclockwise on screen, as `np.rot90(image, k)` turns an
  image indexed [y, x]: 90 maps (x, y) to (y, W − 1 − x) on a H×W (width H) sensor;
- `transpose` swaps x and y (the image's transpose);
- `downsample` by an integer factor k: (x // k, y // k) on a ⌈W/k⌉×⌈H/k⌉ sensor, events kept (k² pixels
  pool into one; tonic's spatial Downsample does the same);
- `crop` keeps the events in [x0, x0 + width) × [y0, y0 + height), shifted to the region's origin: it
  drops the others. One numba pass selects, shifts and copies (branch-free compaction).

Only `crop` drops events; all but `flip` (and a 180° turn) change the geometry or its meaning.
Stateless per event: chunk-invariant and causal by construction, memory O(chunk).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..events import EventChunk, Geometry, shown
from ..jit import njit
from ..pipeline import register
from .base import Transform, check_int


@njit(cache=True, nogil=True)
def crop_kernel(t, x, y, p, x0, y0, width, height, out_t, out_x, out_y, out_p, keep):
    """Copy the events inside the region to the out arrays (one spare cell each), shifted to its origin,
    and their indices to `keep`; returns how many. Every event is written and the end advances on a
    match (no branch); the unsigned compare `x − x0 < width` tests both sides at once."""
    k = 0
    for i in range(len(t)):
        dx = np.int64(x[i]) - x0
        dy = np.int64(y[i]) - y0
        out_t[k] = t[i]
        out_x[k] = dx
        out_y[k] = dy
        out_p[k] = p[i]
        keep[k] = i
        k += (np.uint64(dx) < np.uint64(width)) & (np.uint64(dy) < np.uint64(height))
    return k


@register("stage", "crop")
@dataclass(eq=False)
class Crop(Transform):
    """Keep the events in the region [x0, x0 + width) × [y0, y0 + height), moved to its origin."""

    x0: int = 0
    y0: int = 0
    width: int = 1
    height: int = 1
    drops_events = True
    changes_geometry = True

    def __post_init__(self):
        self.x0, self.y0 = check_int("crop", "x0", self.x0, 0), check_int("crop", "y0", self.y0, 0)
        self.width = check_int("crop", "width", self.width, 1)
        self.height = check_int("crop", "height", self.height, 1)

    def out_geometry(self, geometry: Geometry) -> Geometry:
        if self.x0 + self.width > geometry.width or self.y0 + self.height > geometry.height:
            raise ValueError(f"crop: the region x {self.x0}..{self.x0 + self.width - 1}, y {self.y0}.."
                             f"{self.y0 + self.height - 1} does not fit the {geometry} sensor")
        return Geometry(self.width, self.height)

    def __call__(self, chunk: EventChunk) -> EventChunk:
        g = self.out_geometry(chunk.geometry)
        n = len(chunk)
        out = (np.empty(n + 1, np.int64), np.empty(n + 1, np.uint16), np.empty(n + 1, np.uint16),
               np.empty(n + 1, np.uint8), np.empty(n + 1, np.intp))
        k = crop_kernel(chunk.t, chunk.x, chunk.y, chunk.p, self.x0, self.y0, self.width, self.height, *out)
        keep = out[4][:k]
        return chunk.replace(t=out[0][:k], x=out[1][:k], y=out[2][:k], p=out[3][:k], geometry=g,
                             cls=None if chunk.cls is None else chunk.cls[keep],
                             label=None if chunk.label is None else chunk.label[keep])


@register("stage", "flip")
@dataclass(eq=False)
class Flip(Transform):
    """Mirror the sensor: `axis` "x" left-right, "y" up-down."""

    axis: str = "x"

    def __post_init__(self):
        if self.axis not in ("x", "y"):
            raise ValueError(f"flip: axis must be 'x' or 'y', got {shown(self.axis)}")

    def __call__(self, chunk: EventChunk) -> EventChunk:
        g = chunk.geometry
        if self.axis == "x":
            return chunk.replace(x=np.subtract(g.width - 1, chunk.x, dtype=np.uint16))
        return chunk.replace(y=np.subtract(g.height - 1, chunk.y, dtype=np.uint16))


@register("stage", "rotate")
@dataclass(eq=False)
class Rotate(Transform):
    """Turn the sensor by `degrees` (90, 180 or 270) counterclockwise on screen, as np.rot90."""

    degrees: int = 90
    changes_geometry = True

    def __post_init__(self):
        if isinstance(self.degrees, bool) or self.degrees not in (90, 180, 270):
            raise ValueError(f"rotate: degrees must be 90, 180 or 270, got {shown(self.degrees)}")
        self.degrees = int(self.degrees)

    def out_geometry(self, geometry: Geometry) -> Geometry:
        return geometry if self.degrees == 180 else Geometry(geometry.height, geometry.width)

    def __call__(self, chunk: EventChunk) -> EventChunk:
        g = chunk.geometry
        w1, h1 = g.width - 1, g.height - 1
        if self.degrees == 90:
            x, y = chunk.y, np.subtract(w1, chunk.x, dtype=np.uint16)
        elif self.degrees == 180:
            x, y = np.subtract(w1, chunk.x, dtype=np.uint16), np.subtract(h1, chunk.y, dtype=np.uint16)
        else:
            x, y = np.subtract(h1, chunk.y, dtype=np.uint16), chunk.x
        return chunk.replace(x=x, y=y, geometry=self.out_geometry(g))


@register("stage", "transpose")
@dataclass(eq=False)
class Transpose(Transform):
    """Swap x and y (the image's transpose): a W×H sensor becomes H×W."""

    changes_geometry = True

    def out_geometry(self, geometry: Geometry) -> Geometry:
        return Geometry(geometry.height, geometry.width)

    def __call__(self, chunk: EventChunk) -> EventChunk:
        return chunk.replace(x=chunk.y, y=chunk.x, geometry=self.out_geometry(chunk.geometry))


@register("stage", "downsample")
@dataclass(eq=False)
class Downsample(Transform):
    """Pool `factor`×`factor` pixels into one: (x // k, y // k) on a ⌈W/k⌉×⌈H/k⌉ sensor; every event kept."""

    factor: int = 2
    changes_geometry = True

    def __post_init__(self):
        self.factor = check_int("downsample", "factor", self.factor, 1)

    def out_geometry(self, geometry: Geometry) -> Geometry:
        k = self.factor
        return Geometry(-(-geometry.width // k), -(-geometry.height // k))

    def __call__(self, chunk: EventChunk) -> EventChunk:
        k = np.uint16(self.factor)
        return chunk.replace(x=chunk.x // k, y=chunk.y // k, geometry=self.out_geometry(chunk.geometry))
