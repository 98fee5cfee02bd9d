"""Synthetic scenes with ground truth, simulated the way a DVS pixel works.

Each scene is an analytic intensity field I(x, y, t). Every pixel keeps a reference log intensity and
emits an ON (OFF) event each time log I rises (falls) by its contrast threshold, with per-pixel
threshold mismatch and a refractory period, and sub-step timestamps interpolated linearly — so edges
give several events per pixel, fast edges thin out, and the stream looks like a real sensor's.
All events are labelled SIGNAL; `evstream.noise` adds labelled noise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit

from .events import EventChunk, Geometry, NoiseClass, concat

DEFAULT_GEOMETRY = Geometry(346, 260)  # DAVIS346, the paper's sensor


@dataclass(frozen=True)
class SensorModel:
    """Pixel parameters: contrast threshold (log units), its per-pixel spread, refractory period."""

    threshold: float = 0.25
    threshold_sigma: float = 0.03
    refractory_us: int = 100
    step_us: int = 100  # sampling step of the intensity field


@njit(cache=True, nogil=True)
def _emit(log_prev, log_now, ref, thr_on, thr_off, last_t, t_prev, t_now, refractory_us, x0, y0,
          out_t, out_x, out_y, out_p):
    """Threshold crossings of every pixel of a region (origin x0, y0) between two samples; returns the
    number of events written. `ref` and `last_t` (per-pixel state) are updated in place."""
    h, w = log_now.shape
    n = 0
    cap = len(out_t)
    span = t_now - t_prev
    for y in range(h):
        for x in range(w):
            a = log_prev[y, x]
            b = log_now[y, x]
            r = ref[y, x]
            while n < cap:
                if b - r >= thr_on[y, x]:
                    level = r + thr_on[y, x]
                    pol = 1
                elif r - b >= thr_off[y, x]:
                    level = r - thr_off[y, x]
                    pol = 0
                else:
                    break
                frac = (level - a) / (b - a) if b != a else 1.0
                frac = min(max(frac, 0.0), 1.0)
                tc = t_prev + np.int64(frac * span)
                r = level  # a crossing inside the refractory period is lost, not postponed
                if tc - last_t[y, x] >= refractory_us:
                    last_t[y, x] = tc
                    out_t[n] = tc
                    out_x[n] = x0 + x
                    out_y[n] = y0 + y
                    out_p[n] = pol
                    n += 1
            ref[y, x] = r
    return n


Field = Callable[[float, np.ndarray, np.ndarray], np.ndarray]
Region = Callable[[float, float], tuple[slice, slice]]


def simulate(
    log_intensity: Field,
    geometry: Geometry,
    duration_us: int,
    seed: int = 0,
    model: SensorModel = SensorModel(),
    region: Region | None = None,
    chunk_us: int = 50_000,
):
    """Yield SIGNAL-labelled chunks of the events a DVS would emit watching `log_intensity(t_s, X, Y)`.

    `region(t0_s, t1_s) -> (rows, cols)` bounds where the field may change between two samples, so a
    small moving object costs its own area, not the sensor's.
    """
    rng = np.random.default_rng(seed)
    shape = (geometry.height, geometry.width)
    yy, xx = np.mgrid[0 : geometry.height, 0 : geometry.width].astype(np.float64)
    thr_on = np.maximum(model.threshold + model.threshold_sigma * rng.standard_normal(shape), 0.05)
    thr_off = np.maximum(model.threshold + model.threshold_sigma * rng.standard_normal(shape), 0.05)
    level = log_intensity(0.0, xx, yy)
    ref = level + rng.uniform(-0.5, 0.5, shape) * thr_on  # pixels start at random points of their cycle
    last_t = np.full(shape, -(10**9), np.int64)
    cap = geometry.n_pixels * 8
    out = (np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16),
           np.empty(cap, np.uint8))
    parts = []
    chunk_start = 0
    full = (slice(0, geometry.height), slice(0, geometry.width))
    for t_now in range(model.step_us, duration_us + 1, model.step_us):
        t_prev = t_now - model.step_us
        rows, cols = region(t_prev * 1e-6, t_now * 1e-6) if region else full
        now = log_intensity(t_now * 1e-6, xx[rows, cols], yy[rows, cols])
        n = _emit(level[rows, cols], now, ref[rows, cols], thr_on[rows, cols], thr_off[rows, cols],
                  last_t[rows, cols], t_prev, t_now, model.refractory_us,
                  cols.start, rows.start, *out)
        if n:
            order = np.argsort(out[0][:n], kind="stable")
            parts.append(tuple(a[:n][order] for a in out))
        level[rows, cols] = now
        if t_now - chunk_start >= chunk_us or t_now + model.step_us > duration_us:
            yield _chunk(parts, geometry, t_end=t_now)
            parts, chunk_start = [], t_now


def _box(geometry: Geometry, x0, x1, y0, y1, margin=4) -> tuple[slice, slice]:
    """Row and column slices of a box, widened by a margin and clipped to the sensor."""
    c0 = int(np.clip(np.floor(x0) - margin, 0, geometry.width))
    c1 = int(np.clip(np.ceil(x1) + margin + 1, 0, geometry.width))
    r0 = int(np.clip(np.floor(y0) - margin, 0, geometry.height))
    r1 = int(np.clip(np.ceil(y1) + margin + 1, 0, geometry.height))
    return slice(r0, max(r0, r1)), slice(c0, max(c0, c1))


def _chunk(parts, geometry, t_end):
    if parts:
        t, x, y, p = (np.concatenate(a) for a in zip(*parts))
    else:
        t, x, y, p = (np.zeros(0, d) for d in (np.int64, np.uint16, np.uint16, np.uint8))
    label = np.full(len(t), NoiseClass.SIGNAL, np.uint8)
    return EventChunk.from_arrays(t, x, y, p, geometry, label=label, t_end=t_end)


# -- scenes ----------------------------------------------------------------------------------------
def _soft(d_px):
    """Anti-aliased step: 0 -> 1 over about one pixel as the signed distance `d_px` crosses 0."""
    return 0.5 + 0.5 * np.tanh(2.0 * d_px)


def _log(i):
    return np.log(i + 0.05)


def turntable(geometry: Geometry, *, duration_s: float, sectors: int = 4, rev_hz=(3.0, 0.3),
              radius_frac: float = 0.2):
    """A black-and-white sector disk whose rotation slows linearly from rev_hz[0] to rev_hz[1]
    (the paper's Scene II: fast to slow)."""
    cx, cy = (geometry.width - 1) / 2, (geometry.height - 1) / 2
    radius = radius_frac * min(geometry.width, geometry.height)
    f0, f1 = rev_hz
    k = sectors / 2

    def field(t, xx, yy):
        phase = 2 * np.pi * (f0 * t + (f1 - f0) * t * t / (2 * duration_s))
        dx, dy = xx - cx, yy - cy
        r = np.hypot(dx, dy)
        s = np.sin(k * (np.arctan2(dy, dx) - phase))
        pattern = _soft(r * s / k)  # ~ signed distance to the nearest sector edge, in pixels
        inside = _soft(radius - r)
        return _log(0.45 * (1 - inside) + inside * (0.25 + 0.5 * pattern))

    box = _box(geometry, cx - radius, cx + radius, cy - radius, cy + radius)
    return field, lambda t0, t1: box


def ball(geometry: Geometry, *, duration_s: float, speed_px_s=(60.0, 600.0), radius_frac: float = 0.09):
    """A patterned ball crossing the view on an arc, accelerating from slow to fast (Scene I)."""
    w, h = geometry.width, geometry.height
    radius = radius_frac * min(w, h) + 2
    v0, v1 = speed_px_s

    def centre(t):
        cx = -radius + v0 * t + (v1 - v0) * t * t / (2 * duration_s)
        u = cx / w
        return cx, h * (0.75 - 0.5 * u + 0.35 * u * u)

    def field(t, xx, yy):
        cx, cy = centre(t)
        dx, dy = xx - cx, yy - cy
        r = np.hypot(dx, dy)
        spin = cx / radius  # rolling: the pattern turns as the ball travels
        patches = _soft(2.5 * np.sin(3 * np.arctan2(dy, dx) + spin) * np.sin(r / radius * 4.0))
        inside = _soft(radius - r)
        background = 0.35 + 0.05 * np.sin(xx / 9.0) * np.sin(yy / 7.0)  # static texture: no events
        return _log(background * (1 - inside) + inside * (0.25 + 0.6 * patches))

    def region(t0, t1):
        (ax, ay), (bx, by) = centre(t0), centre(t1)
        return _box(geometry, min(ax, bx) - radius, max(ax, bx) + radius,
                    min(ay, by) - radius, max(ay, by) + radius)

    return field, region


def bar(geometry: Geometry, *, duration_s: float, speed_px_s: float = 150.0, width_px: float = 10.0):
    """A dark vertical bar sliding right at constant speed, wrapping around."""
    period = geometry.width + 4 * width_px

    def centre(t):
        return (speed_px_s * t + 3 * width_px) % period - 2 * width_px

    def field(t, xx, yy):
        d = width_px / 2 - np.abs(xx - centre(t))
        return _log(0.7 - 0.45 * _soft(d))

    def region(t0, t1):
        a, b = centre(t0), centre(t1)
        if b < a:  # wrapped: the bar left on the right and re-entered on the left
            return _box(geometry, 0, geometry.width, 0, geometry.height)
        return _box(geometry, a - width_px, b + width_px, 0, geometry.height)

    return field, region


SCENES = {"turntable": turntable, "ball": ball, "bar": bar}


def scene(name: str, geometry: Geometry = DEFAULT_GEOMETRY, duration_us: int = 1_000_000, seed: int = 0,
          model: SensorModel = SensorModel(), **params) -> EventChunk:
    """Simulate a named scene (`turntable`, `ball`, `bar`) and return its events, labelled SIGNAL."""
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
    if duration_us < model.step_us:
        raise ValueError(f"duration_us must be at least one step ({model.step_us} µs), got {duration_us}")
    field, region = SCENES[name](geometry, duration_s=duration_us * 1e-6, **params)
    return concat(list(simulate(field, geometry, duration_us, seed, model, region)), geometry)
