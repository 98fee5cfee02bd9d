"""Synthetic scenes with ground truth, simulated the way a DVS pixel works.

Each scene is an analytic intensity field I(x, y, t). Every pixel keeps a reference log intensity and
emits an ON (OFF) event each time log I rises (falls) by its contrast threshold, with per-pixel
threshold mismatch and a refractory period, and sub-step timestamps interpolated linearly — so edges
give several events per pixel, fast edges thin out, and the stream looks like a real sensor's.
All events are labelled SIGNAL; `evstream.noise` adds labelled noise.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .events import EventChunk, Geometry, NoiseClass, concat
from .jit import njit

DEFAULT_GEOMETRY = Geometry(346, 260)  # DAVIS346, the paper's sensor


@dataclass(frozen=True)
class SensorModel:
    """Pixel parameters: contrast threshold (log units), its per-pixel spread, refractory period."""

    threshold: float = 0.25
    threshold_sigma: float = 0.03
    refractory_us: int = 100
    step_us: int = 100  # sampling step of the intensity field


BUFFER_EVENTS = 1 << 18  # events a run's buffer holds beyond one step's worst case
NEVER = 2**62  # a wake-up step no simulation reaches
PATCHES_MIN, PATCHES_MAX = 1.0 / (1.0 + math.exp(10.0)), 1.0 / (1.0 + math.exp(-10.0))  # |pattern| <= 10
EDGE_IN, EDGE_OFF = math.exp(-40.0), math.exp(40.0)  # e^-2edge where the ball's edge value saturates
MARGIN = 1e-9  # log units kept between a "cannot cross" bound and a threshold: far above rounding (~1e-15)


@njit(cache=True, nogil=True)
def _cross(a, b, i, j, ref, thr_on, thr_off, last_t, t_prev, span, refractory_us, ex, ey, out, n, cap):
    """The threshold crossings of pixel [i, j] as its log intensity goes from `a` to `b` over `span` µs
    from `t_prev`, written as events at (ex, ey) from index `n` up to `cap`; returns the new count. Updates
    the pixel's reference level and last event time. Each event also gets a sort key (with full-sensor
    state): time, then the earlier step (an event on a step boundary), then row-major pixel order — the
    order the reference emits in, so a run may visit pixels in any order. Called only where a pixel
    crosses: a call passes arrays, whose reference counts cost more than the test."""
    out_t, out_x, out_y, out_p, out_k = out
    h, w = ref.shape
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
            out_k[n] = (2 * tc + (1 if tc == t_prev else 0)) * (h * w) + ey * w + ex
            n += 1
    ref[i, j] = r
    return n


@njit(cache=True, nogil=True, inline="always")
def _crosses(b, r, on, off):
    """Whether log intensity `b` is a threshold away from the reference `r`."""
    return b - r >= on or r - b >= off


@njit(cache=True, nogil=True)
def _emit(log_prev, log_now, ref, thr_on, thr_off, last_t, t_prev, t_now, refractory_us, x0, y0, out):
    """Threshold crossings of every pixel of a region (origin x0, y0) between two samples, in row order;
    returns the number of events written. `ref` and `last_t` (per-pixel state) are updated in place."""
    h, w = log_now.shape
    n = 0
    for y in range(h):
        for x in range(w):
            if _crosses(log_now[y, x], ref[y, x], thr_on[y, x], thr_off[y, x]):
                n = _cross(log_prev[y, x], log_now[y, x], y, x, ref, thr_on, thr_off, last_t, t_prev, t_now - t_prev,
                           refractory_us, x0 + x, y0 + y, out, n, len(out[0]))
    return n


Field = Callable[[float, np.ndarray, np.ndarray], np.ndarray]
Region = Callable[[float, float], tuple[slice, slice]]
# a compiled run: run(s0, s1) simulates steps s0..s1-1 (step s samples t = s * step_us) and returns their events
# as arrays (t, x, y, p, sort key), in any order: the key orders them as the reference emits them
Run = Callable[[int, int], list]
# makes a scene's run over the simulation's per-pixel state (level, ref, thr_on, thr_off, last_t)
Runner = Callable[[tuple, "SensorModel"], Run]
Progress = Callable[[int, int], None]  # (µs of scene simulated, µs in all)


THREADS = max(1, min(4, os.cpu_count() or 1))  # row bands simulated side by side (the kernels release the GIL)
_pool: list[ThreadPoolExecutor] = []


def _in_bands(kernel, s0, s1, args, buffers, step_cap):
    """`kernel(s0, s1, band, bands, *args, step_cap, out, n) -> (n, next step)` over interleaved row bands, one
    per buffer, in threads; returns every band's events (copies). A band whose buffer fills is emptied and
    goes on from where it stopped."""
    def one(band):
        out, parts, s = buffers[band], [], s0
        while s < s1:
            n, s = kernel(s, s1, band, len(buffers), *args, step_cap, out, 0)
            if n:
                parts.append(tuple(a[:n].copy() for a in out))
        return parts

    if len(buffers) == 1:
        return one(0)
    if not _pool:
        _pool.append(ThreadPoolExecutor(THREADS, thread_name_prefix="evstream-synth"))
    return [p for parts in _pool[0].map(one, range(len(buffers))) for p in parts]


def _buffers(cap):
    return (np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16), np.empty(cap, np.uint8),
            np.empty(cap, np.int64))


def simulate(
    log_intensity: Field,
    geometry: Geometry,
    duration_us: int,
    seed: int = 0,
    model: SensorModel = SensorModel(),
    region: Region | None = None,
    chunk_us: int = 50_000,
    runner: Runner | None = None,
    on_progress: Progress | None = None,
):
    """Yield SIGNAL-labelled chunks of the events a DVS would emit watching `log_intensity(t_s, X, Y)`.

    `region(t0_s, t1_s) -> (rows, cols)` bounds where the field may change between two samples, so a
    small moving object costs its own area, not the sensor's. `runner`, when given, makes a compiled run:
    the same field as `log_intensity` (to ~1e-15: the same events) over whole chunks of steps, visiting only
    the pixels that may cross; `log_intensity` then only gives the start. `on_progress(done_us, total_us)`
    is called per chunk.
    """
    rng = np.random.default_rng(seed)
    shape = (geometry.height, geometry.width)
    yy, xx = np.mgrid[0 : geometry.height, 0 : geometry.width].astype(np.float64)
    thr_on = np.maximum(model.threshold + model.threshold_sigma * rng.standard_normal(shape), 0.05)
    thr_off = np.maximum(model.threshold + model.threshold_sigma * rng.standard_normal(shape), 0.05)
    level = log_intensity(0.0, xx, yy)
    ref = level + rng.uniform(-0.5, 0.5, shape) * thr_on  # pixels start at random points of their cycle
    last_t = np.full(shape, -(10**9), np.int64)
    out = _buffers(geometry.n_pixels * 8)  # events one step may write
    px = (level, ref, thr_on, thr_off, last_t)
    run = runner(px, model) if runner else None
    full = (slice(0, geometry.height), slice(0, geometry.width))
    n_steps = duration_us // model.step_us
    s, chunk_start = 1, 0
    while s <= n_steps:
        # the chunk ends at the first step at least chunk_us after its start, or at the last step
        last = min(max(s, -(-(chunk_start + chunk_us) // model.step_us)), n_steps)
        parts = []
        if run is None:
            for step in range(s, last + 1):
                t_now = step * model.step_us
                t_prev = t_now - model.step_us
                rows, cols = region(t_prev * 1e-6, t_now * 1e-6) if region else full
                now = log_intensity(t_now * 1e-6, xx[rows, cols], yy[rows, cols])
                n = _emit(level[rows, cols], now, ref[rows, cols], thr_on[rows, cols], thr_off[rows, cols],
                          last_t[rows, cols], t_prev, t_now, model.refractory_us, cols.start, rows.start, out)
                level[rows, cols] = now
                if n:
                    order = np.argsort(out[0][:n], kind="stable")
                    parts.append(tuple(a[:n][order] for a in out[:4]))
        else:
            parts = run(s, last + 1)
            if parts:
                keys = np.concatenate([p[4] for p in parts])
                order = np.argsort(keys, kind="stable")
                parts = [tuple(np.concatenate([p[i] for p in parts])[order] for i in range(4))]
        t_end = last * model.step_us
        if on_progress is not None:
            on_progress(t_end, duration_us)
        yield _chunk(parts, geometry, t_end=t_end)
        s, chunk_start = last + 1, t_end


def _box(geometry: Geometry, x0, x1, y0, y1, margin=4) -> tuple[slice, slice]:
    """Row and column slices of a box, widened by a margin and clipped to the sensor."""
    r0, r1, c0, c1 = (int(v) for v in _boxes(geometry, x0, x1, y0, y1, margin))
    return slice(r0, r1), slice(c0, c1)


def _chunk(parts, geometry, t_end):
    if parts:
        t, x, y, p = (np.concatenate(a) for a in zip(*parts))
    else:
        t, x, y, p = (np.zeros(0, d) for d in (np.int64, np.uint16, np.uint16, np.uint8))
    label = np.full(len(t), NoiseClass.SIGNAL, np.uint8)
    return EventChunk.from_arrays(t, x, y, p, geometry, label=label, t_end=t_end)


# -- scenes ----------------------------------------------------------------------------------------
# Each scene is a numpy field (the reference, and the start of every simulation) and a compiled run that
# samples the same field and makes the crossings over whole chunks of steps. The runs compute the field
# exactly as before (the same numbers to ~1e-15 as numpy, so the same events: tests/test_synth_noise.py):
# tanh(x) is exactly ±1 for |x| >= SATURATED, sin(a - b) = sin a cos b - cos a sin b with sin a, cos a kept
# per pixel, 0.5 + 0.5 tanh(x) = 1 / (1 + e^-2x). They skip, exactly, what cannot make an event: a pixel
# whose value cannot reach either threshold before the scene has moved enough is not looked at again
# until then (turntable, ball); a column whose value lies between every row's thresholds is passed over
# (bar); a value is only logged when it is near a threshold. Where a crossing needs the value of the
# previous step, that value is computed again from that step's parameters: the same bits.
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
def _wake(travel, i, s, s0, need):
    """The first step after step s (index i of `travel`, the scene's cumulative motion from step s0 - 1) at
    which the scene may have moved by `need`; the run's end (s0 - 1 + len(travel)) if none before. Galloping
    search from i: most answers are near."""
    if not need > 0.0:
        return s + 1
    target = travel[i] + need
    lo, step = i + 1, 1
    while lo + step - 1 < len(travel) and travel[lo + step - 1] < target:
        lo += step
        step *= 2
    hi = min(lo + step - 1, len(travel))
    while lo < hi:
        mid = (lo + hi) // 2
        if travel[mid] >= target:
            hi = mid
        else:
            lo = mid + 1
    return s0 - 1 + lo


@njit(cache=True, nogil=True, inline="always")
def _tt_edge(r, sin_kth, cos_kth, cos_phase, sin_phase, k):
    """~ twice the signed distance (px) of a turntable pixel to the nearest sector edge."""
    return 2.0 * r * (sin_kth * cos_phase - cos_kth * sin_phase) / k


@njit(cache=True, nogil=True, inline="always")
def _tt_value(edge, outside, inside, dark, light):
    """A turntable pixel's log intensity: `dark`/`light` where the pattern is saturated (most of the disk),
    so only the edges cost a log."""
    if inside == 0.0:  # off the disk
        return dark
    if edge >= SATURATED:
        return light
    if edge <= -SATURATED:
        return dark
    return np.log(outside + inside * (0.25 + 0.5 * _logistic(2.0 * edge)) + 0.05)


@njit(cache=True, nogil=True)
def _tt_safe(ref, on, off, outside, inside, dark, light):
    """(lo, hi): while a turntable pixel's edge value stays strictly between them, it cannot cross either
    threshold. Its value rises with the edge value from `dark` to `light` through a logistic, so each
    threshold is one edge value, found by inverting with margins (and clipped where the logistic is too
    flat to invert to 1e-6): ±inf where a threshold is out of reach, lo >= hi where nothing is safe."""
    top = ref + on - MARGIN  # below it, no ON event
    if light <= top - 1e-12:
        hi = np.inf
    else:
        sig = ((np.exp(top) - 0.05 - outside) / inside - 0.25) / 0.5 if inside >= 1e-3 else 0.0
        hi = 0.5 * np.log(min(sig, 1.0 - 1e-4) / (1.0 - min(sig, 1.0 - 1e-4))) - 1e-6 if sig > 1e-4 else -np.inf
    bottom = ref - off + MARGIN  # above it, no OFF event
    if dark >= bottom + 1e-12:
        lo = -np.inf
    else:
        sig = ((np.exp(bottom) - 0.05 - outside) / inside - 0.25) / 0.5 if inside >= 1e-3 else 1.0
        lo = 0.5 * np.log(max(sig, 1e-4) / (1.0 - max(sig, 1e-4))) + 1e-6 if sig < 1.0 - 1e-4 else np.inf
    return lo, hi


@njit(cache=True, nogil=True)
def _turntable_init(static, px, safe, box):
    """Every pixel of the box: its safe edge range, and a look at step 1."""
    r, sin_kth, cos_kth, outside, inside, dark, light = static
    level, ref, thr_on, thr_off, last_t = px
    lo, hi, wake = safe
    for y in range(box[0], box[1]):
        for x in range(box[2], box[3]):
            lo[y, x], hi[y, x] = _tt_safe(ref[y, x], thr_on[y, x], thr_off[y, x], outside[y, x], inside[y, x],
                                          dark[y, x], light[y, x])
            wake[y, x] = 1


@njit(cache=True, nogil=True)
def _turntable_run(s0, s1, band, bands, first, cos_ph, sin_ph, travel, k, static, px, safe, box, step_us,
                   refractory_us, step_cap, out, n):
    """Steps s0..s1-1 of the turntable over the rows of its box in `band` of `bands` (interleaved);
    per-step arrays start at step first - 1. A pixel is looked at on its wake-up step only: its edge value
    moves by at most 2 r |Δ(k phase)| (`travel`), so until it has travelled its distance to the safe
    range's ends, it cannot cross."""
    r, sin_kth, cos_kth, outside, inside, dark, light = static
    level, ref, thr_on, thr_off, last_t = px
    lo, hi, wake = safe
    cap = len(out[0])
    for s in range(s0, s1):
        if n + step_cap > cap:
            return n, s
        i = s - first + 1
        t_prev = (s - 1) * step_us
        limit = n + step_cap
        for y in range(box[0] + (band - box[0]) % bands, box[1], bands):
            for x in range(box[2], box[3]):
                if wake[y, x] > s:
                    continue
                e = _tt_edge(r[y, x], sin_kth[y, x], cos_kth[y, x], cos_ph[i], sin_ph[i], k)
                if not lo[y, x] < e < hi[y, x]:
                    b = _tt_value(e, outside[y, x], inside[y, x], dark[y, x], light[y, x])
                    if _crosses(b, ref[y, x], thr_on[y, x], thr_off[y, x]):
                        if s == 1:  # the start is the numpy field
                            a = level[y, x]
                        else:
                            before = _tt_edge(r[y, x], sin_kth[y, x], cos_kth[y, x], cos_ph[i - 1], sin_ph[i - 1], k)
                            a = _tt_value(before, outside[y, x], inside[y, x], dark[y, x], light[y, x])
                        n = _cross(a, b, y, x, ref, thr_on, thr_off, last_t, t_prev, step_us, refractory_us, x, y,
                                   out, n, limit)
                        lo[y, x], hi[y, x] = _tt_safe(ref[y, x], thr_on[y, x], thr_off[y, x], outside[y, x],
                                                      inside[y, x], dark[y, x], light[y, x])
                low, high = lo[y, x], hi[y, x]
                if low == -np.inf and high == np.inf:  # both thresholds out of reach: never again
                    wake[y, x] = NEVER
                elif r[y, x] == 0.0:  # the centre does not change
                    wake[y, x] = NEVER if low < e < high else s + 1
                else:
                    d = min(high - e, e - low)
                    wake[y, x] = _wake(travel, i, s, first, (d * (1.0 - 1e-9) - 1e-7) * k / (2.0 * r[y, x]))
    return n, s1


@njit(cache=True, nogil=True, inline="always")
def _ball_value(x, y, cx, cy, radius, cos_spin, sin_spin, background):
    """(off the ball, the argument of the log, e^-pattern, e^-2edge, r) of a ball pixel:
    sin(3θ + spin) from (dx + i dy)^3 / r^3. Off the ball its value is the static texture's
    (log_background) and the rest is not computed; where the edge is saturated, e^-2edge is its largest
    value there."""
    dx, dy = x - cx, y - cy
    r = np.sqrt(dx * dx + dy * dy)
    if 2.0 * (radius - r) <= -SATURATED:
        return True, 0.0, 1.0, EDGE_OFF, r
    if r > 0.0:
        c, s = dx / r, dy / r
    else:
        c, s = 1.0, 0.0  # arctan2(0, 0) = 0
    sin3, cos3 = s * (3.0 * c * c - s * s), c * (c * c - 3.0 * s * s)
    ring = np.sin(r / radius * 4.0)
    e_pattern = np.exp(-(10.0 * (sin3 * cos_spin + cos3 * sin_spin) * ring))
    patches = 1.0 / (1.0 + e_pattern)
    edge = 2.0 * (radius - r)
    if edge >= SATURATED:
        inside, e_edge = 1.0, EDGE_IN
    else:
        e_edge = np.exp(-(2.0 * edge))
        inside = 1.0 / (1.0 + e_edge)
    return False, background * (1 - inside) + inside * (0.25 + 0.6 * patches) + 0.05, e_pattern, e_edge, r


@njit(cache=True, nogil=True, inline="always")
def _ball_log(off, v, log_background):
    return log_background if off else np.log(v)


@njit(cache=True, nogil=True, inline="always")
def _ball_stays(off, e_pattern, e_edge, background, grow_pattern, grow_edge, v_lo, v_hi):
    """Whether a ball pixel's log argument stays strictly inside (v_lo, v_hi) while its pattern argument
    moves by at most log(grow_pattern) and twice its edge value by at most log(grow_edge). The argument,
    bg + 0.05 + inside * (0.25 + 0.6 patches - bg), is bilinear in (inside, patches), each a logistic of
    its argument, so its range is at the corners of their ranges."""
    if off:  # the pattern argument is not known: any
        p_lo, p_hi = PATCHES_MIN, PATCHES_MAX
    else:
        p_lo = max(1.0 / (1.0 + e_pattern * grow_pattern), PATCHES_MIN)
        p_hi = min(1.0 / (1.0 + e_pattern / grow_pattern), PATCHES_MAX)
    i_lo, i_hi = 1.0 / (1.0 + e_edge * grow_edge), 1.0 / (1.0 + e_edge / grow_edge)
    w_lo, w_hi = 0.25 + 0.6 * p_lo - background, 0.25 + 0.6 * p_hi - background
    c1, c2, c3, c4 = i_lo * w_lo, i_lo * w_hi, i_hi * w_lo, i_hi * w_hi
    base = background + 0.05
    return (base + min(min(c1, c2), min(c3, c4)) > v_lo * (1.0 + 1e-12)
            and base + max(max(c1, c2), max(c3, c4)) < v_hi * (1.0 - 1e-12))


RING_PX = 0.25  # radius rings of the pattern-rate table
REACH_PX = 0.1 * 2.0 ** np.arange(-8, 11)  # the travels a ball pixel may be given (REACH_PX[-1] = 102 px)


@njit(cache=True, nogil=True, inline="always")
def _pattern_rate(r, ring, radius, d):
    """A bound on the gradient of the ball's pattern argument A = 10 sin(3θ + spin) sin(4r/R), the spin's
    share included, anywhere within `d` px of a pixel at radius r with sin(4r/R) = ring: radially
    10 (4/R) |cos(4ρ/R)|, around 30 |sin(4ρ/R)| / ρ (<= 30 * 4/R), the spin (10/R) |sin(4ρ/R)| per px of
    x travel, with |sin|, |cos| growing by at most 4d/R over ρ in [r - d, r + d]."""
    u = 4.0 / radius
    grow = u * d
    s = min(1.0, abs(ring) + grow)
    c = min(1.0, np.sqrt(max(0.0, 1.0 - ring * ring)) + grow)
    around = 30.0 * u if r <= d else min(30.0 * u, 30.0 * s / (r - d))
    return np.sqrt((10.0 * u * c) ** 2 + around * around) + 10.0 / radius * s


@njit(cache=True, nogil=True)
def _ball_reach(off, e_pattern, e_edge, r, background, grow, k, v_lo, v_hi):
    """The index into REACH_PX of a travel of the ball this pixel stays safe for, from the last answer `k`:
    one up if that is safe (a pixel is looked at often: no need to climb further at once), else `k` if
    safe, else down by two until safe; -1 where none is (look again next step). grow[0, k] = e^(4 d) (the
    edge value moves by at most 2 d over a travel d), grow[1 + j, k] = e^(rate * d) for a pixel at radius
    r in [j, j + 1) * RING_PX (the pattern argument moves by at most rate * d, `_pattern_rate`)."""
    j = 1 + min(int(r / RING_PX), grow.shape[0] - 2)
    if k + 1 < grow.shape[1] and _ball_stays(off, e_pattern, e_edge, background, grow[j, k + 1], grow[0, k + 1],
                                             v_lo, v_hi):
        return k + 1
    while k >= 0:
        if _ball_stays(off, e_pattern, e_edge, background, grow[j, k], grow[0, k], v_lo, v_hi):
            return k
        k -= 2
    return -1


def _ball_grow(radius):
    """The growth factors `_ball_reach` uses (see there), per radius ring of RING_PX and travel REACH_PX; the
    last ring, everything beyond the ball, takes the bound that holds everywhere (136.5 / R)."""
    rings = int((radius + SATURATED / 2) / RING_PX) + 2
    grow = np.empty((rings + 1, len(REACH_PX)))
    grow[0] = np.exp(4.0 * REACH_PX * (1.0 + 1e-9))
    for j in range(rings):
        r = (j + 0.5) * RING_PX  # every r of the ring is within RING_PX / 2 of it: a neighbourhood that much wider
        for k, d in enumerate(REACH_PX):
            wider = d + RING_PX / 2
            rate = 136.5 / radius if j == rings - 1 else _pattern_rate(r, math.sin(r / radius * 4.0), radius, wider)
            x = rate * d * (1.0 + 1e-9)
            grow[1 + j, k] = math.exp(x) if x < 700.0 else math.inf
    return grow


@njit(cache=True, nogil=True, inline="always")
def _in_box(box, y, x):
    return box[0] <= y < box[1] and box[2] <= x < box[3]


V_PREV, V_STEP, V_LO, V_HI, REACH, BG, LOG_BG = range(7)  # a ball pixel's state, side by side in memory


@njit(cache=True, nogil=True)
def _ball_run(s0, s1, band, bands, cx, cy, cos_spin, sin_spin, boxes, travel, radius, grow, px, wake, state,
              step_us, refractory_us, step_cap, out, n):
    """Steps s0..s1-1 of the ball over each step's box, its rows in `band` of `bands` (interleaved;
    per-step arrays are indexed by step). A pixel is
    looked at on its wake-up step only: until the ball has travelled the distance `_ball_reach` allows, it
    cannot cross. Where a crossing needs the pixel's value at its previous step in a box, that step is
    found and its value computed again. `state[y, x]`: the argument of its log when last looked at (-1 off
    the ball), that step (-1: never), its thresholds as bounds on that argument, its REACH_PX index, the
    texture and its log."""
    level, ref, thr_on, thr_off, last_t = px
    cap = len(out[0])
    for s in range(s0, s1):
        if n + step_cap > cap:
            return n, s
        t_prev = (s - 1) * step_us
        limit = n + step_cap
        for y in range(boxes[s, 0] + (band - boxes[s, 0]) % bands, boxes[s, 1], bands):
            for x in range(boxes[s, 2], boxes[s, 3]):
                if wake[y, x] > s:
                    continue
                st = state[y, x]
                bg = st[BG]
                off, v, e_pattern, e_edge, r = _ball_value(x, y, cx[s], cy[s], radius, cos_spin[s], sin_spin[s], bg)
                if off:
                    crosses = _crosses(st[LOG_BG], ref[y, x], thr_on[y, x], thr_off[y, x])
                else:
                    crosses = not st[V_LO] < v < st[V_HI] and _crosses(np.log(v), ref[y, x], thr_on[y, x],
                                                                       thr_off[y, x])
                if crosses:
                    if st[V_STEP] < 0:  # never in a box before: the numpy start
                        a = level[y, x]
                    else:
                        q = s - 1
                        while q > st[V_STEP] and not _in_box(boxes[q], y, x):
                            q -= 1  # the pixel's last step in a box (the reference's `level`)
                        if q == st[V_STEP]:
                            a = st[LOG_BG] if st[V_PREV] < 0.0 else np.log(st[V_PREV])
                        else:
                            o, u, _, _, _ = _ball_value(x, y, cx[q], cy[q], radius, cos_spin[q], sin_spin[q], bg)
                            a = _ball_log(o, u, st[LOG_BG])
                    n = _cross(a, _ball_log(off, v, st[LOG_BG]), y, x, ref, thr_on, thr_off, last_t, t_prev,
                               step_us, refractory_us, x, y, out, n, limit)
                    st[V_LO] = np.exp(ref[y, x] - thr_off[y, x] + MARGIN)
                    st[V_HI] = np.exp(ref[y, x] + thr_on[y, x] - MARGIN)
                st[V_PREV] = -1.0 if off else v
                st[V_STEP] = s
                k = _ball_reach(off, e_pattern, e_edge, r, bg, grow, int(st[REACH]), st[V_LO], st[V_HI])
                st[REACH] = max(k, 0)
                wake[y, x] = _wake(travel, s, s, 1, REACH_PX[k] * (1.0 - 1e-9) - 1e-9) if k >= 0 else s + 1
    return n, s1


@njit(cache=True, nogil=True)
def _bar_run(s0, s1, band, bands, first, centres, boxes, width_px, px, state, step_us, refractory_us, step_cap,
             out, n):
    """Steps s0..s1-1 of the bar, in one band (per-step arrays start at step `first`). It depends on x
    alone: one log per column, and a column is passed over while its value lies strictly between every
    row's thresholds."""
    level, ref, thr_on, thr_off, last_t = px
    value, col_lo, col_hi = state  # value: at the column's last step in the region (NaN: never sampled)
    cap = len(out[0])
    for s in range(s0, s1):
        if n + step_cap > cap:
            return n, s
        i = s - first
        t_prev = (s - 1) * step_us
        limit = n + step_cap
        centre = centres[i]
        for x in range(boxes[i, 2], boxes[i, 3]):
            edge = 2.0 * (width_px / 2 - abs(x - centre))
            if edge >= SATURATED:
                b = np.log(0.7 - 0.45 + 0.05)
            elif edge <= -SATURATED:
                b = np.log(0.7 + 0.05)
            else:
                b = np.log(0.7 - 0.45 * _logistic(2.0 * edge) + 0.05)
            before = value[x]
            value[x] = b
            if col_lo[x] < b < col_hi[x]:
                continue
            low, high = -np.inf, np.inf
            for y in range(boxes[i, 0], boxes[i, 1]):
                if _crosses(b, ref[y, x], thr_on[y, x], thr_off[y, x]):
                    a = level[y, x] if np.isnan(before) else before
                    n = _cross(a, b, y, x, ref, thr_on, thr_off, last_t, t_prev, step_us, refractory_us, x, y,
                               out, n, limit)
                low = max(low, ref[y, x] - thr_off[y, x])
                high = min(high, ref[y, x] + thr_on[y, x])
            col_lo[x], col_hi[x] = low + MARGIN, high - MARGIN
    return n, s1


def _step_times(s0, s1, step_us):
    """Seconds of steps s0..s1-1, as the reference computes them (µs * 1e-6)."""
    return np.arange(s0, s1, dtype=np.int64) * step_us * 1e-6


def _boxes(geometry: Geometry, x0, x1, y0, y1, margin=4) -> np.ndarray:
    """Boxes (rows0, rows1, cols0, cols1) per step from arrays of extents, as `_box` makes them."""
    c0 = np.clip(np.floor(x0) - margin, 0, geometry.width).astype(np.int64)
    c1 = np.clip(np.ceil(x1) + margin + 1, 0, geometry.width).astype(np.int64)
    r0 = np.clip(np.floor(y0) - margin, 0, geometry.height).astype(np.int64)
    r1 = np.clip(np.ceil(y1) + margin + 1, 0, geometry.height).astype(np.int64)
    return np.stack([r0, np.maximum(r0, r1), c0, np.maximum(c0, c1)], axis=-1)


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

    def runner(px, model):
        yy, xx = np.mgrid[0 : geometry.height, 0 : geometry.width].astype(np.float64)
        dx, dy = xx - cx, yy - cy
        r = np.hypot(dx, dy)
        kth = k * np.arctan2(dy, dx)
        inside = _soft(radius - r)
        outside = 0.45 * (1 - inside)
        static = (r, np.sin(kth), np.cos(kth), outside, inside, _log(outside + inside * 0.25),
                  _log(outside + inside * 0.75))
        shape = r.shape
        safe = (np.full(shape, np.inf), np.full(shape, -np.inf), np.full(shape, NEVER, np.int64))
        limits = np.array([box[0].start, box[0].stop, box[1].start, box[1].stop], np.int64)
        _turntable_init(static, px, safe, limits)
        step_cap = 8 * geometry.n_pixels
        buffers = [_buffers(step_cap + BUFFER_EVENTS) for _ in range(THREADS)]

        def run(s0, s1):
            kphase = k * phase_at(_step_times(s0 - 1, s1, model.step_us))
            cos_ph, sin_ph = np.cos(kphase), np.sin(kphase)  # bit for bit what np.cos of each value gives
            travel = np.concatenate(([0.0], np.cumsum(np.abs(np.diff(kphase)))))
            return _in_bands(_turntable_run, s0, s1, (s0, cos_ph, sin_ph, travel, k, static, px, safe, limits,
                                                       model.step_us, model.refractory_us), buffers, step_cap)

        return run

    return field, lambda t0, t1: box, runner


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

    def boxes(t0, t1):
        (ax, ay), (bx, by) = centre(t0), centre(t1)
        return _boxes(geometry, np.minimum(ax, bx) - radius, np.maximum(ax, bx) + radius,
                      np.minimum(ay, by) - radius, np.maximum(ay, by) + radius)

    def region(t0, t1):
        r0, r1, c0, c1 = (int(v) for v in boxes(t0, t1))
        return slice(r0, r1), slice(c0, c1)

    def runner(px, model):
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        background = texture(xx, yy)
        state = np.stack([np.zeros(background.shape), np.full(background.shape, -1.0), np.exp(px[1] - px[3] + MARGIN),
                          np.exp(px[1] + px[2] - MARGIN), np.full(background.shape, 8.0), background,
                          _log(background)], axis=-1)
        wake = np.zeros(background.shape, np.int64)
        grow = _ball_grow(radius)
        steps = {}  # per-step parameters, indexed by step, for every step simulated so far

        def extend(s1):  # known steps: to s1 and some way beyond, so that wake-ups can look ahead
            known = len(steps.get("cx", ()))
            if s1 <= known:
                return
            t = _step_times(known, s1 + 2_000, model.step_us)
            cx, cy = centre(t)
            spin = cx / radius
            new = {"cx": cx, "cy": cy, "cos": np.cos(spin), "sin": np.sin(spin),  # as np.cos of each value
                   "boxes": boxes(t - model.step_us * 1e-6, t)}
            if known:
                moved = np.hypot(np.diff(cx, prepend=steps["cx"][-1]), np.diff(cy, prepend=steps["cy"][-1]))
                new["travel"] = steps["travel"][-1] + np.cumsum(moved)
            else:
                new["travel"] = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(cx), np.diff(cy)))))
            for key, value in new.items():
                steps[key] = np.concatenate([steps[key], value]) if key in steps else value

        step_cap = 8 * geometry.n_pixels
        buffers = [_buffers(step_cap + BUFFER_EVENTS) for _ in range(THREADS)]

        def run(s0, s1):
            extend(s1)
            return _in_bands(_ball_run, s0, s1, (steps["cx"], steps["cy"], steps["cos"], steps["sin"], steps["boxes"],
                                                 steps["travel"], radius, grow, px, wake, state, model.step_us,
                                                 model.refractory_us), buffers, step_cap)

        return run

    return field, region, runner


def bar(geometry: Geometry, *, duration_s: float, speed_px_s: float = 150.0, width_px: float = 10.0):
    """A dark vertical bar sliding right at constant speed, wrapping around."""
    period = geometry.width + 4 * width_px

    def centre(t):
        return (speed_px_s * t + 3 * width_px) % period - 2 * width_px

    def field(t, xx, yy):
        d = width_px / 2 - np.abs(xx - centre(t))
        return _log(0.7 - 0.45 * _soft(d))

    def boxes(t0, t1):
        a, b = centre(t0), centre(t1)
        wrapped = b < a  # the bar left on the right and re-entered on the left: all of it
        return _boxes(geometry, np.where(wrapped, 0, a - width_px), np.where(wrapped, geometry.width, b + width_px),
                      np.zeros_like(a), np.full_like(a, geometry.height))

    def region(t0, t1):
        r0, r1, c0, c1 = (int(v) for v in boxes(t0, t1))
        return slice(r0, r1), slice(c0, c1)

    def runner(px, model):
        shape = px[0].shape
        state = (np.full(shape[1], np.nan), np.full(shape[1], np.inf), np.full(shape[1], -np.inf))

        step_cap = 8 * geometry.n_pixels
        buffers = [_buffers(step_cap + BUFFER_EVENTS)]  # one band: a column is all its rows at once

        def run(s0, s1):
            t = _step_times(s0, s1, model.step_us)
            return _in_bands(_bar_run, s0, s1, (s0, centre(t), boxes(t - model.step_us * 1e-6, t), width_px, px, state,
                                                model.step_us, model.refractory_us), buffers, step_cap)

        return run

    return field, region, runner


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
    field, region, runner = SCENES[name](geometry, duration_s=duration_us * 1e-6, **params)
    chunks = simulate(field, geometry, duration_us, seed, model, region,
                      runner=runner if compiled else None, on_progress=on_progress)
    return concat(list(chunks), geometry)
