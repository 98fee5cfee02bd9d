"""Undistortion: events moved to where an ideal pinhole camera would have seen them, using the camera's
calibration (`evstream.camera`: a ROS camera_info YAML or OpenCV-style intrinsics).

The sensor's pixels are few and fixed, so the mapping is a lookup table computed once (at the first
chunk): each pixel's undistorted position, rounded to the nearest pixel, or "dropped" when it falls
outside the sensor (or the model has no undistorted point for it). Per event it is then one table read
in a numba pass that also compacts the kept events. Several distorted pixels may land on one pixel and
some pixels receive none (holes): an event stream has no pixel grid to interpolate on. Memory: two
one int32 per pixel; stateless per event, so chunk-invariant and causal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import CameraModel, from_camera_info
from ..events import EventChunk, Geometry, shown
from ..jit import njit
from ..pipeline import register
from .base import Transform


@njit(cache=True, nogil=True)
def undistort_kernel(t, x, y, p, width, lut, out_t, out_x, out_y, out_p, keep):
    """Copy the events whose pixel has a target (lut >= 0) to the out arrays (one spare cell each) with
    their new coordinates, and their indices to `keep`; returns how many. `lut` packs a pixel's target
    as x | y << 16 (one random read per event, not two). Branch-free: every event is written, the end
    advances when kept."""
    k = 0
    for i in range(len(t)):
        target = lut[np.intp(y[i]) * width + np.intp(x[i])]
        out_t[k] = t[i]
        out_x[k] = target & 0xFFFF
        out_y[k] = (target >> 16) & 0xFFFF
        out_p[k] = p[i]
        keep[k] = i
        k += target >= 0
    return k


def lookup_table(camera: CameraModel, geometry: Geometry) -> np.ndarray:
    """Per pixel (flat y·W + x) its undistorted pixel as int32 x | y << 16, or −1 where dropped."""
    w, h = geometry.width, geometry.height
    v, u = np.divmod(np.arange(w * h, dtype=np.float64), w)
    ux, uy = camera.undistort_points(u, v)
    with np.errstate(invalid="ignore"):
        rx, ry = np.rint(ux), np.rint(uy)  # nearest pixel (half to even, as numpy rounds)
        inside = (rx >= 0) & (rx < w) & (ry >= 0) & (ry < h)
    lut = np.full(w * h, -1, np.int64)
    lut[inside] = rx[inside].astype(np.int64) | (ry[inside].astype(np.int64) << 16)
    return lut.astype(np.int32)  # y < 2^15 on any real sensor: the packed value stays positive


def unpack(lut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A packed table as (x, y) columns, −1 where dropped."""
    return np.where(lut < 0, -1, lut & 0xFFFF), np.where(lut < 0, -1, lut >> 16)


@register("stage", "undistort")
@dataclass(eq=False)
class Undistort(Transform):
    """Undistort events with a camera model: `camera_info` (a ROS camera_info YAML file) or the
    intrinsics `fx`, `fy`, `cx`, `cy` with `distortion` coefficients of `model` (plumb_bob /
    rational_polynomial: k1 k2 p1 p2 [k3 [k4 k5 k6]]; equidistant: k1 k2 k3 k4). Events whose
    undistorted pixel is outside the sensor are dropped."""

    camera_info: str | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    distortion: list | None = None
    model: str = "plumb_bob"
    drops_events = True

    def __post_init__(self):
        intrinsics = (self.fx, self.fy, self.cx, self.cy)
        if self.camera_info is not None:
            if any(v is not None for v in intrinsics) or self.distortion is not None:
                raise ValueError("undistort: give camera_info or the intrinsics (fx, fy, cx, cy, distortion), not both")
            self.camera = from_camera_info(self.camera_info)
        else:
            if any(v is None for v in intrinsics):
                raise ValueError("undistort: needs camera_info = FILE.yaml, or fx, fy, cx and cy (and distortion)")
            if self.distortion is not None and not isinstance(self.distortion, (list, tuple, np.ndarray)):
                raise ValueError("undistort: distortion is a list of numbers, as in --set 'distortion=[-0.3, 0.1, 0, "
                                 f"0]'; got {shown(self.distortion)}")  # a string's characters were read one by one
            self.camera = CameraModel(self.fx, self.fy, self.cx, self.cy, self.model, tuple(self.distortion or ()))
        self._geometry: Geometry | None = None

    def out_geometry(self, geometry: Geometry) -> Geometry:
        c = self.camera
        if c.width is not None and c.height is not None and (c.width, c.height) != (geometry.width, geometry.height):
            of = f" ({self.camera_info})" if self.camera_info is not None else ""
            raise ValueError(f"undistort: the camera{of} was calibrated at {c.width}x{c.height}, the events come "
                             f"from a {geometry} sensor")
        return geometry

    def __call__(self, chunk: EventChunk) -> EventChunk:
        g = chunk.geometry
        if g != self._geometry:  # once per stream: the table for this sensor
            self.out_geometry(g)
            if g.height >= 1 << 15:
                raise ValueError(f"undistort: a {g} sensor is too tall for the packed table (rows < 32768)")
            self._lut = lookup_table(self.camera, g)
            self._geometry = g
        n = len(chunk)
        out = (np.empty(n + 1, np.int64), np.empty(n + 1, np.uint16), np.empty(n + 1, np.uint16),
               np.empty(n + 1, np.uint8), np.empty(n + 1, np.intp))
        k = undistort_kernel(chunk.t, chunk.x, chunk.y, chunk.p, g.width, self._lut, *out)
        keep = out[4][:k]
        return chunk.replace(t=out[0][:k], x=out[1][:k], y=out[2][:k], p=out[3][:k],
                             cls=None if chunk.cls is None else chunk.cls[keep],
                             label=None if chunk.label is None else chunk.label[keep])
