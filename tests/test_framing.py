"""Framers: equal to plain-Python references on random streams, chunk-invariant, causal, bounded,
closing frames on the watermark; parameter validation; the paper's Eq. 5 on a hand-made stream."""

from bisect import bisect_left

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream.events import EventChunk, EventError, Frame, Geometry, NoiseClass, concat
from evstream.framing import AdaptiveOverlap, FixedCount, FixedWindow, OverlapAccumulation
from evstream.framing.fixed import FN_FULL, FN_TIMEOUT, fn_run, fn_scan
from evstream.pipeline import Pipeline, build, describe, kinds
from evstream.testing import (
    assert_bounded_state,
    assert_chunk_invariant,
    assert_framer_causal,
    assert_frames_equal,
    frames_of,
    one_event_chunks,
    random_bounds,
    random_stream,
    split,
)

G = Geometry(24, 18)
seeds = st.integers(0, 2**32 - 1)


# -- plain-Python references: the definitions, written as directly as possible ------------------------
def _counted(stream: EventChunk, all_events: bool) -> list[bool]:
    if all_events or stream.cls is None:
        return [True] * len(stream)
    return [int(c) == NoiseClass.SIGNAL for c in stream.cls]


def _counts(stream: EventChunk, members: list[int]) -> np.ndarray:
    c = np.zeros((2, stream.geometry.height, stream.geometry.width), np.int64)
    for i in members:
        c[int(stream.p[i]), int(stream.y[i]), int(stream.x[i])] += 1
    return np.minimum(c, 65535).astype(np.uint16)  # counts saturate


def ref_time_frames(stream, window_us, next_start, *, all_events=False, max_empty_frames=1000):
    """Frames [s, s + window) from the first event on; s advances by next_start(s, n). A frame whose
    end the final watermark reached is emitted (an empty one only while fewer than max_empty_frames
    empty frames came in a row); after that, the open frames that hold events."""
    t = [int(v) for v in stream.t]
    if not t:
        return []
    counted = _counted(stream, all_events)
    w_final = max(int(stream.t_end), t[-1])
    frames, run, s = [], 0, t[0]
    while True:
        e = s + window_us
        members = [i for i in range(bisect_left(t, s), bisect_left(t, e)) if counted[i]]
        if e <= w_final:
            if members or run < max_empty_frames:
                frames.append(Frame(s, e, len(members), _counts(stream, members)))
            run = 0 if members else run + 1
        elif members:
            frames.append(Frame(s, e, len(members), _counts(stream, members)))
        else:
            return frames
        s = next_start(s, len(members))


def ref_fw(stream, window_us, **kw):
    return ref_time_frames(stream, window_us, lambda s, n: s + window_us, **kw)


def ref_oa(stream, window_us, stride_us, **kw):
    return ref_time_frames(stream, window_us, lambda s, n: s + stride_us, **kw)


def ref_adaptive(stream, window_us, n_base, k_us_per_event, overlap_max_us, overlap_init_us=0, **kw):
    overlap = [overlap_init_us]

    def next_start(s, n):  # Eq. 5: O_{i+1} = clip(O_i + k (n_i - N_base), 0, O_max)
        o = overlap[0] + round(k_us_per_event * (n - n_base))
        overlap[0] = min(max(o, 0), overlap_max_us)
        return s + window_us - overlap[0]

    return ref_time_frames(stream, window_us, next_start, **kw)


def ref_fn(stream, n_events, max_window_us=None, *, all_events=False):
    """Counted events in stream order, n_events a frame; a frame also closes once an event (or the final
    watermark) reaches max_window_us after its first event."""
    counted = _counted(stream, all_events)
    t = [int(v) for v in stream.t]
    limit = float("inf") if max_window_us is None else max_window_us
    frames, cur = [], []
    for i in range(len(t)):
        if cur and t[i] >= t[cur[0]] + limit:
            frames.append(Frame(t[cur[0]], t[cur[0]] + max_window_us, len(cur), _counts(stream, cur)))
            cur = []
        if counted[i]:
            cur.append(i)
            if len(cur) == n_events:
                frames.append(Frame(t[cur[0]], t[i] + 1, len(cur), _counts(stream, cur)))
                cur = []
    if cur and max(int(stream.t_end), t[-1]) >= t[cur[0]] + limit:
        frames.append(Frame(t[cur[0]], t[cur[0]] + max_window_us, len(cur), _counts(stream, cur)))
        cur = []
    if cur:
        frames.append(Frame(t[cur[0]], t[cur[-1]] + 1, len(cur), _counts(stream, cur)))
    return frames


# -- random streams with quiet stretches, classes and a watermark past the last event --------------
def stream_for(rng: np.random.Generator, n: int) -> EventChunk:
    s = random_stream(rng, n, G, mean_dt_us=float(rng.choice([5.0, 50.0])))
    if n:
        gaps = np.where(rng.random(n) < 0.01, rng.integers(1, 20_000, n), 0)  # quiet stretches
        s = s.replace(t=s.t + np.cumsum(gaps), t_end=None)
        s = EventChunk(s.t, s.x, s.y, s.p, G, label=s.label)
        if rng.random() < 0.6:  # classified by a stage: frames count the SIGNAL events only
            s = s.replace(cls=s.label.copy())
        if rng.random() < 0.5:  # the source promises quiet after the last event
            s = s.replace(t_end=int(s.t[-1]) + int(rng.integers(0, 30_000)))
    return s


def random_framer(rng: np.random.Generator):
    """(a fresh-framer factory, the matching reference) with random parameters."""
    kind = rng.choice(["fw", "fn", "oa", "adaptive"])
    common = {"all_events": bool(rng.random() < 0.3)}
    if kind != "fn":
        common["max_empty_frames"] = int(rng.choice([0, 1, 3, 1000]))
    if kind == "fw":
        p = dict(window_us=int(rng.integers(1, 3000)), **common)
        return (lambda: FixedWindow(**p)), (lambda s: ref_fw(s, **p))
    if kind == "fn":
        p = dict(n_events=int(rng.integers(1, 200)), all_events=common["all_events"],
                 max_window_us=None if rng.random() < 0.3 else int(rng.integers(1, 5000)))
        return (lambda: FixedCount(**p)), (lambda s: ref_fn(s, **p))
    if kind == "oa":
        w = int(rng.integers(1, 3000))
        p = dict(window_us=w, stride_us=int(rng.integers(1, w + 1)), **common)
        return (lambda: OverlapAccumulation(**p)), (lambda s: ref_oa(s, **p))
    w = int(rng.integers(2, 3000))
    o_max = int(rng.integers(0, w))
    p = dict(window_us=w, n_base=int(rng.integers(0, 60)), k_us_per_event=float(rng.choice([0.3, 1, 7.5, 40])),
             overlap_max_us=o_max, overlap_init_us=int(rng.integers(0, o_max + 1)), **common)
    return (lambda: AdaptiveOverlap(**p)), (lambda s: ref_adaptive(s, **p))


@given(seeds)
def test_framers_equal_their_references_for_any_chunking(seed):
    rng = np.random.default_rng(seed)
    make, ref = random_framer(rng)
    stream = stream_for(rng, int(rng.integers(0, 600)))
    expected = ref(stream)
    assert_frames_equal(frames_of(make(), split(stream, random_bounds(rng, len(stream)))), expected,
                        f"{make().params()} vs reference")


@given(seeds)
def test_framers_are_chunk_invariant_and_causal(seed):
    rng = np.random.default_rng(seed)
    make, _ = random_framer(rng)
    stream = stream_for(rng, int(rng.integers(2, 400)))
    assert_chunk_invariant(make, stream, rng, apply=frames_of, splits=2)
    # the kit's check swaps the future for unclassified events, so give it an unclassified stream
    assert_framer_causal(make, stream.replace(cls=None), rng)
    # with classes: what a prefix emits (its watermark its last event) is a prefix of the whole output
    m = int(rng.integers(1, len(stream)))
    early = make().push(stream[:m].replace(t_end=int(stream.t[m - 1])))
    assert_frames_equal(early, frames_of(make(), [stream])[: len(early)], f"prefix of {m} events")


@pytest.mark.parametrize("make", [
    lambda: FixedWindow(window_us=500),
    lambda: FixedCount(n_events=40),
    lambda: OverlapAccumulation(window_us=1000, stride_us=300),
    lambda: AdaptiveOverlap(window_us=1000, n_base=20, overlap_max_us=700),
], ids=["fw", "fn", "oa", "adaptive"])
def test_framer_state_does_not_grow_with_the_stream(make):
    assert_bounded_state(make, lambda n: random_stream(7, n, G), feed=lambda f, c: f.push(c), n=3000)


@pytest.mark.parametrize("make", [
    lambda: FixedWindow(window_us=1000),
    lambda: OverlapAccumulation(window_us=1000, stride_us=500),
    lambda: AdaptiveOverlap(window_us=1000, n_base=5, overlap_max_us=500),
], ids=["fw", "oa", "adaptive"])
def test_quiet_period_frames_come_out_on_the_watermark(make):
    """An empty chunk whose watermark advances closes the frames that end before it, events or not."""
    f = make()
    s = random_stream(2, 50, G, mean_dt_us=10)
    assert all(fr.t_end <= s.t_end for fr in f.push(s))
    t_last = int(s.t[-1])
    frames = f.push(EventChunk.empty(G, t_end=t_last + 10_000))
    assert frames and frames[-1].t_end <= t_last + 10_000 < frames[-1].t_end + 1000
    assert frames[0].n_events > 0 and frames[-1].n_events == 0
    assert frames[-1].counts.sum() == 0
    assert f.finish() == []  # nothing open holds events


def test_fn_times_out_on_the_watermark_and_closes_on_count():
    f = FixedCount(n_events=10, max_window_us=5000)
    s = EventChunk.from_arrays(np.arange(25) * 100, np.arange(25) % 5, np.zeros(25), np.ones(25), G)
    frames = f.push(s)
    assert [(fr.t_start, fr.t_end, fr.n_events) for fr in frames] == [(0, 901, 10), (1000, 1901, 10)]
    assert f.push(EventChunk.empty(G, t_end=6999)) == []
    (late,) = f.push(EventChunk.empty(G, t_end=7000))  # 5 ms after its first event at 2000 µs
    assert (late.t_start, late.t_end, late.n_events) == (2000, 7000, 5)
    assert late.counts[1, 0, :5].tolist() == [1] * 5 and late.counts[0].sum() == 0


def test_adaptive_follows_eq5_on_a_hand_made_stream():
    """Δt 1000 µs, N_base 10, k 10 µs/event, O_max 500; 30 events in [0, 300), 40 in [1000, 1400).
    Slice 0 [0, 1000) holds 30: O_1 = 0 + 10·(30 − 10) = 200, s_1 = 0 + 1000 − 200 = 800.
    Slice 1 [800, 1800) holds 40: O_2 = min(200 + 300, 500) = 500, s_2 = 1300.
    Slice 2 [1300, 2300) holds 10: O_3 = 500 + 0 = 500, s_3 = 1800.
    Slice 3 [1800, 2800) holds 0: O_4 = 500 − 100 = 400, s_4 = 2400 (still open at watermark 3000)."""
    t = np.concatenate([np.arange(0, 300, 10), np.arange(1000, 1400, 10)])
    s = EventChunk.from_arrays(t, np.zeros(70), np.zeros(70), np.ones(70), G, t_end=3000)
    f = AdaptiveOverlap(window_us=1000, n_base=10, k_us_per_event=10, overlap_max_us=500)
    frames = f.push(s)
    assert [(fr.t_start, fr.t_end, fr.n_events) for fr in frames] == [
        (0, 1000, 30), (800, 1800, 40), (1300, 2300, 10), (1800, 2800, 0)]
    assert (f.start, f.overlap_us) == (2400, 400)
    assert frames[2].counts[1, 0, 0] == 10 and frames[1].counts[1, 0, 0] == 40


def test_frames_count_signal_by_default_and_all_events_on_request():
    s = random_stream(5, 400, G)
    s = s.replace(cls=s.label.copy())
    signal = int((s.label == NoiseClass.SIGNAL).sum())
    for make in (FixedWindow, OverlapAccumulation, AdaptiveOverlap, FixedCount):
        assert sum(fr.n_events for fr in frames_of(make(), [s])) >= signal > 0
    fw = frames_of(FixedWindow(window_us=1000), [s])
    fw_all = frames_of(FixedWindow(window_us=1000, all_events=True), [s])
    assert sum(fr.n_events for fr in fw) == signal
    assert sum(fr.n_events for fr in fw_all) == len(s)
    for fr in fw + fw_all:
        assert fr.counts.sum() == fr.n_events and fr.counts.shape == (2, G.height, G.width)


def test_a_first_window_of_noise_alone_is_an_empty_frame():
    """The first frame can be empty when every event in it is classed noise: it is emitted as one (the
    count of empty frames in a row starts at 0), then the next window's signal event."""
    noise = NoiseClass.BACKGROUND
    s = EventChunk.from_arrays([0, 500, 1500], [1, 2, 3], [1, 2, 3], [1, 0, 1], G, cls_=[noise, noise, 0])
    frames = frames_of(FixedWindow(window_us=1000, max_empty_frames=1), [s])
    assert [(fr.t_start, fr.n_events) for fr in frames] == [(0, 0), (1000, 1)]


def test_many_empty_frames_are_bounded_and_the_grid_is_kept():
    s = EventChunk.from_arrays([0, 10**9], [1, 2], [1, 2], [1, 0], G)  # 1000 s of nothing between
    frames = frames_of(FixedWindow(window_us=1000, max_empty_frames=5), [s])
    assert len(frames) == 1 + 5 + 1
    assert [fr.n_events for fr in frames] == [1, 0, 0, 0, 0, 0, 1]
    assert frames[-1].t_start == 10**9 and frames[-1].t_start % 1000 == 0
    adaptive = frames_of(AdaptiveOverlap(window_us=1000, n_base=1000, overlap_max_us=900,
                                         overlap_init_us=900, max_empty_frames=2), [s])
    assert [fr.n_events for fr in adaptive] == [1, 0, 0, 1]


@pytest.mark.parametrize("spec, message", [
    ({"kind": "fw", "window_us": 0}, "window_us must be an integer >= 1"),
    ({"kind": "fw", "window_us": 2.5}, "window_us must be an integer"),
    ({"kind": "fn", "n_events": -3}, "n_events"),
    ({"kind": "fn", "max_window_us": 0}, "max_window_us"),
    ({"kind": "oa", "window_us": 100, "stride_us": 200}, "must not exceed window_us"),
    ({"kind": "adaptive", "window_us": 100, "overlap_max_us": 100}, "less than window_us"),
    ({"kind": "adaptive", "k_us_per_event": -1}, "k_us_per_event"),
    *(({"kind": "adaptive", "k_us_per_event": k}, f"^adaptive: k_us_per_event must be a finite number >= 0, got {s}$")
      for k, s in ((float("inf"), "inf"), (float("nan"), "nan"), (True, "True"), ("2", "'2'"), (-0.5, "-0.5"))),
    ({"kind": "adaptive", "overlap_init_us": 6000}, "overlap_init_us"),
    ({"kind": "timesurface", "tau_us": True}, r"^timesurface: tau_us must be a number in \(0, 2\^40\] µs, got True$"),
    ({"kind": "fw", "all_events": "yes"}, "^fw: all_events must be true or false, got 'yes'$"),
    ({"kind": "fw", "stride_us": 3}, "unknown parameter .stride_us.; its parameters: window_us"),
])
def test_bad_parameters_are_a_clear_value_error(spec, message):
    with pytest.raises(ValueError, match=message):
        build("framer", spec)


def test_framers_are_registered_and_describe_their_parameters():
    assert {"fw", "fn", "oa", "adaptive"} <= set(kinds("framer"))
    f = build("framer", {"kind": "adaptive", "window_us": 20_000})
    d = describe(f)
    assert d["kind"] == "adaptive" and d["window_us"] == 20_000 and d["n_base"] == 8000
    assert build("framer", d).params() == f.params()  # round trip


def test_pipeline_carries_frames_and_geometry_change_is_an_error():
    s = random_stream(9, 1000, G)
    pipe = Pipeline([], FixedWindow(window_us=2000))
    frames = []
    stats = pipe.run(split(s, random_bounds(9, len(s))), on_batch=lambda b: frames.extend(b.frames))
    assert stats.frames >= len(frames) > 0
    f = FixedWindow()
    f.push(s)
    with pytest.raises(EventError, match="geometry changed"):
        f.push(random_stream(1, 10, Geometry(30, 20)))


@pytest.mark.parametrize("make", [
    lambda: FixedWindow(window_us=100),
    lambda: FixedCount(n_events=70_000),
    lambda: OverlapAccumulation(window_us=100, stride_us=40),
    lambda: AdaptiveOverlap(window_us=100, n_base=0, overlap_max_us=60),
], ids=["fw", "fn", "oa", "adaptive"])
def test_counts_saturate_and_n_events_stays_exact(make):
    n = 70_000  # on one pixel, all at t 0..49: past the uint16 count
    s = EventChunk.from_arrays(np.arange(n) * 50 // n, np.full(n, 3), np.full(n, 2), np.ones(n), G)
    frames = frames_of(make(), [s])
    assert frames[0].n_events == n and frames[0].counts[1, 2, 3] == 65535
    assert frames[0].counts.dtype == np.uint16 and frames[0].image[2, 3] == 65535


@pytest.mark.parametrize("make", [
    lambda: FixedWindow(window_us=300),
    lambda: FixedCount(n_events=20),
    lambda: AdaptiveOverlap(window_us=400, n_base=5, overlap_max_us=200),
], ids=["fw", "fn", "adaptive"])
def test_recycled_count_buffers_never_touch_frames_still_held(make):
    """Buffers of dropped frames are reused; frames a consumer keeps stay as they were emitted."""
    s = random_stream(11, 3000, G, mean_dt_us=10)
    expected = frames_of(make(), [s])
    f = make()
    kept = []
    for c in split(s, list(range(0, len(s), 97)) + [len(s)]):
        frames = f.push(c)
        kept.extend(frames[::2])  # the others are dropped here: their buffers go back to the pool
    kept.extend(f.finish())
    assert f._pool is None  # finish() reset the framer
    by_key = {(fr.t_start, fr.t_end, fr.n_events): fr for fr in expected}
    assert len(by_key) == len(expected) and len(kept) > len(expected) // 3
    for fr in kept:
        assert_frames_equal([fr], [by_key[(fr.t_start, fr.t_end, fr.n_events)]], "a kept frame")


def test_count_buffers_are_recycled():
    f = FixedWindow(window_us=100)
    s = random_stream(12, 2000, G, mean_dt_us=10)
    most = 0
    for c in split(s, list(range(0, len(s), 100)) + [len(s)]):
        most = max(most, len(f.push(c)))  # frames dropped at once
    # buffers come back to be reused: the pool holds what one batch of frames needed, not the stream
    assert 0 < len(f._pool) <= most + 1 < 20


# -- each numba kernel against plain Python on random input --------------------------------------------
def _flat(s, i):
    return int(s.p[i]) * G.n_pixels + int(s.y[i]) * G.width + int(s.x[i])


@given(seeds)
def test_kernels_equal_plain_python(seed):
    from evstream.framing.fixed import FN_DONE, FN_FULL, FN_TIMEOUT, accumulate, fn_run
    from evstream.framing.overlap import add_flat, flat_index, flat_index_of

    rng = np.random.default_rng(seed)
    s = random_stream(rng, int(rng.integers(1, 300)), G)
    cls = rng.integers(0, 3, len(s)).astype(np.uint8)
    use_cls = bool(rng.random() < 0.5)
    a, b = sorted(int(v) for v in rng.integers(0, len(s) + 1, 2))
    start = rng.integers(0, 65530, 2 * G.n_pixels).astype(np.uint16)  # near saturation too

    counts = start.copy()
    added = accumulate(s.x, s.y, s.p, cls, use_cls, a, b, counts, G.width, G.n_pixels)
    want, n = start.astype(np.int64), 0
    for i in range(a, b):
        if not use_cls or cls[i] == 0:
            want[_flat(s, i)] += 1
            n += 1
    assert added == n and np.array_equal(counts, np.minimum(want, 65535))

    out = np.zeros(len(s) + 5, np.uint32)
    flat_index(s.x, s.y, s.p, a, b, G.width, G.n_pixels, out, 3)
    assert out[3 : 3 + b - a].tolist() == [_flat(s, i) for i in range(a, b)]
    idx = np.flatnonzero(cls == 0)
    flat_index_of(s.x, s.y, s.p, idx, G.width, G.n_pixels, out, 1)
    assert out[1 : 1 + len(idx)].tolist() == [_flat(s, i) for i in idx]

    counts = start.copy()
    add_flat(counts, out, 1, 1 + len(idx))
    want = start.astype(np.int64)
    for f in out[1 : 1 + len(idx)]:
        want[f] += 1
    assert np.array_equal(counts, np.minimum(want, 65535))

    # fn_run: fill a frame of n_target from index a, or time out max_window after its first event
    n_target, max_window = int(rng.integers(1, 50)), int(rng.integers(1, 3000))
    counts = np.zeros(2 * G.n_pixels, np.uint16)
    i, have, first, last, status = fn_run(s.t, s.x, s.y, s.p, cls, use_cls, a, counts, G.width, G.n_pixels,
                                          0, n_target, 0, 0, max_window)
    j, members, exp_status = a, [], FN_DONE
    while j < len(s):
        if members and s.t[j] >= s.t[members[0]] + max_window:
            exp_status = FN_TIMEOUT
            break
        if not use_cls or cls[j] == 0:
            members.append(j)
            if len(members) == n_target:
                j += 1
                exp_status = FN_FULL
                break
        j += 1
    assert (i, have, status) == (j, len(members), exp_status)
    if members:
        assert (first, last) == (s.t[members[0]], s.t[members[-1]])
    want = np.zeros(2 * G.n_pixels, np.int64)
    for m in members:
        want[_flat(s, m)] += 1
    assert np.array_equal(counts, want)


def test_oa_stride_defaults_to_half_the_window_and_may_equal_it():
    """OA's default stride is half the window (at least 1 µs); a stride equal to the window is FW."""
    assert [OverlapAccumulation(window_us=w).stride_us for w in (1, 2, 3, 1001)] == [1, 1, 1, 500]
    s = random_stream(5, 3000, G)
    assert_frames_equal(frames_of(OverlapAccumulation(window_us=700), [s]),
                        frames_of(OverlapAccumulation(window_us=700, stride_us=350), [s]))
    assert_frames_equal(frames_of(OverlapAccumulation(window_us=700, stride_us=700), [s]),
                        frames_of(FixedWindow(window_us=700), [s]))


# the next event on the end of the frame where skipping starts (2800), of the one after (3400), of a far
# one, and on none
@pytest.mark.parametrize("gap_us", [2800, 3400, 600 * 10**6 + 1000, 600 * 10**6 + 1234])
def test_adaptive_with_a_fixed_overlap_skips_empty_frames_onto_oa_grid(gap_us):
    """With k = 0 the overlap stays at its initial value: adaptive is OA with stride Δt − O, and after a
    long quiet stretch it must land on the same frames as OA does (also when an event falls exactly
    on a frame's end)."""
    s = EventChunk.from_arrays([0, 5, gap_us, gap_us + 7], [1, 2, 3, 4], [1, 2, 3, 4], [1, 0, 1, 1], G)
    adaptive = frames_of(AdaptiveOverlap(window_us=1000, n_base=10, k_us_per_event=0, overlap_max_us=900,
                                         overlap_init_us=400, max_empty_frames=2), [s])
    assert_frames_equal(adaptive, frames_of(OverlapAccumulation(window_us=1000, stride_us=600, max_empty_frames=2),
                                            [s]))


def test_overlap_buffer_grows_past_its_initial_size():
    """A window holding more events than the overlap buffer's initial 16384 (so it grows, keeping what
    it holds), in chunks of every size, against the reference OA."""
    s = random_stream(11, 60_000, G, mean_dt_us=0.5)  # ~30,000 events per 15 ms window
    frames = frames_of(OverlapAccumulation(window_us=15_000, stride_us=5_000), split(s, [0, 7, 20_000, 20_001, len(s)]))
    assert max(fr.n_events for fr in frames) > 1 << 14
    assert_frames_equal(frames, ref_oa(s, window_us=15_000, stride_us=5_000))


def test_overlap_buffer_grows_while_it_holds_events_then_fills_again():
    """The buffer grows while it holds a window's events (16384 of them when the next chunk comes), and
    then fills past the size it grew to before it grows again: both of its arrays (times and flat
    indices) must have grown alike. One frame holds ~40,000 events (stride 1 ms of a 30 ms window, so
    nearly all are buffered), pushed in chunks of 1000; the frames are those of one push."""
    s = random_stream(12, 45_000, G, mean_dt_us=0.5)
    oa = dict(window_us=30_000, stride_us=1_000)
    frames = frames_of(OverlapAccumulation(**oa), split(s, list(range(0, len(s), 1000)) + [len(s)]))
    assert max(fr.n_events for fr in frames) > 2 * (1 << 14)
    assert_frames_equal(frames, frames_of(OverlapAccumulation(**oa), [s]))


def test_frame_step_and_frame_bytes_hold_for_the_frames_made():
    """What `framing.bound.cut` relies on: `frame_step` the least event time (fw and oa: the exact step) or the
    fewest counted events (fn: a full frame's) from one frame's end to the next's, `pause_step_us` the step
    between empty frames in a pause, `frame_bytes` what one frame holds (its two count planes)."""
    a, b = random_stream(3, 1500, G, mean_dt_us=30), random_stream(4, 1500, G, mean_dt_us=30)
    s = concat([a, b.replace(t=b.t + int(a.t[-1]) + 20_000)])  # a pause of ~20 windows
    for framer in (FixedWindow(window_us=1000), FixedCount(n_events=50, max_window_us=800),
                   OverlapAccumulation(window_us=1000, stride_us=400), AdaptiveOverlap(window_us=1000, n_base=50)):
        frames = frames_of(framer, [s])
        step_us, step_n = framer.frame_step()
        steps = np.diff([fr.t_end for fr in frames])
        if isinstance(framer, FixedCount):
            assert (step_us, step_n) == (800, 50) and max(fr.n_events for fr in frames) == step_n
            assert max(fr.t_end - fr.t_start for fr in frames) == step_us and framer.pause_step_us() is None
        else:
            assert step_n is None and steps.min() >= step_us
            if isinstance(framer, AdaptiveOverlap):  # O_max = window / 2 by default
                assert step_us == 500 and framer.pause_step_us() == 1000
                assert [int(d) for d, e, f in zip(steps, frames, frames[1:]) if not e.n_events and not f.n_events][
                    :5] == [1000] * 5
            else:
                assert steps.max() == step_us and framer.pause_step_us() is None
        assert all(framer.frame_bytes(G.n_pixels) == fr.counts.nbytes for fr in frames)


def test_overlap_buffer_starts_again_at_its_front_when_its_tail_reaches_its_end():
    """Bursts of 1000 events at one time, 5 ms apart, through OA 3 ms / 1 ms: a next frame holds each burst, so
    it is buffered, and dropped once the frames pass it; the buffer's tail creeps to its end holding nothing,
    until a burst finds no room there and the buffer starts again at its front (its first slot holding the
    burst's first event, which the next frames need)."""
    rng = np.random.default_rng(3)
    t = np.repeat(np.arange(40, dtype=np.int64) * 5000 + 2500, 1000)
    s = EventChunk.from_arrays(t, rng.integers(0, G.width, len(t)), rng.integers(0, G.height, len(t)),
                               rng.integers(0, 2, len(t)), G)
    for chunks in ([s], split(s, list(range(0, len(s), 1000)) + [len(s)])):
        frames = frames_of(OverlapAccumulation(window_us=3000, stride_us=1000), chunks)
        assert sum(fr.n_events for fr in frames) > 40 * 1000
        assert_frames_equal(frames, ref_oa(s, window_us=3000, stride_us=1000))


@pytest.mark.parametrize("use_cls", [False, True])
def test_fn_kernels_give_an_empty_frame_no_deadline(use_cls):
    """A frame holding no event yet has no deadline: the first and last times handed in are still those
    of the frame before (closed full), and an event long past them starts the new frame. Timing out on
    them instead made FixedCount, over a classified stream, close empty frames without end."""
    t = np.array([5000, 5001, 5002], np.int64)
    cls = np.zeros(3, np.uint8)
    assert fn_scan(t, cls, use_cls, 0, 0, 2, 100, 150, 500) == (2, 2, 5000, 5001, FN_FULL)
    counts = np.zeros(2 * 3 * 4, np.uint16)
    x, y, p = np.array([0, 1, 2], np.uint16), np.array([0, 1, 2], np.uint16), np.array([1, 0, 1], np.uint8)
    assert fn_run(t, x, y, p, cls, use_cls, 0, counts, 4, 12, 0, 2, 100, 150, 500) == (2, 2, 5000, 5001, FN_FULL)
    assert counts.reshape(2, 3, 4)[1, 0, 0] == 1 and counts.reshape(2, 3, 4)[0, 1, 1] == 1 and counts.sum() == 2


@pytest.mark.parametrize("use_cls", [False, True])
@pytest.mark.parametrize("times, have", [
    ([600, 601], 1),  # the frame holds one event (at 100): an event exactly on its deadline closes it
    ([700, 701], 1),  # ... and one past it
    ([900, 901], 3),  # a chunk whose first event is past the deadline of the frame the chunk before left open
])
def test_fn_kernels_close_a_frame_on_its_deadline(use_cls, times, have):
    """The frame [100, 100 + 500) holds `have` events (first at 100, last at 150) when a chunk comes: its
    first event, at or past the deadline, times the frame out before any is taken, and the frame's first
    and last times stay as they were."""
    t = np.array(times, np.int64)
    cls = np.zeros(len(t), np.uint8)
    want = (0, have, 100, 150, FN_TIMEOUT)
    assert fn_scan(t, cls, use_cls, 0, have, 10, 100, 150, 500) == want
    counts = np.zeros(2 * 3 * 4, np.uint16)
    x = y = np.zeros(len(t), np.uint16)
    assert fn_run(t, x, y, x.astype(np.uint8), cls, use_cls, 0, counts, 4, 12, have, 10, 100, 150, 500) == want
    assert not counts.any()


def test_fn_windows_after_a_quiet_stretch_are_the_same_with_a_follower():
    """A representation over fixed-count windows finds them without counting (`fn_scan`): over a
    classified stream whose events come long after the last full frame began, the same windows as
    FixedCount's own."""
    s = random_stream(13, 400, G, mean_dt_us=40)
    gap = EventChunk.from_arrays(s.t + 10_000_000, s.x, s.y, s.p, G).replace(cls=s.label)
    s = concat([s.replace(cls=s.label), gap])
    spec = {"n_events": 50, "max_window_us": 5_000}
    plain = frames_of(FixedCount(**spec), [s])
    voxels = frames_of(build("framer", {"kind": "voxel", "window": "fn", "bins": 3, **spec}), [s])
    assert [(f.t_start, f.t_end, f.n_events) for f in voxels] == [(f.t_start, f.t_end, f.n_events) for f in plain]
    assert any(f.t_start > 10_000_000 for f in plain) and all(f.n_events for f in plain)


def test_empty_frames_hold_counts_of_the_frames_dtype_and_a_run_counts_them():
    """An empty frame's counts are the sensor's zeros in COUNT_DTYPE, as a full frame's; FrameStats, as a
    run's sink, counts every frame of each batch and takes the run's duration."""
    from evstream.framing.base import COUNT_DTYPE
    from evstream.framing.stats import FrameStats

    s = EventChunk.from_arrays([0, 5, 3_000, 3_001], [1, 2, 3, 4], [1, 2, 3, 4], [1, 0, 1, 1], G)
    frames = frames_of(FixedWindow(window_us=1000), [s])
    assert [f.n_events for f in frames] == [2, 0, 0, 2]
    assert all(f.counts.dtype == COUNT_DTYPE and f.counts.shape == (2, G.height, G.width) for f in frames)
    stats = FrameStats()
    run = Pipeline([], FixedWindow(window_us=1000)).run([s[:2], s[2:]], [stats])
    assert (stats.frames, stats.empty_frames, stats.duration_us) == (4, 2, run.duration_us)


def test_fn_an_event_on_the_deadline_starts_the_next_frame():
    """An FN frame spans [first, first + max_window_us): an event exactly at the deadline closes it and
    opens the next one, in one chunk and one event at a time (the watermark then sits on the deadline)."""
    s = EventChunk.from_arrays([100, 150, 600, 601, 1100], [1, 2, 3, 4, 5], [1, 2, 3, 4, 5], [1, 0, 1, 1, 0], G)
    for chunks in ([s], one_event_chunks(s)):
        frames = frames_of(FixedCount(n_events=10, max_window_us=500), chunks)
        assert_frames_equal(frames, ref_fn(s, n_events=10, max_window_us=500))
        assert [(f.t_start, f.t_end, f.n_events) for f in frames] == [(100, 600, 2), (600, 1100, 2), (1100, 1101, 1)]
