"""Undistortion: events moved to where an ideal pinhole camera would have seen them, using the camera's
calibration (`evstream.camera`: a ROS camera_info YAML or OpenCV-style intrinsics).

The sensor's pixels are few and fixed, so the mapping is a lookup table computed once (at the first
chunk): each pixel's undistorted position, rounded to the nearest pixel, or "dropped" when it falls
outside the sensor (or the model has no undistorted point for it). Per event it is then one table read
in a numba pass that also compacts the kept events. Several distorted pixels may land on one pixel and
some pixels receive none (holes): an event stream has no pixel grid to interpolate on. Memory: two
int32 per pixel; stateless per event, so chunk-invariant and causal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..camera import CameraModel, from_camera_info
from ..events import EventChunk, Geometry
from ..pipeline import register
from .base import Transform, select


@njit(cache=True, nogil=True)
def undistort_kernel(x, y, width, lut_x, lut_y, keep, out_x, out_y):
    """Indices (into `keep`) and new coordinates of the events whose pixel has a target (lut_x >= 0);
    returns how many. Branch-free: every event is written, the end advances when kept."""
    k = 0
    for i in range(len(x)):
        f = np.intp(y[i]) * width + np.intp(x[i])
        tx = lut_x[f]
        keep[k] = i
        out_x[k] = tx
        out_y[k] = lut_y[f]
        k += tx >= 0
    return k


def lookup_table(camera: CameraModel, geometry: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel (flat y·W + x) the undistorted pixel's column and row (int32), −1 where dropped."""
    w, h = geometry.width, geometry.height
    v, u = np.divmod(np.arange(w * h, dtype=np.float64), w)
    ux, uy = camera.undistort_points(u, v)
    with np.errstate(invalid="ignore"):
        rx, ry = np.rint(ux), np.rint(uy)  # nearest pixel (half to even, as numpy rounds)
        inside = (rx >= 0) & (rx < w) & (ry >= 0) & (ry < h)
    lut_x = np.where(inside, rx, -1).astype(np.int32)
    lut_y = np.where(inside, ry, -1).astype(np.int32)
    return lut_x, lut_y


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
            self.camera = CameraModel(self.fx, self.fy, self.cx, self.cy, self.model, tuple(self.distortion or ()))
        self._geometry: Geometry | None = None

    def out_geometry(self, geometry: Geometry) -> Geometry:
        c = self.camera
        if c.width is not None and c.height is not None and (c.width, c.height) != (geometry.width, geometry.height):
            raise ValueError(f"undistort: the camera was calibrated at {c.width}x{c.height}, the events come "
                             f"from a {geometry} sensor")
        return geometry

    def __call__(self, chunk: EventChunk) -> EventChunk:
        g = chunk.geometry
        if g != self._geometry:  # once per stream: the table for this sensor
            self.out_geometry(g)
            self._lut_x, self._lut_y = lookup_table(self.camera, g)
            self._geometry = g
        n = len(chunk)
        keep = np.empty(n + 1, np.intp)
        out_x, out_y = np.empty(n + 1, np.uint16), np.empty(n + 1, np.uint16)
        k = undistort_kernel(chunk.x, chunk.y, g.width, self._lut_x, self._lut_y, keep, out_x, out_y)
        return select(chunk, keep[:k], g, out_x[:k], out_y[:k])
