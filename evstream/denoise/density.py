"""Coarse stage of Jiang et al. (Sensors 2024): spatio-temporal density against background activity.

Reconstruction (the paper's equations were lost; see docs/method.md). For event m at (x, y, t), with
L = 2r + 1 and window Δt:

    N(m) = #{ j < m : |x_j - x| <= r, |y_j - y| <= r, t - Δt < t_j <= t }

counts the past events of this stage's input in the L×L window, the centre pixel's own included (so a
hot pixel survives this stage and is left to the fine one). The density is ρ(m) = N(m) / (L²·Δt).

- `absolute` (the paper, literally): BACKGROUND iff ρ(m) < D_th (events per pixel per second).
- `relative` (default): keep iff N(m) >= max(1, ρ_rel · L² · g(m) / (W·H)), g(m) being the events on
  the whole sensor in the same window — "denser than the sensor's average", which adapts the threshold
  to the noise environment as the paper asks, with no per-recording tuning.

Exact, not approximate: a row-summed count map of the events inside the window (`rowsum`) plus a FIFO
of them in arrival order; each event expires the FIFO's head (16 entries at a time over small maps),
sums L cells and pushes itself. The FIFO
holds the events of one window (it grows when needed), so memory is O(W·H + events per Δt).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..events import EventChunk, NoiseClass, shown
from ..jit import bind, intrinsic, njit
from ..nowrap import ix
from ..pipeline import register
from .base import InPlaceClassifier, fifo_capacity, grow_fifo
from .common import is_int
from .prefetch import FAR_BYTES, prefetch
from .rowsum import MAX_RADIUS_PX, box_area, column_sum, padded_map, row_add, row_full

ABSOLUTE, RELATIVE = 0, 1
# How far ahead a kernel over a map larger than the L2 cache prefetches (measured at 1280×720 with the
# uint16 map, in the cascade: 16 events and 32 FIFO entries 2-3 ns/event faster than 4 and 8, 32 and 64
# no better; with the int32 map 4 and 8 had measured best).
PREFETCH_EVENTS, PREFETCH_FIFO = 16, 32
# The FIFO expires its entries G at a time (see the kernel).
EXPIRE_GROUP = 16


@intrinsic
def _head_group(typingctx, fifo_t, fifo_x, fifo_y, head, oldest, x0, y0, box):
    """The EXPIRE_GROUP entries from `head` as one vector test: `out + (near << 32)`, `out` the entries whose
    time is <= `oldest`, `near` those of them with column in x0 .. x0 + box and row in y0 .. y0 + box
    (compared modulo the coordinates' width: the caller keeps x0, y0 >= -MAX_RADIUS_PX and the
    coordinates below 2**bits - MAX_RADIUS_PX). Two masks and two popcounts: the loop over the entries
    it replaces widened the uint16 coordinates to the times' 64-bit lanes (about 60 instructions)."""
    from llvmlite import ir  # typing time: numba is loaded (evstream.jit)
    from numba.core import types

    arrays = (fifo_t, fifo_x, fifo_y)
    if not all(isinstance(a, types.Array) and a.layout == "C" and isinstance(a.dtype, types.Integer) for a in arrays):
        return None
    if fifo_x.dtype != fifo_y.dtype:
        return None
    n = EXPIRE_GROUP

    def codegen(context, builder, signature, args):
        t_ary, x_ary, y_ary, at, old, cx, cy, span = args
        i32 = ir.IntType(32)

        def load(ty, ary, cell):
            data = context.make_array(ty)(context, builder, ary).data
            vec = ir.VectorType(cell, n)
            return builder.load(builder.bitcast(builder.gep(data, [at]), vec.as_pointer()), align=1), vec

        def splat(vec, value):
            one = builder.insert_element(ir.Constant(vec, ir.Undefined), value, ir.Constant(i32, 0))
            lanes = ir.Constant(ir.VectorType(i32, n), [0] * n)
            return builder.shuffle_vector(one, ir.Constant(vec, ir.Undefined), lanes)

        def bits(mask):  # <n x i1> -> how many set, as i64
            return builder.zext(builder.ctpop(builder.bitcast(mask, ir.IntType(n))), ir.IntType(64))

        tv, tvec = load(fifo_t, t_ary, context.get_value_type(fifo_t.dtype))
        gone = builder.icmp_signed("<=", tv, splat(tvec, old))
        cell = context.get_value_type(fifo_x.dtype)
        inside = []
        for ty, ary, lo in ((fifo_x, x_ary, cx), (fifo_y, y_ary, cy)):
            v, vec = load(ty, ary, cell)
            d = builder.sub(v, splat(vec, builder.trunc(lo, cell)))
            inside.append(builder.icmp_unsigned("<=", d, splat(vec, builder.trunc(span, cell))))
        near = builder.and_(gone, builder.and_(inside[0], inside[1]))
        return builder.or_(bits(gone), builder.shl(bits(near), ir.Constant(ir.IntType(64), 32)))

    return types.int64(fifo_t, fifo_x, fifo_y, types.intp, types.int64, types.intp, types.intp, types.intp), codegen


def reference_head_group(fifo_t, fifo_x, fifo_y, head, oldest, x0, y0, box) -> int:
    """`_head_group` in plain Python (its tests' reference; the plain twin tests/mutation.py runs in its
    place): the same `out + (near << 32)`, the coordinates compared modulo their width."""
    group = slice(head, head + EXPIRE_GROUP)
    wrap = (1 << (8 * fifo_x.itemsize)) - 1
    gone = fifo_t[group] <= oldest
    inside = [((c[group].astype(np.int64) - lo) & wrap) <= (box & wrap) for c, lo in ((fifo_x, x0), (fifo_y, y0))]
    return int(gone.sum()) + (int((gone & inside[0] & inside[1]).sum()) << 32)


@functools.cache
def density_kernel(radius, mode, match_polarity, clip_border, want_score, all_live, far):
    """The kernel compiled for one configuration: the options are compile-time constants, so the
    per-event loop carries no option branches and L-cell loops unroll (+13 % over runtime flags).
    `all_live`: no event is rejected yet (the usual first stage), so none is tested (+7–13 %).
    `far`: the map is larger than the L2 cache (`FAR_BYTES`), so each event prefetches the box of the
    event PREFETCH_EVENTS ahead and the row of the FIFO entry PREFETCH_FIFO behind the head, and the
    FIFO expires one entry at a time (there the group expiry below measured slower: the misses, not
    the mispredictions, take the time)."""
    L = 2 * radius + 1
    G = EXPIRE_GROUP

    @njit(cache=True, nogil=True)
    def kernel(t, x, y, p, start, codes, noise_code, hsum, padded_width, fifo_t, fifo_pos, fifo_x, fifo_y,
               fifo_state, per_pol, cell_max, window_us, density_hz, rho_rel, width, height, out_score):
        """Classify events `start..` whose code is SIGNAL (others are skipped: an earlier stage rejected
        them), writing `noise_code` into `codes` for those in sparse neighbourhoods and, if `want_score`,
        the score into `out_score`. Returns the index reached: len(t) unless the FIFO is full or a cell
        the next event adds to is at `cell_max` (the caller grows the FIFO or widens the map, and calls
        again from there).

        `hsum` is a row-summed count map (`rowsum`) of the FIFO's events: one plane, or one per
        polarity with `match_polarity`. The FIFO holds each event's time and its map position
        (`fifo_pos`, `far`) or column and row (`fifo_x`; `fifo_y` plus `height + 2r + 1` on the ON plane
        with `match_polarity`); `fifo_state` = [head, size]; `per_pol` counts the FIFO's events per
        plane. The cells start as uint8 (a quarter of int32's bytes: at 1280×720 0.9 MB, which stays in
        the L2 cache beside the fine stage's state); before an event adds to its L cells the kernel tests
        them against `cell_max` (the type's largest value) in the same vector, and stops there if one is
        at it (the caller widens the map; the event is judged again, the same, on the next call).

        Expiry by groups of G (not `far`): the head advances G entries at a time, once the G-th is
        out of the window (the times are non-decreasing), so the FIFO also holds up to G - 1 events
        already out of it. Each event subtracts those from its count and from g by a fixed G-entry
        test without a branch (vectorised): an expiry loop per event mispredicted its exit on about
        every event (4–5 ns of 12 at 346×260).
        """
        cap = len(fifo_t)  # a multiple of G, and head one too: a group never wraps
        mask = cap - 1
        head = fifo_state[0]
        size = fifo_state[1]
        window_s = window_us * 1e-6
        per_area_abs = density_hz * window_s  # absolute: keep iff N >= D_th · area · Δt
        per_area_rel = rho_rel / (width * height)  # relative: keep iff N >= max(1, ρ_rel · area · g / (W·H))
        plane = (height + 2 * radius) * padded_width
        y_plane = height + 2 * radius + 1  # fifo_y's offset per plane: rows of two planes are > r apart
        box = np.uint32(2 * radius)
        i = start
        n = len(t)
        while i < n:
            stop = min(n, i + cap - size)  # each event pushes at most one: no test inside
            if stop == i:
                break
            while i < stop:
                if not all_live and codes[ix(i)] != 0:
                    i += 1
                    continue
                ti = t[ix(i)]
                oldest = ti - window_us
                if far:
                    a = min(i + PREFETCH_EVENTS, n - 1)
                    top = np.intp(p[ix(a)]) * plane if match_polarity else 0
                    top += np.intp(y[ix(a)]) * padded_width + np.intp(x[ix(a)]) + radius
                    for k in range(L):
                        prefetch(hsum, top + k * padded_width)
                    prefetch(hsum, np.intp(fifo_pos[ix((head + PREFETCH_FIFO) & mask)]))
                    while size > 0 and fifo_t[ix(head)] <= oldest:  # one by one (groups measured slower here)
                        pos = fifo_pos[ix(head)]
                        row_add(hsum, pos, -1, L)
                        if match_polarity:
                            per_pol[1 if pos >= plane else 0] -= 1
                        head = (head + 1) & mask
                        size -= 1
                while not far and size >= G and fifo_t[ix(head + G - 1)] <= oldest:  # the head group is out
                    for k in range(G):
                        yk = np.intp(fifo_y[ix(head + k)])
                        pos = yk * padded_width + np.intp(fifo_x[ix(head + k)]) + radius * padded_width
                        if match_polarity:  # the ON plane's rows are offset by y_plane in fifo_y
                            on = np.intp(yk >= y_plane)
                            pos += on * (plane - y_plane * padded_width)
                            per_pol[on] -= 1
                        row_add(hsum, pos, -1, L)
                    head = (head + G) & mask
                    size -= G
                xi = np.intp(x[ix(i)])
                yi = np.intp(y[ix(i)])
                pl = np.intp(p[ix(i)]) if match_polarity else 0
                yq = yi + pl * y_plane
                x0 = xi - radius  # in the box: 0 <= fifo_x - x0 <= 2r (as uint32: one compare, 32-bit lanes)
                y0 = yq - radius
                out = 0  # events of the head group already out of the window: in the box, on this plane
                near = 0
                same = 0
                if not far and not match_polarity and size >= G:  # the usual case: one vector test
                    both = _head_group(fifo_t, fifo_x, fifo_y, np.intp(head), oldest, x0, y0, np.intp(box))
                    out = both & 0xFFFFFFFF
                    near = both >> 32
                else:
                    for k in range(0 if far else G):
                        q = ix(head + k)
                        d = (k < size) & (fifo_t[q] <= oldest)
                        out += d
                        near += d & (np.uint32(fifo_x[q] - x0) <= box) & (np.uint32(fifo_y[q] - y0) <= box)
                        if match_polarity:
                            same += d & ((fifo_y[q] >= y_plane) == (pl == 1))
                corner = pl * plane + yi * padded_width + xi  # padded (row y, column x): the box's top-left
                pos = corner + radius * padded_width  # the event's L cells
                if row_full(hsum, pos, L, cell_max):  # one would pass its type's largest value: stop before
                    break  # the event's code is written (an event classed noise is skipped when not all_live)
                total = column_sum(hsum, corner + radius, padded_width, L) - near
                area = L * L
                if clip_border:
                    area = box_area(xi, yi, radius, width, height)
                g = (per_pol[pl] - same) * 2 if match_polarity else size - out
                if mode == ABSOLUTE:
                    threshold = per_area_abs * area - 1e-9  # compare counts: no rounding flips
                else:
                    threshold = max(1.0, per_area_rel * area * g)
                codes[ix(i)] = noise_code * (total < threshold)  # branchless: the outcome is data-dependent
                if want_score:
                    if mode == ABSOLUTE:
                        out_score[ix(i)] = total / (area * window_s)
                    else:  # density relative to the sensor's mean: keep iff >= rho_rel (and N >= 1)
                        mean_count = area * g / (width * height)
                        out_score[ix(i)] = total / mean_count if mean_count > 0 else (np.inf if total > 0 else 0.0)
                row_add(hsum, pos, 1, L)
                slot = ix((head + size) & mask)
                fifo_t[slot] = ti
                if far:
                    fifo_pos[slot] = pos
                else:  # the position follows from the column and row
                    fifo_x[slot] = xi
                    fifo_y[slot] = yq
                if match_polarity:
                    per_pol[pl] += 1
                size += 1
                i += 1
            if i < stop:  # stopped for a full cell
                break
        fifo_state[0] = head
        fifo_state[1] = size
        return i

    return kernel


@register("stage", "density")
@dataclass
class DensityFilter(InPlaceClassifier):
    """Spatio-temporal density filter (coarse stage): events in sparse neighbourhoods are BACKGROUND.

    `radius_px` r gives the L = 2r + 1 window; `window_us` is Δt; `mode` "relative" (default) or
    "absolute"; `density_hz` is D_th in events per pixel per second (absolute mode); `rho_rel` the
    multiple of the sensor's mean density an event's neighbourhood must reach (relative mode).
    Score (`classify_scored`): ρ(m) in Hz/pixel (absolute; kept iff >= D_th) or the density relative
    to the sensor's mean, N(m) · W·H / (L² · g(m)) (relative; kept iff >= ρ_rel and N(m) >= 1).
    """

    radius_px: int = 2
    window_us: int = 20_000
    mode: str = "relative"
    density_hz: float = 10.0
    rho_rel: float = 1.5
    match_polarity: bool = False
    clip_border: bool = False
    noise_class = NoiseClass.BACKGROUND
    _state: dict | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        if not is_int(self.radius_px) or not 0 <= self.radius_px <= MAX_RADIUS_PX:
            raise ValueError(f"radius_px must be an integer in 0..{MAX_RADIUS_PX} (L = 2r + 1 is odd), got "
                             f"{shown(self.radius_px)}")
        if not is_int(self.window_us) or self.window_us <= 0:
            raise ValueError(f"window_us must be a positive whole number of µs, got {shown(self.window_us)}")
        self.radius_px, self.window_us = int(self.radius_px), int(self.window_us)
        if self.mode not in ("relative", "absolute"):
            raise ValueError(f"mode must be 'relative' or 'absolute', got {shown(self.mode)}")
        if not self.density_hz >= 0 or not math.isfinite(self.density_hz):
            raise ValueError(f"density_hz must be a finite number >= 0, got {self.density_hz}")
        if not self.rho_rel >= 0 or not math.isfinite(self.rho_rel):
            raise ValueError(f"rho_rel must be a finite number >= 0, got {self.rho_rel}")

    @property
    def n_threshold(self) -> int:
        """Absolute mode as a count: keep iff N(m) >= ceil(D_th · L² · Δt)."""
        L = 2 * self.radius_px + 1
        return math.ceil(self.density_hz * L * L * self.window_us * 1e-6 - 1e-9)

    def _init(self, chunk: EventChunk) -> dict:
        g = chunk.geometry
        r = self.radius_px
        cap = fifo_capacity(g.n_pixels // 16)  # the benchmark scenes' 20 ms windows hold ~n_pixels / 10 events
        # uint8 cells until one would pass 255 (the kernel stops, `_grow` widens them): a quarter of int32's
        # bytes, so at 1280×720 the map (0.9 MB, not 3.7) stays in the L2 cache beside the fine stage's
        hsum = padded_map(g.width, g.height, r, np.uint8, planes=2 if self.match_polarity else 1)
        far = 4 * hsum.nbytes > FAR_BYTES  # as int32 cells (the prefetching paths measured best from there)
        group = 0 if far else cap  # the group expiry keeps columns and rows (not `far`), not positions
        rows = 2 * (g.height + 2 * r + 1)  # fifo_y's range with match_polarity
        xy = np.uint16 if max(g.width, rows) <= 2**16 - MAX_RADIUS_PX else np.int32  # _head_group: no wrap
        return {
            "geometry": g,
            "far": far,
            "hsum": hsum,
            "fifo_t": np.zeros(cap, np.int64),
            "fifo_pos": np.zeros(cap - group, np.int32 if len(hsum) < 2**31 else np.int64),  # map positions
            "fifo_x": np.zeros(group, xy),
            "fifo_y": np.zeros(group, xy),  # the row, plus height + 2r + 1 on the ON plane (match_polarity)
            "fifo_state": np.zeros(2, np.int64),
            "per_pol": np.zeros(2, np.int64),
        }

    def _run(self, chunk: EventChunk, codes: np.ndarray, want_score: bool, all_live: bool | None = None) -> np.ndarray:
        """Classify the events of `chunk` whose `codes` are SIGNAL, in place; returns the scores.
        `all_live`: the caller knows whether every code is SIGNAL (None: test it). The parameters are
        read when the state is built, on the first chunk: the per-call cost is the kernel's dispatch."""
        self._ready(chunk)
        if all_live is None:
            all_live = not np.count_nonzero(codes)
        variant = (want_score, all_live)
        call = self._calls.get(variant) or self._calls.setdefault(variant, self._bound(variant))
        n = len(chunk)
        t, x, y, p = chunk.t, chunk.x, chunk.y, chunk.p
        i = 0
        if want_score:
            score = np.zeros(n, np.float64)
            more = (score,)
        else:  # the class-only kernel's score argument is bound with the state: one argument fewer to key
            score, more = _NO_SCORE, ()
        while True:
            i = call(t, x, y, p, i, codes, *more)
            if i >= n:
                return score
            self._grow()
            call = self._calls.setdefault(variant, self._bound(variant))

    def _ready(self, chunk: EventChunk) -> None:
        """The state for the chunk's geometry, built (and the kernel's arguments bound) on the first chunk."""
        s, g = self._state, chunk.geometry
        if s is None or (s["geometry"] is not g and s["geometry"] != g):
            self._state = self._init(chunk)
            self._bind()

    def _grow(self) -> None:
        """Make the room the kernel stopped for (it returned early) and bind the new arrays: double the FIFO
        when it is full, else widen the map's cells (uint8 -> uint16 -> int32 -> int64: one was at its
        type's largest value; the values copy as they are)."""
        s = self._state
        if s["fifo_state"][1] == len(s["fifo_t"]):
            grow_fifo(s, ("fifo_t", "fifo_pos") if self._far else ("fifo_t", "fifo_x", "fifo_y"))
        else:
            s["hsum"] = s["hsum"].astype(WIDER[s["hsum"].dtype])
        self._bind()

    def _bind(self) -> None:
        """The kernel's arguments after the codes: state arrays, then parameters as the kernel's types."""
        s, g, r = self._state, self._state["geometry"], self.radius_px
        self._far = s["far"]
        self._options = (r, ABSOLUTE if self.mode == "absolute" else RELATIVE, self.match_polarity, self.clip_border)
        self._args = (int(self.noise_class), s["hsum"], g.width + 2 * r, s["fifo_t"], s["fifo_pos"], s["fifo_x"],
                      s["fifo_y"], s["fifo_state"], s["per_pol"], cell_max(s["hsum"].dtype),
                      self.window_us, float(self.density_hz),
                      float(self.rho_rel), g.width, g.height)
        self._calls = {}  # (want_score, all_live) -> the kernel's call with these arguments bound

    def _bound(self, variant: tuple) -> object:
        """The kernel for `variant` = (want_score, all_live) with this state bound (evstream.jit.bind)."""
        want_score = variant[0]
        return bind(self._kernel(*variant), 6, self._args if want_score else (*self._args, _NO_SCORE))

    def _kernel(self, want_score: bool, all_live: bool):
        """The kernel compiled for these options and this state (after `_ready`)."""
        return density_kernel(*self._options, want_score, all_live, self._far)


_NO_SCORE = np.zeros(0, np.float64)  # the kernels compiled without the score never touch it
# The type a full map widens to
WIDER = {np.dtype(np.uint8): np.uint16, np.dtype(np.uint16): np.int32, np.dtype(np.int32): np.int64}
# The largest value of a uint8 cell (tests lower it, so that random streams widen the map at any point).
UINT8_CELL_MAX = 2**8 - 1


def cell_max(dtype) -> int:
    """The value at which a cell of `dtype` is full: the map widens before an event adds to it."""
    return UINT8_CELL_MAX if dtype == np.uint8 else np.iinfo(dtype).max
