"""Representations (time surface, voxel grid, histogram, count, last timestamp) as framers: each checked
against a plain-Python definition over the frames the windowing framer emits, and with the invariant kit."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evstream.events import EventChunk, Geometry, concat
from evstream.framing.base import COUNT_MAX
from evstream.framing.fixed import FN_DONE, FN_FULL, FN_TIMEOUT, accumulate, fn_scan
from evstream.framing.overlap import add_flat, slide_kernel
from evstream.framing.represent import (
    EXP_FLOOR,
    EXP_MIN_NORMAL,
    NEVER_US,
    REPRESENTATIONS,
    Representation,
    RepresentationFramer,
    last_time_count_of,
    last_time_of,
    last_time_take,
    rebase,
    surface,
    surface_exponent,
    timestamp_kernel,
    timestamp_of_chunk,
    voxel_count_flat,
    voxel_count_kernel,
    voxel_count_of_chunk,
    voxel_kernel,
    voxel_of_chunk,
    voxel_table,
    voxel_table_kernel,
    voxel_table_of_chunk,
    voxel_take,
)
from evstream.pipeline import Pipeline, build
from evstream.testing import (
    assert_bounded_state,
    assert_cameras_independent,
    assert_chunk_invariant,
    assert_framer_causal,
    frames_of,
    random_stream,
)

WINDOWS = {
    "fw": {"window_us": 3000},
    "fn": {"n_events": 120, "max_window_us": 20_000},
    "oa": {"window_us": 4000, "stride_us": 1500},
    "adaptive": {"window_us": 4000, "n_base": 60},
}
EXTRA = {"voxel": {"bins": 4}, "timesurface": {"tau_us": 2000.0}}
CHANNELS = {"timesurface": ("off", "on"), "voxel": ("bin0", "bin1", "bin2", "bin3"), "histogram": ("off", "on"),
            "count": ("events",), "timestamp": ("off", "on")}


def make(kind, window, **more):
    return lambda: build("framer", {"kind": kind, "window": window, **WINDOWS[window], **EXTRA.get(kind, {}), **more})


# -- plain-Python definitions ---------------------------------------------------------------------
def window_events(stream: EventChunk, frames, window: str, all_events=False):
    """The counted events of each frame, found the plain way: by time, or by count for fn."""
    counted = np.ones(len(stream), bool) if all_events or stream.cls is None else stream.cls == 0
    t, x, y, p = stream.t[counted], stream.x[counted], stream.y[counted], stream.p[counted]
    out, k = [], 0
    for fr in frames:
        if window == "fn":
            sel = slice(k, k + fr.n_events)
            k += fr.n_events
        else:
            idx = [i for i in range(len(t)) if fr.t_start <= t[i] < fr.t_end]
            sel = slice(idx[0], idx[-1] + 1) if idx else slice(0, 0)
        out.append((t[sel], x[sel], y[sel], p[sel], sel.stop))
    return out, (t, x, y, p)


def reference(kind, stream, frames, window, bins=4, tau_us=2000.0, all_events=False):
    g = stream.geometry
    per_window, (ta, xa, ya, pa) = window_events(stream, frames, window, all_events)
    refs = []
    for fr, (t, x, y, p, upto) in zip(frames, per_window):
        assert len(t) == fr.n_events
        if kind == "histogram":
            d = np.zeros((2, g.height, g.width))
            for i in range(len(t)):
                d[p[i], y[i], x[i]] += 1
        elif kind == "count":
            d = np.zeros((1, g.height, g.width))
            for i in range(len(t)):
                d[0, y[i], x[i]] += 1
        elif kind == "timestamp":
            d = np.zeros((2, g.height, g.width))
            for i in range(len(t)):
                d[p[i], y[i], x[i]] = (int(t[i]) - fr.t_start + 1) / (fr.t_end - fr.t_start)
        elif kind == "voxel":
            d = np.zeros((bins, g.height, g.width))
            span = max(1, fr.t_end - 1 - fr.t_start)
            for i in range(len(t)):
                tn = (bins - 1) * (int(t[i]) - fr.t_start) / span
                for b in range(bins):
                    d[b, y[i], x[i]] += (1 if p[i] else -1) * max(0.0, 1 - abs(b - tn))
        elif kind == "timesurface":
            d = np.zeros((2, g.height, g.width))
            last = {}
            # every event before the window's end; for fn, up to its last event in stream order (one
            # at the same time after it belongs to the next window, and may not have arrived yet)
            for i in range(upto if window == "fn" else len(ta)):
                if ta[i] < fr.t_end:
                    last[(pa[i], ya[i], xa[i])] = int(ta[i])
            for (pp, yy, xx), tl in last.items():
                d[pp, yy, xx] = math.exp(-(fr.t_end - tl) / tau_us)
        refs.append(d)
    return refs


def labelled(seed, n):
    s = random_stream(seed, n, Geometry(9, 7), mean_dt_us=40)
    return s.replace(cls=s.label)  # some events are not SIGNAL: they must not be counted


@pytest.mark.parametrize("all_events", [False, True])
@pytest.mark.parametrize("window", sorted(WINDOWS))
@pytest.mark.parametrize("kind", REPRESENTATIONS)
def test_matches_the_definition(kind, window, all_events):
    stream = labelled(3, 1500)
    framer = make(kind, window, all_events=all_events)()
    frames = frames_of(framer, [stream])
    assert len(frames) > 5
    inner = build("framer", {"kind": window, **WINDOWS[window], "all_events": all_events})
    plain = frames_of(inner, [stream])
    # what framing.bound.cut reads: the windows' steps, and the bytes of a frame (counts and channels)
    assert (framer.frame_step(), framer.pause_step_us()) == (inner.frame_step(), inner.pause_step_us())
    assert all(framer.frame_bytes(stream.geometry.n_pixels) == fr.counts.nbytes + fr.data.nbytes for fr in frames)
    assert [(f.t_start, f.t_end, f.n_events) for f in frames] == [(f.t_start, f.t_end, f.n_events) for f in plain]
    assert all(np.array_equal(f.counts, g.counts) for f, g in zip(frames, plain))  # some counted by the follower
    for fr, ref in zip(frames, reference(kind, stream, frames, window, all_events=all_events)):
        assert isinstance(fr, Representation) and fr.kind == kind
        assert fr.data.dtype == np.float32 and fr.data.flags.c_contiguous and fr.data.flags.owndata
        assert fr.data.shape == ref.shape and fr.channels == CHANNELS[kind]
        np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize("window", ["fw", "oa", "adaptive"])
@pytest.mark.parametrize("kind", REPRESENTATIONS)
def test_windows_without_events_are_zero(kind, window):
    """A quiet stretch of several windows: each empty window is emitted (max_empty_frames), all zero."""
    first = labelled(7, 300)
    second = labelled(8, 300)
    gap = int(first.t[-1]) + 20_000
    stream = concat([first, second.replace(t=second.t + gap)])
    frames = frames_of(make(kind, window)(), [stream])
    assert sum(fr.n_events == 0 for fr in frames) >= 3
    for fr, ref in zip(frames, reference(kind, stream, frames, window), strict=True):
        assert fr.data.shape == ref.shape and fr.channels == CHANNELS[kind]
        np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


@dataclass(eq=False)
class BufferedHistogram(RepresentationFramer):
    """The smallest subclass (`channels_of` and `_compute` alone): it buffers its windows' events and finds
    each window's by time (by count over fn windows), as no shipped representation does over time windows
    (the voxel grid and the timestamp image add events as they are counted). Here: the histogram."""

    kind = "buffered-histogram"

    def __post_init__(self):
        self._setup()

    def channels_of(self) -> tuple:
        return ("off", "on")

    def _compute(self, fr, a, b):
        la, lb = self._local(a, b)
        g = self.geometry
        per_pixel = np.bincount(self._buf.f[la:lb], minlength=2 * g.n_pixels)
        return per_pixel.astype(np.float32).reshape(2, g.height, g.width)


@pytest.mark.parametrize("window", sorted(WINDOWS))
def test_a_subclass_that_buffers_finds_each_windows_events(window):
    stream = labelled(12, 2000)

    def make_it():
        return BufferedHistogram(window=window, **WINDOWS[window])

    for chunks in ([stream], [stream[a : a + 97] for a in range(0, len(stream), 97)]):
        frames = frames_of(make_it(), chunks)
        assert len(frames) > 5 and not make_it()._direct
        for fr, ref in zip(frames, reference("histogram", stream, frames, window), strict=True):
            np.testing.assert_array_equal(fr.data, ref)
    assert_chunk_invariant(make_it, stream, 3, apply=frames_of, splits=2)
    assert_bounded_state(make_it, lambda n: labelled(5, n), n=3000, feed=lambda f, c: f.push(c))


@pytest.mark.parametrize("kind", ["voxel", "timestamp"])
def test_fixed_count_windows_over_chunks_larger_than_the_buffer(kind):
    """Over fn windows the voxel grid and timestamp image buffer each window's events: chunks of thousands of
    events grow that buffer (4096 events at first), and later ones move its events to the front."""
    stream = labelled(13, 12_000)
    for size in (12_000, 2500):
        frames = frames_of(make(kind, "fn")(), [stream[a : a + size] for a in range(0, len(stream), size)])
        assert len(frames) > 50
        for fr, ref in zip(frames, reference(kind, stream, frames, "fn"), strict=True):
            np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize("window", ["fw", "oa", "adaptive"])
def test_voxel_grid_of_windows_longer_than_its_table_before_time_zero(window):
    """Windows over VOXEL_TABLE_MAX_US (no table: the events' bins computed one by one), at negative times."""
    s = random_stream(15, 1500, Geometry(9, 7), mean_dt_us=400)
    stream = s.replace(t=s.t - 10**6, cls=s.label)
    more = {"window_us": 100_000, **({"stride_us": 40_000} if window == "oa" else {})}
    frames = frames_of(make("voxel", window, **more)(), [stream])
    assert len(frames) > 3 and frames[0].t_start < frames[0].t_end < 0
    for fr, ref in zip(frames, reference("voxel", stream, frames, window), strict=True):
        np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize("window", sorted(WINDOWS))
def test_voxel_grids_are_whole_though_not_zero_filled(window, monkeypatch):
    """A voxel grid is zeroed bin by bin as its events reach them, and the rest when its window closes:
    every array starts as NaN here, so a bin left unwritten or added to before it was zeroed would show."""
    import evstream.framing.represent as represent

    start = represent._Grid.__init__

    def poisoned(grid, data, ready):
        data.reshape(-1)[ready:] = np.nan
        start(grid, data, ready)

    monkeypatch.setattr(represent._Grid, "__init__", poisoned)
    stream = labelled(4, 1500)
    frames = frames_of(make("voxel", window)(), [stream])
    assert len(frames) > 5
    for fr, ref in zip(frames, reference("voxel", stream, frames, window)):
        np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


def test_voxel_of_a_fixed_count_window_spans_first_to_last_event():
    """fn windows: t_start and t_end − 1 are the first and last events, as in tonic and Zhu et al."""
    g = Geometry(4, 1)
    s = EventChunk.from_arrays([10, 20, 30, 40], [0, 1, 2, 3], [0, 0, 0, 0], [1, 1, 0, 1], g)
    fr, = frames_of(build("framer", {"kind": "voxel", "window": "fn", "n_events": 4, "bins": 3}), [s])
    np.testing.assert_allclose(fr.data[:, 0, :], [[1, 1 / 3, 0, 0], [0, 2 / 3, -2 / 3, 0], [0, 0, -1 / 3, 1]],
                               atol=1e-6)


def test_time_surface_remembers_events_of_earlier_windows():
    g = Geometry(2, 1)
    s = EventChunk.from_arrays([0, 1000, 2500], [0, 1, 1], [0, 0, 0], [1, 0, 0], g, t_end=6000)
    frs = frames_of(build("framer", {"kind": "timesurface", "window_us": 1000, "tau_us": 1000}), [s])
    assert [f.t_end for f in frs] == [1000, 2000, 3000, 4000, 5000, 6000]
    assert frs[-1].data[1, 0, 0] == pytest.approx(math.exp(-6), rel=1e-6)  # the ON event at 0, 6 ms on
    assert frs[-1].data[0, 0, 1] == pytest.approx(math.exp(-3.5), rel=1e-6)
    assert frs[0].data[0, 0, 1] == 0  # the OFF event at 1000 µs is not before the first window's end


def test_a_window_parameter_the_window_does_not_have_is_refused():
    with pytest.raises(ValueError, match=r"^voxel: n_events does not apply to window 'fw' \(its parameters: "
                                         r"max_empty_frames, window_us\)$"):
        build("framer", {"kind": "voxel", "n_events": 10})
    with pytest.raises(ValueError, match="window must be one of"):
        build("framer", {"kind": "histogram", "window": "hourly"})
    with pytest.raises(ValueError, match="tau_us"):
        build("framer", {"kind": "timesurface", "tau_us": 0})
    for tau in (1, 0.5, 2.0**40):  # the range is (0, 2^40] µs: a τ at or under 1 µs is taken too
        assert build("framer", {"kind": "timesurface", "tau_us": tau}).tau_us == tau
    with pytest.raises(ValueError, match="bins"):
        build("framer", {"kind": "voxel", "bins": 0})
    with pytest.raises(ValueError, match="stride_us"):
        build("framer", {"kind": "voxel", "window": "oa", "window_us": 100, "stride_us": 200})


def test_from_toml_and_its_parameters_round_trip(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text('[framer]\nkind = "voxel"\nwindow = "adaptive"\nbins = 3\nwindow_us = 5000\nn_base = 100\n')
    pipe = Pipeline.from_toml(p)
    assert pipe.describe()["framer"] == {"kind": "voxel", "bins": 3, "window": "adaptive", "window_us": 5000,
                                         "n_base": 100, "all_events": False}
    again = build("framer", pipe.describe()["framer"])
    s = labelled(1, 800)
    assert len(frames_of(again, [s])) == len(frames_of(pipe.framer, [s]))


def test_torch_takes_the_arrays_without_a_copy():
    torch = pytest.importorskip("torch", reason="torch not installed: the zero-copy claim is checked on numpy")
    fr = frames_of(make("voxel", "fw")(), [labelled(2, 600)])[0]
    assert torch.from_numpy(fr.data).data_ptr() == fr.data.ctypes.data


# -- kernels against plain Python on random input (the hypothesis profile sets the number of examples) --
def voxel_plain(t, pix, on, t_start, t_end, bins, hw):
    ref = np.zeros(bins * hw)
    for j in range(len(t)):
        tn = (bins - 1) * (int(t[j]) - t_start) / max(1, t_end - 1 - t_start)
        for k in range(bins):
            ref[k * hw + pix[j]] += (1 if on[j] else -1) * max(0, 1 - abs(k - tn))
    return ref


def timestamp_plain(t, flat, t_start, t_end, hw):
    ref = np.zeros(2 * hw)
    for j in range(len(t)):
        ref[flat[j]] = (int(t[j]) - t_start + 1) / (t_end - t_start)
    return ref


def lazily(run, size):
    """The grid a voxel kernel `run(out, ready) -> ready` makes from a grid of NaN of which nothing is
    written (ready 0), the rest zeroed after it as a window's array is: checked to be, bit for bit, the grid
    it makes from a zero-filled one (ready = size). A bin used before it was zeroed would hold NaN."""
    lazy = np.full(size, np.nan, np.float32)
    ready = run(lazy, 0)
    assert 0 <= ready <= size
    lazy[ready:] = 0
    zeroed = np.zeros(size, np.float32)
    assert run(zeroed, size) == size
    assert lazy.view(np.uint32).tolist() == zeroed.view(np.uint32).tolist()
    return lazy


def random_events(rng, n, width, height, t0=100):
    """n time-ordered events on a width x height sensor (some pixels hit often), with classes."""
    t = np.sort(rng.integers(t0, t0 + max(1, n) * 3, n)).astype(np.int64)
    x, y = rng.integers(0, width, n).astype(np.uint16), rng.integers(0, height, n).astype(np.uint16)
    p, cls = rng.integers(0, 2, n).astype(np.uint8), rng.integers(0, 3, n).astype(np.uint8)
    return t, x, y, p, cls


@given(st.integers(0, 2**32 - 1), st.integers(0, 300), st.integers(1, 6))
def test_buffer_kernels_match_plain_python(seed, n, bins):
    rng = np.random.default_rng(seed)
    hw = 12
    t = np.sort(rng.integers(100, 100 + max(1, n) * 3, n)).astype(np.int64)
    f = rng.integers(0, 2 * hw, n).astype(np.uint32)
    t_start, t_end = 100, 100 + max(1, n) * 3 + int(rng.integers(0, 5))

    vox = lazily(lambda out, ready: voxel_kernel(t, f, t_start, t_end, bins, hw, out, ready), bins * hw)
    np.testing.assert_allclose(vox, voxel_plain(t, f % hw, f >= hw, t_start, t_end, bins, hw), atol=1e-5)

    ts = np.zeros(2 * hw, np.float32)
    timestamp_kernel(t, f, t_start, t_end, ts)
    np.testing.assert_allclose(ts, timestamp_plain(t, f, t_start, t_end, hw), rtol=1e-6)


@pytest.mark.parametrize("span_us", [1, 2, 3])  # t_end − t_start: the events at one time, over 1 µs, over 2 µs
def test_buffer_voxel_kernels_over_the_shortest_windows(span_us):
    """The random windows above span 3 µs or more: here 1 µs (t* = 0 for every event), 2 µs (t_end − 1 −
    t_start = 1: the window's two times are its first and last bins) and 3 µs, against the definition."""
    hw, bins = 4, 3
    t = np.array([100, 100, 100 + span_us - 1, 100 + span_us - 1], np.int64)
    f = np.array([0, 5, 2, 7], np.uint32)
    ref = voxel_plain(t, f % hw, f >= hw, 100, 100 + span_us, bins, hw)
    vox = lazily(lambda out, ready: voxel_kernel(t, f, 100, 100 + span_us, bins, hw, out, ready), bins * hw)
    np.testing.assert_allclose(vox, ref, atol=1e-6)
    counts = np.zeros(2 * hw, np.uint16)
    both = lazily(lambda out, ready: voxel_count_kernel(t, f, 100, 100 + span_us, bins, hw, counts.copy(), out, ready),
                  bins * hw)
    np.testing.assert_allclose(both, ref, atol=1e-6)
    if span_us == 2:
        assert ref[2 * hw + 2] == -1 and ref[2 * hw + 3] == 1 and ref[2] == 0  # the last time in the last bin


@given(st.integers(0, 2**32 - 1), st.integers(0, 300), st.integers(1, 6), st.booleans())
def test_chunk_kernels_match_plain_python(seed, n, bins, use_cls):
    """The fixed-window kernels read the chunk's fields and skip events not classed SIGNAL (`use_cls`)."""
    rng = np.random.default_rng(seed)
    width, height = 4, 3
    hw = width * height
    t, x, y, p, cls = random_events(rng, n, width, height)
    t_start, t_end = 100, 100 + max(1, n) * 3 + int(rng.integers(0, 5))
    keep = cls == 0 if use_cls else np.ones(n, bool)
    pix = y.astype(np.int64) * width + x

    vox = lazily(lambda out, ready: voxel_of_chunk(t, x, y, p, cls, use_cls, t_start, t_end, bins, width, hw, out,
                                                   ready), bins * hw)
    ref = voxel_plain(t[keep], pix[keep], p[keep] == 1, t_start, t_end, bins, hw)
    np.testing.assert_allclose(vox, ref, atol=1e-5)

    ts = np.zeros(2 * hw, np.float32)
    timestamp_of_chunk(t, x, y, p, cls, use_cls, t_start, t_end, width, hw, ts)
    flat = p.astype(np.int64) * hw + pix
    np.testing.assert_allclose(ts, timestamp_plain(t[keep], flat[keep], t_start, t_end, hw), rtol=1e-6)


def voxel_table_plain(span_us, bins, hw):
    """`voxel_table` in plain Python: the same float64 product, its float32 fraction, the signed weights."""
    scale = (bins - 1) / max(1, span_us - 1)
    lo_at, w_lo, w_hi = [], [], []
    for d in range(span_us):
        tn = d * scale
        lo = int(tn)
        w = np.float32(tn - lo)
        if lo == bins - 1:  # the last bin: as bins B − 2 (+0) and B − 1 (all of v)
            lo, w = bins - 2, np.float32(1)
        for on, v in ((0, np.float32(-1)), (1, np.float32(1))):
            lo_at.append((lo - on) * hw)  # + the flat index on·H·W + pix: the offset in bin lo
            w_lo.append(float(v - v * w))
            w_hi.append(float(v * w))
    return lo_at, w_lo, w_hi


@given(st.integers(0, 2**32 - 1), st.integers(0, 300), st.integers(2, 6), st.booleans())
def test_voxel_table_kernels_are_the_arithmetic_kernels_to_the_bit(seed, n, bins, use_cls):
    """Windows of one span go through a table of each µs's arithmetic: the table is the plain-Python one,
    and the grid it gives is the arithmetic kernels' bit for bit (and the definition's)."""
    rng = np.random.default_rng(seed)
    width, height = 4, 3
    hw = width * height
    t, x, y, p, cls = random_events(rng, n, width, height)
    t_start = 100
    span = int(t[-1]) - t_start + 1 + int(rng.integers(0, 5)) if n else int(rng.integers(1, 9))
    lo_at, w_lo, w_hi = np.empty(2 * span, np.intp), np.empty(2 * span, np.float32), np.empty(2 * span, np.float32)
    voxel_table(span, bins, hw, lo_at, w_lo, w_hi)
    assert (lo_at.tolist(), w_lo.tolist(), w_hi.tolist()) == voxel_table_plain(span, bins, hw)

    keep = cls == 0 if use_cls else np.ones(n, bool)
    pix = y.astype(np.int64) * width + x
    flat = (p.astype(np.int64) * hw + pix).astype(np.uint32)
    size = bins * hw
    arith = lazily(lambda out, ready: voxel_kernel(t[keep], flat[keep], t_start, t_start + span, bins, hw, out, ready),
                   size)
    table = lazily(lambda out, ready: voxel_table_kernel(t[keep], flat[keep], t_start, hw, lo_at, w_lo, w_hi, out,
                                                         ready), size)
    assert arith.view(np.uint32).tolist() == table.view(np.uint32).tolist()
    np.testing.assert_allclose(table, voxel_plain(t[keep], pix[keep], p[keep] == 1, t_start, t_start + span, bins,
                                                  hw), atol=1e-5)
    arith = lazily(lambda out, ready: voxel_of_chunk(t, x, y, p, cls, use_cls, t_start, t_start + span, bins, width,
                                                     hw, out, ready), size)
    table = lazily(lambda out, ready: voxel_table_of_chunk(t, x, y, p, cls, use_cls, t_start, width, hw, lo_at, w_lo,
                                                           w_hi, out, ready), size)
    assert arith.view(np.uint32).tolist() == table.view(np.uint32).tolist()

    # counting and adding in one pass: the counts of `accumulate` / `add_flat` (saturating), the same grid
    a = int(rng.integers(0, n + 1))
    start_counts = rng.choice([0, COUNT_MAX - 1, COUNT_MAX], 2 * hw).astype(np.uint16)
    ref_counts = start_counts.copy()
    ref_added = accumulate(x, y, p, cls, use_cls, a, n, ref_counts, width, hw)

    def count_of_chunk(out, ready):
        counts = start_counts.copy()
        added, ready = voxel_count_of_chunk(t, x, y, p, cls, use_cls, a, n, t_start, width, hw, lo_at, w_lo, w_hi,
                                            counts, out, ready)
        assert added == ref_added and counts.tolist() == ref_counts.tolist()
        return ready

    table = lazily(count_of_chunk, size)
    arith = lazily(lambda out, ready: voxel_table_of_chunk(t[a:], x[a:], y[a:], p[a:], cls[a:], use_cls, t_start,
                                                           width, hw, lo_at, w_lo, w_hi, out, ready), size)
    assert arith.view(np.uint32).tolist() == table.view(np.uint32).tolist()
    ref_counts = start_counts.copy()
    add_flat(ref_counts, flat[keep], 0, int(keep.sum()))

    def count_flat(out, ready):
        counts = start_counts.copy()
        ready = voxel_count_flat(t[keep], flat[keep], t_start, hw, lo_at, w_lo, w_hi, counts, out, ready)
        assert counts.tolist() == ref_counts.tolist()
        return ready

    table = lazily(count_flat, size)
    arith = lazily(lambda out, ready: voxel_table_kernel(t[keep], flat[keep], t_start, hw, lo_at, w_lo, w_hi, out,
                                                         ready), size)
    assert arith.view(np.uint32).tolist() == table.view(np.uint32).tolist()


@pytest.mark.parametrize("window", ["fw", "oa", "adaptive"])
def test_voxel_grid_without_its_table_is_the_same_to_the_bit(window, monkeypatch):
    """Windows longer than the table's limit take the arithmetic kernels: the same grids, bit for bit."""
    import evstream.framing.represent as represent

    stream = labelled(5, 2000)
    with_table = frames_of(make("voxel", window)(), [stream])
    monkeypatch.setattr(represent, "VOXEL_TABLE_MAX_US", 0)
    without = frames_of(make("voxel", window)(), [stream])
    assert len(with_table) == len(without) > 5
    for a, b in zip(with_table, without):
        assert (a.t_start, a.t_end, a.n_events) == (b.t_start, b.t_end, b.n_events)
        assert a.data.view(np.uint32).tolist() == b.data.view(np.uint32).tolist()


@given(st.integers(0, 2**32 - 1), st.integers(0, 200), st.booleans(), st.sampled_from([np.int32, np.int64]))
def test_last_time_kernel_matches_plain_python(seed, n, use_cls, dtype):
    """Newest time per pixel relative to a base, in int32 or int64; a time below the dtype's range is stored
    as its smallest value ("never")."""
    rng = np.random.default_rng(seed)
    w, hw = 5, 20
    t, x, y, p, cls = random_events(rng, n, w, 4, t0=int(rng.integers(0, 10**6)))
    never = int(np.iinfo(dtype).min)
    base = int(rng.choice([0, 10**6, 2**31 + 10**6])) if dtype is np.int32 else 0
    last = np.full(2 * hw, never, dtype)
    last_time_of(t, x, y, p, cls, use_cls, w, hw, base, last)
    ref = [never] * (2 * hw)
    for i in range(n):
        if not use_cls or cls[i] == 0:
            ref[int(p[i]) * hw + int(y[i]) * w + int(x[i])] = max(int(t[i]) - base, never)
    assert last.tolist() == ref


@given(st.integers(0, 2**32 - 1), st.integers(0, 200), st.booleans())
def test_last_time_and_counts_in_one_pass_match_plain_python(seed, n, use_cls):
    """Over fixed time and fixed-count windows the time surface counts the frame's events as it stores
    their times: the newest times of `last_time_of` and the saturating counts of `accumulate`."""
    rng = np.random.default_rng(seed)
    w, hw = 5, 20
    t, x, y, p, cls = random_events(rng, n, w, 4, t0=int(rng.integers(0, 10**6)))
    start = rng.choice([0, 7, COUNT_MAX - 1, COUNT_MAX], 2 * hw).astype(np.uint16)
    last, counts = np.full(2 * hw, -(2**31), np.int32), start.copy()
    last_time_count_of(t, x, y, p, cls, use_cls, w, hw, 1000, last, counts)
    ref_last, ref_counts = [-(2**31)] * (2 * hw), [int(c) for c in start]
    for i in range(n):
        if not use_cls or cls[i] == 0:
            f = int(p[i]) * hw + int(y[i]) * w + int(x[i])
            ref_last[f] = max(int(t[i]) - 1000, -(2**31))
            ref_counts[f] = min(ref_counts[f] + 1, COUNT_MAX)
    assert last.tolist() == ref_last and counts.tolist() == ref_counts


@given(st.integers(0, 2**32 - 1), st.integers(0, 300), st.integers(1, 6))
def test_voxel_and_counts_of_a_fixed_count_window_match_plain_python(seed, n, bins):
    rng = np.random.default_rng(seed)
    hw = 12
    t = np.sort(rng.integers(100, 100 + max(1, n) * 3, n)).astype(np.int64)
    f = rng.integers(0, 2 * hw, n).astype(np.uint32)
    t_start, t_end = 100, 100 + max(1, n) * 3 + int(rng.integers(0, 5))
    start = rng.choice([0, COUNT_MAX - 1, COUNT_MAX], 2 * hw).astype(np.uint16)
    ref_counts = [int(c) for c in start]
    for v in f:
        ref_counts[v] = min(ref_counts[v] + 1, COUNT_MAX)

    def run(out, ready):
        counts = start.copy()
        ready = voxel_count_kernel(t, f, t_start, t_end, bins, hw, counts, out, ready)
        assert counts.tolist() == ref_counts
        return ready

    vox = lazily(run, bins * hw)
    np.testing.assert_allclose(vox, voxel_plain(t, f % hw, f >= hw, t_start, t_end, bins, hw), atol=1e-5)
    same = lazily(lambda out, ready: voxel_kernel(t, f, t_start, t_end, bins, hw, out, ready), bins * hw)
    assert vox.view(np.uint32).tolist() == same.view(np.uint32).tolist()


def slide_plain(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail):
    """`slide_kernel` in plain Python: event by event from i until one at or past `end`."""
    counts, buf_t, buf_f = counts.tolist(), buf_t.tolist(), buf_f.tolist()
    added, k = 0, i
    while k < len(t) and t[k] < end:
        if not use_cls or cls[k] == 0:
            f = int(p[k]) * hw + int(y[k]) * width + int(x[k])
            counts[f] = min(counts[f] + 1, COUNT_MAX)
            added += 1
            if t[k] >= keep_t:
                buf_t[tail], buf_f[tail] = int(t[k]), f
                tail += 1
        k += 1
    return k, tail, added, counts, buf_t, buf_f


@given(st.integers(0, 2**32 - 1), st.integers(0, 300), st.integers(2, 6), st.booleans())
def test_an_overlapping_windows_part_of_a_chunk_in_one_call_matches_plain_python(seed, n, bins, use_cls):
    """`slide_kernel` (an overlapping window's counts and buffer, up to its end), `last_time_take` (the same,
    and the newest times) and `voxel_take` (the same, and each event into the window's voxel grid): the
    plain-Python counts, buffer and newest times, and the grid the table kernel makes of the same events,
    bit for bit."""
    rng = np.random.default_rng(seed)
    width, height = 4, 3
    hw = width * height
    t, x, y, p, cls = random_events(rng, n, width, height)
    i = int(rng.integers(0, n + 1))
    t_start = int(t[i]) - int(rng.integers(0, 4)) if i < n else 100
    end = t_start + int(rng.integers(1, 4 * max(1, n)))
    keep_t = t_start + int(rng.integers(0, end - t_start + 1))
    if i < n - 1 and rng.random() < 0.5:  # an event at the end, or at keep_t (events at both stay out / in)
        end = int(t[rng.integers(i + 1, n)])
        keep_t = int(t[rng.integers(i, n)]) if t[i] < end else t_start
        keep_t = min(keep_t, end)
    start_counts = rng.choice([0, 1, COUNT_MAX - 1, COUNT_MAX], 2 * hw).astype(np.uint16)
    tail = int(rng.integers(0, 5))
    buf_t0 = rng.integers(0, 99, tail + n + 3).astype(np.int64)
    buf_f0 = rng.integers(0, 99, tail + n + 3).astype(np.uint32)
    want = slide_plain(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, start_counts, buf_t0, buf_f0, tail)
    stop, new_tail = want[0], want[1]

    counts, buf_t, buf_f = start_counts.copy(), buf_t0.copy(), buf_f0.copy()
    got = slide_kernel(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail)
    assert (*got, counts.tolist(), buf_t.tolist(), buf_f.tolist()) == want

    # the time surface's: the same, and each counted event its pixel's newest time (t − base, floored)
    dtype = np.int32 if seed % 2 else np.int64
    floor = int(np.iinfo(dtype).min)
    base = int(rng.integers(-50, 150)) if rng.random() < 0.8 else 2**40  # far ahead: every time floored (int32)
    last0 = rng.integers(-99, 99, 2 * hw).astype(dtype)
    want_last = last0.tolist()
    for k in range(i, stop):
        if not use_cls or cls[k] == 0:
            want_last[int(p[k]) * hw + int(y[k]) * width + int(x[k])] = max(int(t[k]) - base, floor)
    counts, buf_t, buf_f, last = start_counts.copy(), buf_t0.copy(), buf_f0.copy(), last0.copy()
    got = last_time_take(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail, base, last)
    assert (*got, counts.tolist(), buf_t.tolist(), buf_f.tolist()) == want
    assert last.tolist() == want_last

    span = end - t_start
    lo_at, w_lo, w_hi = np.empty(2 * span, np.intp), np.empty(2 * span, np.float32), np.empty(2 * span, np.float32)
    voxel_table(span, bins, hw, lo_at, w_lo, w_hi)

    def take(out, ready):
        counts, buf_t, buf_f = start_counts.copy(), buf_t0.copy(), buf_f0.copy()
        *got, ready = voxel_take(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail,
                                 t_start, lo_at, w_lo, w_hi, out, ready)
        assert (*got, counts.tolist(), buf_t.tolist(), buf_f.tolist()) == want
        return ready

    size = bins * hw
    grid = lazily(take, size)
    same = lazily(lambda out, ready: voxel_table_of_chunk(t[i:stop], x[i:stop], y[i:stop], p[i:stop], cls[i:stop],
                                                          use_cls, t_start, width, hw, lo_at, w_lo, w_hi, out, ready),
                  size)
    assert grid.view(np.uint32).tolist() == same.view(np.uint32).tolist()
    keep = (cls[i:stop] == 0) if use_cls else np.ones(stop - i, bool)
    pix = (y[i:stop].astype(np.int64) * width + x[i:stop])[keep]
    np.testing.assert_allclose(grid, voxel_plain(t[i:stop][keep], pix, p[i:stop][keep] == 1, t_start, end, bins, hw),
                               atol=1e-5)

    # a buffer without room for the events at or after keep_t (as many as may count): each does nothing and
    # says how much room it needs; with exactly that room, it runs
    need = sum(keep_t <= t[k] < end for k in range(i, n))
    if need:
        short = tail + need - 1
        counts, buf_t, buf_f, last, out = (start_counts.copy(), buf_t0[:short].copy(), buf_f0[:short].copy(),
                                           last0.copy(), np.full(size, np.nan, np.float32))
        before = [a.tolist() for a in (counts, buf_t, buf_f, last)]
        assert slide_kernel(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f,
                            tail) == (stop, -1, need)
        assert last_time_take(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail, base,
                              last) == (stop, -1, need)
        assert voxel_take(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail, t_start,
                          lo_at, w_lo, w_hi, out, 0) == (stop, -1, need, 0)
        assert [a.tolist() for a in (counts, buf_t, buf_f, last)] == before and np.isnan(out).all()
        counts, buf_t, buf_f = start_counts.copy(), buf_t0[: short + 1].copy(), buf_f0[: short + 1].copy()
        got = slide_kernel(t, x, y, p, cls, use_cls, i, end, keep_t, width, hw, counts, buf_t, buf_f, tail)
        assert (*got, counts.tolist()) == (*want[:3], want[3])
    assert new_tail - tail <= stop - i


@given(st.integers(0, 2**32 - 1), st.integers(0, 200), st.booleans(), st.integers(1, 40), st.integers(1, 400))
def test_fn_scan_finds_the_windows_of_plain_python(seed, n, use_cls, n_target, max_window):
    """Fixed-count windows whose representation counts their events: the framer only finds the windows
    (`fn_scan`): fill a frame of n_target from index a, or time out max_window after its first event; the
    frame empty at a, or already holding some events (the first of them at first_t)."""
    rng = np.random.default_rng(seed)
    t, _, _, _, cls = random_events(rng, n, 4, 3)
    a = int(rng.integers(0, n + 1))
    have0 = int(rng.integers(0, n_target)) if rng.random() < 0.5 else 0
    first0 = int(t[a]) - int(rng.integers(0, max_window + 5)) if have0 and a < n else 0
    last0 = first0
    i, have, first, last, status = fn_scan(t, cls, use_cls, a, have0, n_target, first0, last0, max_window)
    j, have_want, first_want, last_want, want = a, have0, first0, last0, FN_DONE
    while j < n:
        if have_want and t[j] >= first_want + max_window:
            want = FN_TIMEOUT
            break
        if not use_cls or cls[j] == 0:
            if not have_want:
                first_want = int(t[j])
            have_want += 1
            last_want = int(t[j])
            if have_want == n_target:
                j += 1
                want = FN_FULL
                break
        j += 1
    assert (i, have, status, first, last) == (j, have_want, want, first_want, last_want)


@given(st.integers(0, 2**32 - 1), st.integers(0, 2**33))
def test_rebase_matches_plain_python(seed, delta):
    rng = np.random.default_rng(seed)
    last = rng.integers(-(2**31), 2**31, 50).astype(np.int32)
    ref = [max(int(v) - delta, -(2**31)) for v in last]
    rebase(last, delta)
    assert last.tolist() == ref


@given(st.integers(0, 2**32 - 1), st.sampled_from([np.int32, np.int64]), st.floats(0.5, 2.0**40))
def test_surface_exponent_and_surface_match_plain_python(seed, dtype, tau):
    """The exponent −(t_now − t_last)/τ is rounded to float32 from the exact µs difference, floored at
    EXP_FLOOR below EXP_MIN_NORMAL; the surface is its float32 exp, 0 for "never" (NEVER_US for int64 times,
    the int32 minimum), and never a subnormal number (their exp is slow)."""
    rng = np.random.default_rng(seed)
    never = NEVER_US if dtype is np.int64 else int(np.iinfo(np.int32).min)
    t_now = int(rng.integers(0, 2**30))
    last = rng.integers(-(2**31) + 1, t_now + 1, 40).astype(dtype)
    last[rng.random(40) < 0.3] = never
    if dtype is np.int32 and tau * 128 > 2**31:
        tau = 2**31 / 128  # the framer keeps int32 times only for these τ ("never" must mean 0)
    last[:4] = [t_now - round(k * tau) for k in (86.9, 87.5, 95.0, 103.5)]  # around and in the subnormal range
    ex = np.zeros(40, np.float32)
    surface_exponent(last, t_now, 1.0 / tau, ex)
    exact = [float(np.float32((int(v) - t_now) * (1.0 / tau))) for v in last]
    ref = [e if e >= np.float32(EXP_MIN_NORMAL) else EXP_FLOOR for e in exact]
    assert ex.tolist() == [float(np.float32(r)) for r in ref]
    sf = np.zeros(40, np.float32)
    surface(last, t_now, tau, sf)
    plain = [0.0 if v == never else math.exp(-(t_now - int(v)) / tau) for v in last]
    # float32 exponent (relative error 2^-24 of up to 110) then float32 exp: within 1e-5 relative; where the
    # float32 exponent is under EXP_MIN_NORMAL the surface is 0, the exact one up to exp(EXP_MIN_NORMAL)
    np.testing.assert_allclose(sf, plain, rtol=1e-5, atol=math.exp(EXP_MIN_NORMAL) * (1 + 1e-5))
    assert all(sf[last == never] == 0)
    assert not np.any((sf > 0) & (sf < np.finfo(np.float32).tiny))


# -- the invariant kit ------------------------------------------------------------------------------
@settings(max_examples=max(1, settings().max_examples // 4))  # each example runs 20 framers: a quarter of the profile
@given(st.integers(0, 2**32 - 1), st.sampled_from(REPRESENTATIONS), st.sampled_from(sorted(WINDOWS)))
def test_chunk_invariant_and_causal(seed, kind, window):
    stream = labelled(seed, 700)
    assert_chunk_invariant(make(kind, window), stream, seed, apply=frames_of, splits=2, one_event=False)
    # the kit's other future carries no classes, so the causal check counts every event
    assert_framer_causal(make(kind, window), random_stream(seed, 700, Geometry(9, 7), mean_dt_us=40), seed)


@pytest.mark.parametrize("kind", REPRESENTATIONS)
def test_one_event_chunks(kind):
    stream = labelled(11, 400)
    for window in WINDOWS:
        assert_chunk_invariant(make(kind, window), stream, 1, apply=frames_of, splits=1)


@pytest.mark.parametrize("window", sorted(WINDOWS))
def test_state_is_bounded(window):
    for kind in ("timesurface", "voxel"):
        assert_bounded_state(make(kind, window), lambda n: labelled(5, n), n=3000, feed=lambda f, c: f.push(c))


def noise_between(seed, n):
    """`labelled`, but only the first 3 ms of every 24 ms hold counted events: the windows between hold
    noise alone."""
    s = labelled(seed, n)
    return s.replace(cls=np.where(s.t % 24_000 >= 3000, 1, s.cls).astype(np.uint8))


def test_time_surface_over_fn_windows_a_chunk_closes_before_its_counted_events():
    """fn windows timing out (max_window_us) in the noise between the counted stretches: a chunk then closes a
    window that holds none of its counted events, and none of them may reach that window's surface."""
    stream = noise_between(9, 3000)
    for size in (len(stream), 97, 31):
        frames = frames_of(make("timesurface", "fn", max_window_us=2000)(), [stream[a : a + size]
                                                                            for a in range(0, len(stream), size)])
        assert len(frames) >= 8 and sum(fr.n_events < 120 for fr in frames) >= 4  # some timed out
        for fr, ref in zip(frames, reference("timesurface", stream, frames, "fn"), strict=True):
            np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


def test_time_surface_over_an_fn_window_a_chunk_closes_after_noise_and_one_counted_event():
    """The second chunk starts with noise, then the one counted event that fills the window: the surface at the
    window's end holds that event (the chunk is applied up to it, not up to its first position)."""
    g = Geometry(4, 1)
    s = EventChunk.from_arrays([0, 10, 20, 30, 40], [0, 1, 2, 3, 1], [0] * 5, [1, 1, 0, 1, 0], g)
    s = s.replace(cls=np.array([0, 1, 0, 0, 0], np.uint8))
    for chunks in ([s], [s[:1], s[1:]]):
        frames = frames_of(make("timesurface", "fn", n_events=2)(), chunks)
        assert [(fr.t_start, fr.t_end, fr.n_events) for fr in frames] == [(0, 21, 2), (30, 41, 2)]
        assert frames[0].data[0, 0, 2] > 0
        for fr, ref in zip(frames, reference("timesurface", s, frames, "fn"), strict=True):
            np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


def test_time_surface_over_fn_windows_timing_out_between_chunks_without_classes():
    """Without classes every event counts: an fn window that times out in a pause is closed by the next chunk
    before its first event, and that event (after the window's end) must not reach the window's surface."""
    s = noise_between(9, 6000)
    s = s[s.cls == 0].replace(cls=None, label=None)  # stretches of 3 ms, 21 ms apart
    starts = [0, *np.flatnonzero(np.diff(s.t) > 10_000) + 1, len(s)]
    chunks = [s[a:b].replace(t_end=int(s.t[b - 1])) for a, b in zip(starts, starts[1:])]
    assert len(chunks) >= 8
    framer, frames, before = make("timesurface", "fn", max_window_us=2000)(), [], 0
    for c in chunks:
        out = framer.push(c)
        before += sum(fr.t_end <= c.t[0] for fr in out)  # closed by this chunk, before its first event
        frames += out
    frames += framer.finish()
    assert before >= 6 and sum(fr.n_events < 120 for fr in frames) >= 6  # timed out
    for fr, ref in zip(frames, reference("timesurface", s, frames, "fn"), strict=True):
        np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


def test_time_surface_counts_fixed_time_windows_of_one_event():
    """Over fixed time windows the time surface counts the frames' events itself (the windowing framer leaves
    them to it): a window holding a single counted event (after noise, or alone) has that event's count."""
    g = Geometry(4, 2)
    t = [0, 5, 1000, 1010, 2500, 4200, 4300, 4400, 7000]
    x, y, p = [0, 1, 2, 3, 0, 1, 2, 3, 0], [0, 1, 0, 1, 0, 1, 0, 1, 0], [1, 0, 1, 1, 0, 1, 0, 0, 1]
    s = EventChunk.from_arrays(t, x, y, p, g)
    s = s.replace(cls=np.array([0, 0, 1, 0, 0, 1, 1, 0, 0], np.uint8))
    for chunks in ([s], [s[:4], s[4:]]):
        frames = frames_of(make("timesurface", "fw", window_us=1000, max_empty_frames=5)(), chunks)
        plain = frames_of(build("framer", {"kind": "fw", "window_us": 1000, "max_empty_frames": 5}), chunks)
        assert [fr.n_events for fr in frames] == [fr.n_events for fr in plain] == [2, 1, 1, 0, 1, 0, 0, 1]
        assert all(np.array_equal(f.counts, q.counts) for f, q in zip(frames, plain, strict=True))


def test_time_surface_over_fixed_time_windows_of_noise_alone():
    """A fixed time window holding only events the stages classed as noise is an empty frame whose counts are
    the shared read-only zeros: nothing may be counted into them (compiled, numba refuses the write: 48140dd)."""
    stream = noise_between(6, 3000)
    frames = frames_of(make("timesurface", "fw")(), [stream])
    assert sum(fr.n_events == 0 and np.any(fr.data > 0) for fr in frames) >= 5  # noise windows, after counted events
    for fr, ref in zip(frames, reference("timesurface", stream, frames, "fw"), strict=True):
        np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize("window", ["fw", "oa", "adaptive"])
def test_windows_of_noise_alone_leave_no_state(window):
    """A window that adds events as they are counted has an array from its first event, counted or not;
    one the framer passes without emitting it (noise alone, no empty frames) is dropped."""
    for kind in ("timestamp", "voxel"):
        make_it = make(kind, window, max_empty_frames=0)
        stream = noise_between(6, 3000)
        frames = frames_of(make_it(), [stream])
        assert len(frames) >= 5
        for fr, ref in zip(frames, reference(kind, stream, frames, window), strict=True):
            np.testing.assert_allclose(fr.data, ref, rtol=1e-5, atol=1e-6)
        assert_bounded_state(make_it, lambda n: noise_between(6, n), n=3000, feed=lambda f, c: f.push(c))


@pytest.mark.parametrize("kind", REPRESENTATIONS)
def test_cameras_are_independent(kind):
    streams = [labelled(k, 500) for k in range(3)]
    assert_cameras_independent(make(kind, "adaptive"), streams, 2, framer=True)


@pytest.mark.parametrize("window", sorted(WINDOWS))
def test_time_surface_under_many_splits(window):
    for seed in range(8):
        stream = labelled(100 + seed, 600)
        assert_chunk_invariant(make("timesurface", window), stream, seed, apply=frames_of, splits=3)
        assert_chunk_invariant(make("timesurface", window, all_events=True), stream, seed, apply=frames_of,
                               splits=2, one_event=False)


@pytest.mark.parametrize("window", sorted(WINDOWS))
def test_time_surface_of_a_pixel_2_31_us_old_with_a_long_tau(window):
    """int32 newest times (rebased) only while τ·128 <= 2^31 µs: with τ = 3e7 µs a pixel 2^31 µs old is
    exp(−71.6), about 1e-31, a normal float32, not "never" (0)."""
    rng = np.random.default_rng(5)
    g = Geometry(4, 3)
    t = np.sort(np.concatenate([rng.integers(0, 10**6, 40), rng.integers(2**31 + 5 * 10**6, 2**31 + 6 * 10**6, 40)]))
    stream = EventChunk.from_arrays(t, rng.integers(0, 4, len(t)), rng.integers(0, 3, len(t)),
                                    rng.integers(0, 2, len(t)), g)
    params = {"fw": {"window_us": 2**27, "max_empty_frames": 0}, "fn": {"n_events": 20},
              "oa": {"window_us": 2**27, "max_empty_frames": 0},
              "adaptive": {"window_us": 2**27, "n_base": 30, "max_empty_frames": 0}}[window]
    spec = {"kind": "timesurface", "window": window, **params, "tau_us": 3e7}
    frames = frames_of(build("framer", spec), [stream])
    late = [fr for fr in frames if fr.t_start > 2**31]
    assert late and all(np.any((fr.data > 0) & (fr.data < 1e-30)) for fr in late)
    for fr, ref in zip(frames, reference("timesurface", stream, frames, window, tau_us=3e7), strict=True):
        np.testing.assert_allclose(fr.data, ref, rtol=1e-5, atol=math.exp(EXP_MIN_NORMAL) * (1 + 1e-5))


def test_time_surface_windows_before_a_chunk_spanning_2_31_us():
    """Fixed time windows a chunk closes before its first event are made before any of its events is applied:
    the int32 base must not move to the chunk's last time first (older pixels would become "never" there,
    though their surface at those windows' ends is still well above 0)."""
    g = Geometry(3, 2)
    t = np.array([0, 5, 10, 10**9, 15 * 10**8, 23 * 10**8], np.int64)
    stream = EventChunk.from_arrays(t, np.array([0, 1, 2, 0, 1, 2]), np.zeros(6, int), np.array([1, 0, 1, 1, 1, 0]), g)
    spec = {"kind": "timesurface", "window": "fw", "window_us": 2**27, "tau_us": 2.0**24}
    framer = build("framer", spec)
    # the first chunk's watermark is its last event (a slice's would be the next event, 10^9 µs, and it would
    # close those windows itself): the second chunk closes them, before its first event
    assert framer.push(stream[:3].replace(t_end=10)) == []
    frames = frames_of(framer, [stream[3:]])
    assert len(frames) > 7 and frames[1].data.max() > 1e-7 and frames[6].t_end < 10**9
    for fr, ref in zip(frames, reference("timesurface", stream, frames, "fw", tau_us=2.0**24), strict=True):
        np.testing.assert_allclose(fr.data, ref, rtol=1e-5, atol=math.exp(EXP_MIN_NORMAL) * (1 + 1e-5))


@pytest.mark.parametrize("window", sorted(WINDOWS))  # each moves the base its own way (oa, adaptive: `take`)
@pytest.mark.parametrize("tau_us", [3e5, 1e8])  # int32 newest times (rebased), and int64 ones for long τ
def test_time_surface_over_hours_matches_the_definition(tau_us, window):
    """Times past 2^30 µs move the int32 base; pixels then older than 2^31 µs become "never", which is
    exact: their surface is exp(<= −128) = 0 in float32 anyway."""
    rng = np.random.default_rng(4)
    g = Geometry(5, 4)
    t = np.sort(np.concatenate([rng.integers(k * 2**30, k * 2**30 + 10**6, 60) for k in (0, 1, 3, 7)]))
    stream = EventChunk.from_arrays(t, rng.integers(0, 5, len(t)), rng.integers(0, 4, len(t)),
                                    rng.integers(0, 2, len(t)), g)
    params = {"fw": {"window_us": 2**27, "max_empty_frames": 2}, "fn": {"n_events": 20},
              "oa": {"window_us": 2**27, "max_empty_frames": 2},
              "adaptive": {"window_us": 2**27, "n_base": 30, "max_empty_frames": 2}}[window]
    spec = {"kind": "timesurface", "window": window, **params, "tau_us": tau_us}
    frames = frames_of(build("framer", spec), [stream])
    assert frames[-1].t_end > 7 * 2**30 and len(frames) > 8
    for fr, ref in zip(frames, reference("timesurface", stream, frames, window, tau_us=tau_us)):
        np.testing.assert_allclose(fr.data, ref, rtol=2e-6, atol=1e-30)
    assert_chunk_invariant(lambda: build("framer", spec), stream, 4, apply=frames_of, splits=3)
