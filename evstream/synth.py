"""Synthetic scenes with ground truth, simulated the way a DVS pixel works.

Each scene is an analytic intensity field I(x, y, t). Every pixel keeps a reference log intensity and
emits an ON (OFF) event each time log I rises (falls) by its contrast threshold, with per-pixel
threshold mismatch and a refractory period, and sub-step timestamps interpolated linearly — so edges
give several events per pixel, fast edges thin out, and the stream looks like a real sensor's.
All events are labelled SIGNAL; `evstream.noise` adds labelled noise.
"""

from __future__ import annotations

import math
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
def _cross(a, b, i, j, ref, thr_on, thr_off, last_t, t_prev, span, refractory_us, ex, ey,
           out_t, out_x, out_y, out_p, n):
    """The threshold crossings of pixel [i, j] as its log intensity goes from `a` to `b` over `span` µs
    from `t_prev`, written as events at (ex, ey) from index `n`; returns the new count. Updates the
    pixel's reference level and last event time. Called only where `_crosses` says so: a call passes
    arrays, whose reference counts cost more than the test."""
    cap = len(out_t)
    r = ref[i, j]
    while n < cap:
        if b - r >= thr_on[i, j]:
            level = r + thr_on[i, j]
            pol = 1
        elif r - b >= thr_off[i, j]:
            level = r - thr_off[i, j]
            pol = 0
        else:
            break
        frac = (level - a) / (b - a) if b != a else 1.0
        frac = min(max(frac, 0.0), 1.0)
        tc = t_prev + np.int64(frac * span)
        r = level  # a crossing inside the refractory period is lost, not postponed
        if tc - last_t[i, j] >= refractory_us:
            last_t[i, j] = tc
            out_t[n] = tc
            out_x[n] = ex
            out_y[n] = ey
            out_p[n] = pol
            n += 1
    ref[i, j] = r
    return n


@njit(cache=True, nogil=True, inline="always")
def _crosses(b, r, on, off):
    """Whether log intensity `b` is a threshold away from the reference `r`."""
    return b - r >= on or r - b >= off


@njit(cache=True, nogil=True)
def _emit(log_prev, log_now, ref, thr_on, thr_off, last_t, t_prev, t_now, refractory_us, x0, y0,
          out_t, out_x, out_y, out_p):
    """Threshold crossings of every pixel of a region (origin x0, y0) between two samples; returns the
    number of events written. `ref` and `last_t` (per-pixel state) are updated in place."""
    h, w = log_now.shape
    n = 0
    for y in range(h):
        for x in range(w):
            if _crosses(log_now[y, x], ref[y, x], thr_on[y, x], thr_off[y, x]):
                n = _cross(log_prev[y, x], log_now[y, x], y, x, ref, thr_on, thr_off, last_t, t_prev, t_now - t_prev,
                           refractory_us, x0 + x, y0 + y, out_t, out_x, out_y, out_p, n)
    return n


Field = Callable[[float, np.ndarray, np.ndarray], np.ndarray]
Region = Callable[[float, float], tuple[slice, slice]]
# a compiled step: (t_prev_us, t_now_us, rows, cols, px, refractory_us, out) -> events written into out
Stepper = Callable[[int, int, slice, slice, tuple, int, tuple], int]
Progress = Callable[[int, int], None]  # (µs of scene simulated, µs in all)


def simulate(
    log_intensity: Field,
    geometry: Geometry,
    duration_us: int,
    seed: int = 0,
    model: SensorModel = SensorModel(),
    region: Region | None = None,
    chunk_us: int = 50_000,
    stepper: Stepper | None = None,
    on_progress: Progress | None = None,
):
    """Yield SIGNAL-labelled chunks of the events a DVS would emit watching `log_intensity(t_s, X, Y)`.

    `region(t0_s, t1_s) -> (rows, cols)` bounds where the field may change between two samples, so a
    small moving object costs its own area, not the sensor's. `stepper`, when given, is a compiled step:
    the same field as `log_intensity` (to ~1e-15: the same events) and the crossings in one pass over the
    region; `log_intensity` then only gives the start. `on_progress(done_us, total_us)` is called per chunk.
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
    px = (level, ref, thr_on, thr_off, last_t)
    parts = []
    chunk_start = 0
    full = (slice(0, geometry.height), slice(0, geometry.width))
    for t_now in range(model.step_us, duration_us + 1, model.step_us):
        t_prev = t_now - model.step_us
        rows, cols = region(t_prev * 1e-6, t_now * 1e-6) if region else full
        if stepper is None:
            now = log_intensity(t_now * 1e-6, xx[rows, cols], yy[rows, cols])
            n = _emit(level[rows, cols], now, ref[rows, cols], thr_on[rows, cols], thr_off[rows, cols],
                      last_t[rows, cols], t_prev, t_now, model.refractory_us,
                      cols.start, rows.start, *out)
            level[rows, cols] = now
        else:
            n = stepper(t_prev, t_now, rows, cols, px, model.refractory_us, out)
        if n:
            order = np.argsort(out[0][:n], kind="stable")
            parts.append(tuple(a[:n][order] for a in out))
        if t_now - chunk_start >= chunk_us or t_now + model.step_us > duration_us:
            if on_progress is not None:
                on_progress(t_now, duration_us)
            yield _chunk(parts, geometry, t_end=t_now)
            parts, chunk_start = [], t_now


def _box(geometry: Geometry, x0, x1, y0, y1, margin=4) -> tuple[slice, slice]:
    """Row and column slices of a box, widened by a margin and clipped to the sensor."""
    c0 = min(max(math.floor(x0) - margin, 0), geometry.width)
    c1 = min(max(math.ceil(x1) + margin + 1, 0), geometry.width)
    r0 = min(max(math.floor(y0) - margin, 0), geometry.height)
    r1 = min(max(math.ceil(y1) + margin + 1, 0), geometry.height)
    return slice(r0, max(r0, r1)), slice(c0, max(c0, c1))


def _chunk(parts, geometry, t_end):
    if parts:
        t, x, y, p = (np.concatenate(a) for a in zip(*parts))
    else:
        t, x, y, p = (np.zeros(0, d) for d in (np.int64, np.uint16, np.uint16, np.uint8))
    label = np.full(len(t), NoiseClass.SIGNAL, np.uint8)
    return EventChunk.from_arrays(t, x, y, p, geometry, label=label, t_end=t_end)


# -- scenes ----------------------------------------------------------------------------------------
# Each scene is a numpy field (the reference, and the start of every simulation) and a compiled step that
# samples the same field over a region and makes the crossings in one pass. The steps skip the work that
# cannot change a value (tanh(x) is exactly ±1 for |x| >= SATURATED), turn sin(a - b) into
# sin a cos b - cos a sin b with sin a, cos a kept per pixel, and 0.5 + 0.5 tanh(x) into 1 / (1 + e^-2x):
# the same numbers to ~1e-15, so the same events (tests/test_synth_noise.py compares them).
SATURATED = 20.0  # tanh(20) = 1 - 8e-18 rounds to 1.0 in float64


def _soft(d_px):
    """Anti-aliased step: 0 -> 1 over about one pixel as the signed distance `d_px` crosses 0."""
    return 0.5 + 0.5 * np.tanh(2.0 * d_px)


def _log(i):
    return np.log(i + 0.05)


@njit(cache=True, nogil=True, inline="always")
def _logistic(x):
    """1 / (1 + e^-x) = 0.5 + 0.5 tanh(x / 2) (one exp is cheaper than a tanh; equal to ~1e-16)."""
    return 1.0 / (1.0 + np.exp(-x))


@njit(cache=True, nogil=True)
def _turntable_step(cos_phase, sin_phase, k, r, sin_kth, cos_kth, outside, inside, dark, light,
                    rows0, rows1, cols0, cols1, px, t_prev, t_now, refractory_us, out):
    """The turntable over a region: sin(k(θ - phase)) from per-pixel sin kθ, cos kθ; `dark`/`light` are
    the pixel's values where the pattern is saturated (most of the disk), so only the edges cost a log."""
    level, ref, thr_on, thr_off, last_t = px
    out_t, out_x, out_y, out_p = out
    span = t_now - t_prev
    n = 0
    for y in range(rows0, rows1):
        for x in range(cols0, cols1):
            if inside[y, x] == 0.0:  # off the disk
                b = dark[y, x]
            else:
                edge = 2.0 * r[y, x] * (sin_kth[y, x] * cos_phase - cos_kth[y, x] * sin_phase) / k
                if edge >= SATURATED:
                    b = light[y, x]
                elif edge <= -SATURATED:
                    b = dark[y, x]
                else:
                    b = np.log(outside[y, x] + inside[y, x] * (0.25 + 0.5 * _logistic(2.0 * edge)) + 0.05)
            if _crosses(b, ref[y, x], thr_on[y, x], thr_off[y, x]):
                n = _cross(level[y, x], b, y, x, ref, thr_on, thr_off, last_t, t_prev, span, refractory_us, x, y,
                           out_t, out_x, out_y, out_p, n)
            level[y, x] = b
    return n


@njit(cache=True, nogil=True)
def _ball_step(cx, cy, radius, cos_spin, sin_spin, background, log_background,
               rows0, rows1, cols0, cols1, px, t_prev, t_now, refractory_us, out):
    """The ball over a region; sin(3θ + spin) from (dx + i dy)^3 / r^3, the texture as it is off the ball."""
    level, ref, thr_on, thr_off, last_t = px
    out_t, out_x, out_y, out_p = out
    span = t_now - t_prev
    n = 0
    for y in range(rows0, rows1):
        for x in range(cols0, cols1):
            dx, dy = x - cx, y - cy
            r = np.sqrt(dx * dx + dy * dy)
            if 2.0 * (radius - r) <= -SATURATED:  # off the ball: the static texture
                b = log_background[y, x]
            else:
                if r > 0.0:
                    c, s = dx / r, dy / r
                else:
                    c, s = 1.0, 0.0  # arctan2(0, 0) = 0
                sin3, cos3 = s * (3.0 * c * c - s * s), c * (c * c - 3.0 * s * s)
                patches = _logistic(10.0 * (sin3 * cos_spin + cos3 * sin_spin) * np.sin(r / radius * 4.0))
                edge = 2.0 * (radius - r)
                inside = 1.0 if edge >= SATURATED else _logistic(2.0 * edge)
                b = np.log(background[y, x] * (1 - inside) + inside * (0.25 + 0.6 * patches) + 0.05)
            if _crosses(b, ref[y, x], thr_on[y, x], thr_off[y, x]):
                n = _cross(level[y, x], b, y, x, ref, thr_on, thr_off, last_t, t_prev, span, refractory_us, x, y,
                           out_t, out_x, out_y, out_p, n)
            level[y, x] = b
    return n


@njit(cache=True, nogil=True)
def _bar_step(centre, width_px, rows0, rows1, cols0, cols1, px, t_prev, t_now, refractory_us, out):
    """The bar over a region: it depends on x alone, so one log per column."""
    level, ref, thr_on, thr_off, last_t = px
    out_t, out_x, out_y, out_p = out
    span = t_now - t_prev
    values = np.empty(cols1 - cols0)
    for x in range(cols0, cols1):
        edge = 2.0 * (width_px / 2 - abs(x - centre))
        if edge >= SATURATED:
            values[x - cols0] = np.log(0.7 - 0.45 + 0.05)
        elif edge <= -SATURATED:
            values[x - cols0] = np.log(0.7 + 0.05)
        else:
            values[x - cols0] = np.log(0.7 - 0.45 * _logistic(2.0 * edge) + 0.05)
    n = 0
    for y in range(rows0, rows1):  # row by row, as the reference emits (equal times keep that order)
        for x in range(cols0, cols1):
            b = values[x - cols0]
            if _crosses(b, ref[y, x], thr_on[y, x], thr_off[y, x]):
                n = _cross(level[y, x], b, y, x, ref, thr_on, thr_off, last_t, t_prev, span, refractory_us, x, y,
                           out_t, out_x, out_y, out_p, n)
            level[y, x] = b
    return n


def turntable(geometry: Geometry, *, duration_s: float, sectors: int = 4, rev_hz=(3.0, 0.3),
              radius_frac: float = 0.2):
    """A black-and-white sector disk whose rotation slows linearly from rev_hz[0] to rev_hz[1]
    (the paper's Scene II: fast to slow)."""
    cx, cy = (geometry.width - 1) / 2, (geometry.height - 1) / 2
    radius = radius_frac * min(geometry.width, geometry.height)
    f0, f1 = rev_hz
    k = sectors / 2

    def phase_at(t):
        return 2 * np.pi * (f0 * t + (f1 - f0) * t * t / (2 * duration_s))

    def field(t, xx, yy):
        phase = phase_at(t)
        dx, dy = xx - cx, yy - cy
        r = np.hypot(dx, dy)
        s = np.sin(k * (np.arctan2(dy, dx) - phase))
        pattern = _soft(r * s / k)  # ~ signed distance to the nearest sector edge, in pixels
        inside = _soft(radius - r)
        return _log(0.45 * (1 - inside) + inside * (0.25 + 0.5 * pattern))

    box = _box(geometry, cx - radius, cx + radius, cy - radius, cy + radius)
    static = {}

    def stepper(t_prev, t_now, rows, cols, px, refractory_us, out):
        if not static:  # per pixel, once: what does not turn
            yy, xx = np.mgrid[0 : geometry.height, 0 : geometry.width].astype(np.float64)
            dx, dy = xx - cx, yy - cy
            r = np.hypot(dx, dy)
            kth = k * np.arctan2(dy, dx)
            inside = _soft(radius - r)
            outside = 0.45 * (1 - inside)
            static.update(r=r, sin_kth=np.sin(kth), cos_kth=np.cos(kth), outside=outside, inside=inside,
                          dark=_log(outside + inside * 0.25), light=_log(outside + inside * 0.75))
        kphase = k * phase_at(t_now * 1e-6)
        return _turntable_step(np.cos(kphase), np.sin(kphase), k, static["r"], static["sin_kth"], static["cos_kth"],
                               static["outside"], static["inside"], static["dark"], static["light"],
                               rows.start, rows.stop, cols.start, cols.stop, px, t_prev, t_now, refractory_us, out)

    return field, lambda t0, t1: box, stepper


def ball(geometry: Geometry, *, duration_s: float, speed_px_s=(60.0, 600.0), radius_frac: float = 0.09):
    """A patterned ball crossing the view on an arc, accelerating from slow to fast (Scene I)."""
    w, h = geometry.width, geometry.height
    radius = radius_frac * min(w, h) + 2
    v0, v1 = speed_px_s

    def centre(t):
        cx = -radius + v0 * t + (v1 - v0) * t * t / (2 * duration_s)
        u = cx / w
        return cx, h * (0.75 - 0.5 * u + 0.35 * u * u)

    def texture(xx, yy):
        return 0.35 + 0.05 * np.sin(xx / 9.0) * np.sin(yy / 7.0)  # static texture: no events

    def field(t, xx, yy):
        cx, cy = centre(t)
        dx, dy = xx - cx, yy - cy
        r = np.hypot(dx, dy)
        spin = cx / radius  # rolling: the pattern turns as the ball travels
        patches = _soft(2.5 * np.sin(3 * np.arctan2(dy, dx) + spin) * np.sin(r / radius * 4.0))
        inside = _soft(radius - r)
        return _log(texture(xx, yy) * (1 - inside) + inside * (0.25 + 0.6 * patches))

    def region(t0, t1):
        (ax, ay), (bx, by) = centre(t0), centre(t1)
        return _box(geometry, min(ax, bx) - radius, max(ax, bx) + radius,
                    min(ay, by) - radius, max(ay, by) + radius)

    static = {}

    def stepper(t_prev, t_now, rows, cols, px, refractory_us, out):
        if not static:
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
            background = texture(xx, yy)
            static.update(background=background, log_background=_log(background))
        cx, cy = centre(t_now * 1e-6)
        spin = cx / radius
        return _ball_step(cx, cy, radius, np.cos(spin), np.sin(spin), static["background"], static["log_background"],
                          rows.start, rows.stop, cols.start, cols.stop, px, t_prev, t_now, refractory_us, out)

    return field, region, stepper


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

    def stepper(t_prev, t_now, rows, cols, px, refractory_us, out):
        return _bar_step(centre(t_now * 1e-6), width_px, rows.start, rows.stop, cols.start, cols.stop, px,
                         t_prev, t_now, refractory_us, out)

    return field, region, stepper


SCENES = {"turntable": turntable, "ball": ball, "bar": bar}


def scene(name: str, geometry: Geometry = DEFAULT_GEOMETRY, duration_us: int = 1_000_000, seed: int = 0,
          model: SensorModel = SensorModel(), *, compiled: bool = True, on_progress: Progress | None = None,
          **params) -> EventChunk:
    """Simulate a named scene (`turntable`, `ball`, `bar`) and return its events, labelled SIGNAL.

    `compiled=False` samples the numpy reference field at every step (slow; the same events)."""
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
    if duration_us < model.step_us:
        raise ValueError(f"duration_us must be at least one step ({model.step_us} µs), got {duration_us}")
    field, region, stepper = SCENES[name](geometry, duration_s=duration_us * 1e-6, **params)
    chunks = simulate(field, geometry, duration_us, seed, model, region,
                      stepper=stepper if compiled else None, on_progress=on_progress)
    return concat(list(chunks), geometry)
