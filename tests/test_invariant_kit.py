"""The invariant kit must catch stages that break the invariants (else it proves nothing)."""

from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream.events import Frame, NoiseClass
from evstream.framing import FixedWindow
from evstream.testing import (
    assert_bounded_state,
    assert_cameras_independent,
    assert_causal,
    assert_chunk_invariant,
    assert_framer_causal,
    assert_frames_equal,
    frames_of,
    random_bounds,
    random_stream,
    split,
)


@dataclass
class LastSeen:
    """Chunk-invariant, causal, bounded: noise if the pixel fired within window_us before."""

    window_us: int = 100
    last: np.ndarray = field(default_factory=lambda: np.full((18, 24), -(10**9), np.int64))

    def __call__(self, c):
        cls = np.zeros(len(c), np.uint8)
        for i in range(len(c)):
            if c.t[i] - self.last[c.y[i], c.x[i]] < self.window_us:
                cls[i] = NoiseClass.BACKGROUND
            self.last[c.y[i], c.x[i]] = c.t[i]
        return c.replace(cls=cls)


class PerChunk:
    """Breaks chunk invariance: decides on each chunk's own size."""

    def __call__(self, c):
        return c.replace(cls=np.full(len(c), len(c) % 2, np.uint8))


class Peeks:
    """Breaks causality: looks at the last event of the chunk."""

    def __call__(self, c):
        return c.replace(cls=np.full(len(c), int(c.x[-1]) % 2 if len(c) else 0, np.uint8))


class SharesState(LastSeen):
    """Breaks camera independence: every instance writes into one class-level array."""

    shared = np.full((18, 24), -(10**9), np.int64)

    def __init__(self):
        super().__init__(last=SharesState.shared)


class Hoards:
    """Breaks the memory bound: keeps every timestamp."""

    def __init__(self):
        self.seen = []

    def __call__(self, c):
        self.seen.append(c.t.copy())
        return c.replace(cls=np.zeros(len(c), np.uint8))


class Box:
    """A slotted holder: no __dict__ (as represent's `_Grid`)."""

    __slots__ = ("data", "more")

    def __init__(self, data):
        self.data = data


class HoardsInBoxes(Hoards):
    """Breaks the memory bound in slotted objects: keeps every timestamp, each in a `Box`."""

    def __call__(self, c):
        self.seen.append(Box(c.t.copy()))
        return c.replace(cls=np.zeros(len(c), np.uint8))


@given(st.integers(0, 2**32))
def test_kit_accepts_a_correct_stage(seed):
    s = random_stream(seed, 300)
    assert_chunk_invariant(LastSeen, s, seed)
    assert_causal(LastSeen, s, seed)


def test_kit_catches_chunk_dependence():
    with pytest.raises(AssertionError, match="differ"):
        assert_chunk_invariant(PerChunk, random_stream(1, 200), 1)


def test_kit_catches_peeking_at_the_future():
    with pytest.raises(AssertionError, match="prefix of .* events with a different future"):
        for seed in range(20):  # a random cut may by chance agree; across seeds it cannot
            assert_causal(Peeks, random_stream(seed, 200), seed)


def test_kit_bounds_state():
    assert_bounded_state(LastSeen, lambda n: random_stream(0, n))
    for hoards in (Hoards, HoardsInBoxes):
        with pytest.raises(AssertionError, match="grows with stream length"):
            assert_bounded_state(hoards, lambda n: random_stream(0, n))


@given(st.integers(0, 2**32), st.integers(0, 50))
def test_random_bounds_cover_the_stream(seed, n):
    b = random_bounds(seed, n)
    assert b[0] == 0 and b[-1] == n and b == sorted(b)
    assert sum(len(c) for c in split(random_stream(seed, n), b)) == n


def test_kit_catches_a_stage_that_keeps_state_across_cameras():
    streams = [random_stream(s, 300) for s in (1, 2, 3)]
    assert_cameras_independent(LastSeen, streams, 1)  # the same stage with its own state passes
    SharesState.shared[:] = -(10**9)
    with pytest.raises(AssertionError, match="camera .* vs the same camera alone"):
        assert_cameras_independent(SharesState, streams, 1)


# -- framers -------------------------------------------------------------------------------------
class Windows:
    """A plain fixed-window framer (frames [start, start + window_us), emitted when the watermark
    reaches their end), written independently of evstream.framing; its broken variants:
    `peek_us` > 0 adds to each frame the events of the current chunk up to peek_us past its end
    (a framer that looks ahead); `drop_on_watermark` forgets frames closed by a chunk's watermark
    rather than by an event (a framer that drops a frame)."""

    def __init__(self, window_us=400, *, peek_us=0, drop_on_watermark=False):
        self.window_us, self.peek_us, self.drop = window_us, peek_us, drop_on_watermark
        self.start = None
        self.events: list[tuple[int, int, int]] = []

    def _close(self, chunk, out, emit=True):
        end = self.start + self.window_us
        counts = np.zeros((2, chunk.geometry.height, chunk.geometry.width), np.uint16)
        events = list(self.events)
        if self.peek_us:
            ahead = (chunk.t >= end) & (chunk.t < end + self.peek_us)
            events += list(zip(chunk.x[ahead], chunk.y[ahead], chunk.p[ahead]))
        for x, y, p in events:
            counts[p, y, x] += 1
        if emit:
            out.append(Frame(self.start, end, len(events), counts))
        self.start, self.events = end, []

    def push(self, chunk):
        out = []
        for i in range(len(chunk)):
            t = int(chunk.t[i])
            if self.start is None:
                self.start = t
            while t >= self.start + self.window_us:
                self._close(chunk, out)
            self.events.append((int(chunk.x[i]), int(chunk.y[i]), int(chunk.p[i])))
        while self.start is not None and len(chunk) and chunk.t_end >= self.start + self.window_us:
            self._close(chunk, out, emit=not self.drop)
        return out

    def finish(self):
        return []  # the open frame is dropped at the end, the same way for every chunking


framer_seeds = st.integers(0, 2**32)


@given(framer_seeds)
def test_kit_accepts_correct_framers(seed):
    s = random_stream(seed, 300).replace(cls=None)
    for make in (Windows, lambda: FixedWindow(window_us=400)):
        assert_chunk_invariant(make, s, seed, apply=frames_of)
        assert_framer_causal(make, s, seed)
        assert_cameras_independent(make, [s, random_stream(seed + 1, 200)], seed, framer=True)


def test_kit_catches_a_framer_that_peeks_ahead():
    with pytest.raises(AssertionError, match="first frames of the whole stream"):
        for seed in range(20):  # a cut may fall where no frame is close to it; across seeds one is
            assert_framer_causal(lambda: Windows(peek_us=100), random_stream(seed, 300), seed)


def test_kit_catches_a_framer_that_drops_a_frame():
    with pytest.raises(AssertionError, match=r"split at .*: \d+ frames vs \d+"):
        for seed in range(20):
            assert_chunk_invariant(lambda: Windows(drop_on_watermark=True), random_stream(seed, 300), seed,
                                   apply=frames_of, one_event=False)


def test_frames_equal_catches_each_kind_of_difference():
    frames = frames_of(FixedWindow(window_us=400), [random_stream(3, 300)])
    assert len(frames) > 3
    assert_frames_equal(frames, list(frames))
    with pytest.raises(AssertionError, match=f"{len(frames) - 1} frames vs {len(frames)}"):
        assert_frames_equal(frames[:2] + frames[3:], frames)
    f = frames[2]
    counts = f.counts.copy()
    counts[1, 0, 0] += 1
    for changed in (Frame(f.t_start + 1, f.t_end, f.n_events, f.counts),
                    Frame(f.t_start, f.t_end - 1, f.n_events, f.counts),
                    Frame(f.t_start, f.t_end, f.n_events + 1, f.counts),
                    Frame(f.t_start, f.t_end, f.n_events, counts)):
        with pytest.raises(AssertionError, match="frame 2 differs"):
            assert_frames_equal(frames[:2] + [changed] + frames[3:], frames)


# -- the kit's own generators: what the invariant checks rely on them to produce ----------------------
def test_random_stream_has_the_stress_it_promises():
    """Bursts of equal timestamps (30 % of gaps), 60/30/10 % signal/background/hot labels, signal in a
    blob (neighbours within ~1.5 px) that wanders over the whole sensor, hot events on a few pixels,
    events on all four borders, both polarities; deterministic per seed; t from t0_us on."""
    from evstream.events import Geometry

    g = Geometry(24, 18)
    s = random_stream(5, 20_000, g, t0_us=1000)
    assert len(s) == 20_000 and s.geometry == g and s.t.dtype == np.int64 and s.label.dtype == np.uint8
    assert s.t[0] >= 1000 and (np.diff(s.t) >= 0).all()
    assert 0.27 < np.mean(np.diff(s.t) == 0) < 0.33 and s.t[-1] - s.t[0] > 20_000 * 50 * 0.6
    share = np.bincount(s.label, minlength=3) / len(s)
    assert abs(share[0] - 0.6) < 0.02 and abs(share[1] - 0.3) < 0.02 and abs(share[2] - 0.1) < 0.02
    sig = s.label == NoiseClass.SIGNAL
    xs, ys = s.x[sig].astype(float), s.y[sig].astype(float)
    inner = (xs > 2) & (xs < g.width - 3) & (ys > 2) & (ys < g.height - 3)
    dx = np.abs(np.diff(xs[inner]))  # consecutive signal events: two draws around nearly the same centre
    assert 1.2 < dx.mean() < 1.8 and np.percentile(dx, 99) < 8  # sd 1.5 each: E|d| ~ 1.5
    assert np.percentile(xs, 3) < 2 and np.percentile(xs, 97) > g.width - 3  # the blob crosses the sensor
    assert np.percentile(ys, 3) < 2 and np.percentile(ys, 97) > g.height - 3
    hot = s.label == NoiseClass.HOT_PIXEL
    assert len(np.unique(s.y[hot])) == 1  # one hot pixel (5 % of all events are moved to a side border)
    for axis, size in ((s.x, g.width), (s.y, g.height)):
        assert axis.min() == 0 and axis.max() == size - 1
    assert np.mean((s.x == 0) | (s.x == g.width - 1)) > 0.05
    assert 0.48 < s.p.mean() < 0.52 and set(np.unique(s.p)) == {0, 1}
    again = random_stream(5, 20_000, g, t0_us=1000)
    assert all(np.array_equal(getattr(s, k), getattr(again, k)) for k in ("t", "x", "y", "p", "label"))
    none = random_stream(6, 2000, g, hot_pixels=0)
    assert not (none.label == NoiseClass.HOT_PIXEL).any() and (none.label == NoiseClass.BACKGROUND).mean() > 0.35
    many = random_stream(6, 5000, g, hot_pixels=3)
    h = many.label == NoiseClass.HOT_PIXEL
    pixels = np.unique(many.x[h].astype(np.int64) * 1000 + many.y[h])
    assert 1 < len(pixels) <= 3 + 2 * 3  # three, and their rows' border pixels (the 5 % border events)
    empty = random_stream(7, 0, g, t0_us=42)
    assert len(empty) == 0 and empty.t_end == 42 and empty.geometry == g and empty.label is not None
    rng = np.random.default_rng(1)
    assert not np.array_equal(random_stream(rng, 50).t, random_stream(rng, 50).t)  # a Generator is used as is


def test_random_bounds_draw_every_kind_of_split():
    """From one chunk (plus the forced one-event chunk) to max_chunks, a trailing empty chunk in ~30 %."""
    sizes, trailing = set(), 0
    for seed in range(400):
        b = random_bounds(seed, 10_000)
        distinct = sorted(set(b))
        assert distinct[0] == 0 and distinct[-1] == 10_000 and b == sorted(b)
        assert any(q - p == 1 for p, q in zip(distinct, distinct[1:]))  # a one-event chunk
        sizes.add(len(distinct))
        trailing += b[-1] == b[-2]
    assert sizes == set(range(4, 16))  # k - 1 cuts for k in 1..12, plus 0, n and the one-event chunk
    assert 80 < trailing < 160
    for seed in range(20):
        b = random_bounds(seed, 2)
        assert sorted(set(b)) == [0, 1, 2]
        assert set(random_bounds(seed, 0)) == {0}


def test_compare_says_what_differs():
    from evstream.testing import _compare, classify_all

    with pytest.raises(AssertionError, match=r"here: outputs differ \(first differing positions: \[1 3\]\)"):
        _compare(np.array([0, 1, 0, 1], np.uint8), np.array([0, 0, 0, 0], np.uint8), "here")
    with pytest.raises(AssertionError, match=r"first differing positions: shape \(\(3,\)"):
        _compare(np.zeros(3, np.uint8), np.zeros(2, np.uint8), "here")
    with pytest.raises(AssertionError, match="outputs differ"):
        _compare(np.zeros(3, np.uint8), np.zeros(3, np.int64), "dtype")
    with pytest.raises(AssertionError, match=r"first differing positions: \[0 1 2 3 4 5 6 7 8 9\]\)"):
        _compare(np.zeros(12, np.uint8), np.ones(12, np.uint8), "ten")
    with pytest.raises(TypeError, match="cannot compare <class 'int'>"):
        _compare(1, 1, "ints")
    empty = classify_all(LastSeen(), [])
    assert empty.dtype == np.uint8 and empty.shape == (0,)
    with pytest.raises(AssertionError, match="one-event chunks: outputs differ"):
        assert_chunk_invariant(PerChunk, random_stream(1, 200), 1, splits=0)


def test_bounded_state_measures_what_it_holds():
    from collections import deque

    from evstream.testing import state_nbytes

    a = np.zeros(100, np.int64)
    assert state_nbytes(a) == 800 and state_nbytes([a, a]) == 16 + 800  # shared arrays once
    assert state_nbytes(deque([a])) == 8 + 800 and state_nbytes({"k": a}) == 800 and state_nbytes(3) == 0
    assert state_nbytes(LastSeen()) == 18 * 24 * 8
    cyc = []
    cyc.append(cyc)
    assert state_nbytes(cyc) == 8
    with pytest.raises(AssertionError, match=r"state grows with stream length: \d+ B after 2000 events, \d+ B "
                                             r"after 16000"):
        assert_bounded_state(Hoards, lambda n: random_stream(0, n))


class Records(LastSeen):
    """A correct stage that logs what it is fed (to see the kit's draws)."""

    log: list = []

    def __call__(self, c):
        Records.log.append((len(c), int(c.t.sum()), int(c.x.sum())))
        return super().__call__(c)


class RecordsFrames(Windows):
    log: list = []

    def push(self, chunk):
        RecordsFrames.log.append((len(chunk), int(chunk.t.sum()), int(chunk.t_end)))
        return super().push(chunk)


def test_kit_draws_are_determined_by_the_seed():
    """The same seed gives the same splits, cuts and futures (a failure can be replayed), another
    seed other ones."""
    s, s2 = random_stream(8, 300), random_stream(9, 200)
    checks = [(Records, lambda seed: assert_chunk_invariant(Records, s, seed)),
              (Records, lambda seed: assert_causal(Records, s, seed)),
              (Records, lambda seed: assert_cameras_independent(Records, [s, s2], seed)),
              (RecordsFrames, lambda seed: assert_framer_causal(RecordsFrames, s, seed))]
    for cls, check in checks:
        runs = []
        for seed in (3, 3, 4):
            cls.log = []
            check(seed)
            runs.append(cls.log)
        assert runs[0] == runs[1] != runs[2]


def test_frames_equal_compares_representation_data():
    from types import SimpleNamespace

    counts = np.zeros((2, 2, 2), np.uint16)

    def frame(data):
        return SimpleNamespace(t_start=0, t_end=10, n_events=0, counts=counts, data=data)

    a = np.arange(4.0).reshape(2, 2)
    assert_frames_equal([frame(a)], [frame(a.copy())])
    for other in (a + 1, a.astype(np.float32), None):
        with pytest.raises(AssertionError, match="frame 0 differs"):
            assert_frames_equal([frame(a)], [frame(other)])
    with pytest.raises(AssertionError, match="frame 0 differs"):
        assert_frames_equal([frame(None)], [frame(a)])


def test_other_future_keeps_the_prefix_and_replaces_the_rest():
    """The causality checks' altered stream: same length and geometry, the first m events unchanged,
    the rest drawn anew from the prefix's last time on (sometimes at that very time: a burst across
    the cut)."""
    from evstream.events import Geometry
    from evstream.testing import _other_future

    g = Geometry(40, 30)
    at_cut = 0
    for seed in range(60):
        s = random_stream(seed, 200, g)
        m, altered = _other_future(s, np.random.default_rng(seed))
        assert 1 <= m < 200 and len(altered) == 200 and altered.geometry == g
        assert np.array_equal(altered.t[:m], s.t[:m]) and np.array_equal(altered.x[:m], s.x[:m])
        assert altered.t[m] >= s.t[m - 1] and not np.array_equal(altered.x[m:], s.x[m:])
        at_cut += altered.t[m] == s.t[m - 1]
    assert at_cut >= 6


# -- what mutation testing found the checks above left open ---------------------------------------
class Creeps:
    """Breaks the memory bound slowly: a fixed 64 kB map plus 2 bytes per event seen (1.4x over an
    8x longer stream: only the bound's `slack` of 1.25 catches it)."""

    def __init__(self):
        self.map, self.log = np.zeros(64_000, np.uint8), np.zeros(0, np.uint8)

    def __call__(self, c):
        self.log = np.zeros(len(self.log) + 2 * len(c), np.uint8)
        return c.replace(cls=np.zeros(len(c), np.uint8))


class StartsBig(Hoards):
    """Holds 800 kB until its first chunk, then only what it hoards: under its start-up peak for the
    short and the long stream alike, so it passes (the peak counts the state before any event)."""

    def __init__(self):
        super().__init__()
        self.startup = np.zeros(100_000, np.int64)

    def __call__(self, c):
        self.startup = None
        return super().__call__(c)


def test_bounded_state_uses_its_slack_and_counts_the_state_before_the_first_chunk():
    with pytest.raises(AssertionError, match="grows with stream length"):
        assert_bounded_state(Creeps, lambda n: random_stream(0, n))
    big = np.full((480, 640), -(10**9), np.int64)  # a correct stage with a 2.4 MB map: the bound is relative
    assert_bounded_state(lambda: LastSeen(last=big.copy()), lambda n: random_stream(0, n))
    assert_bounded_state(StartsBig, lambda n: random_stream(0, n))


def test_bounded_state_feeds_every_event_once_in_order():
    seen = []

    class Logs(LastSeen):
        def __call__(self, c):
            seen.append(c.t.copy())
            return super().__call__(c)

    streams = {}

    def stream_of_length(n):
        streams[n] = random_stream(0, n)
        return streams[n]

    assert_bounded_state(Logs, stream_of_length, n=600, factor=2, chunk=100)
    fed = np.concatenate(seen)
    assert np.array_equal(fed, np.concatenate([streams[600].t, streams[1200].t]))
    assert [len(t) for t in seen] == [100] * 6 + [100] * 12


def test_state_nbytes_counts_an_array_once_however_it_is_reached():
    from types import SimpleNamespace

    from evstream.testing import state_nbytes

    a = np.zeros(100, np.int64)
    holder = SimpleNamespace(a=a)
    assert state_nbytes([a, holder]) == 16 + 800 and state_nbytes([a, {"k": a}]) == 16 + 800
    holder.me = holder  # a cycle through an object's attributes
    assert state_nbytes(holder) == 800


def test_state_nbytes_counts_what_slotted_objects_hold():
    from evstream.testing import state_nbytes

    class One:
        __slots__ = "data"  # one slot, named by a string

    class Both(Box):  # slots of its base and a __dict__ of its own
        pass

    a, b = np.zeros(100, np.int64), np.zeros(10, np.int32)
    assert state_nbytes(Box(a)) == 800  # its unset slot holds nothing
    one = One()
    one.data = a
    assert state_nbytes(one) == 800 and state_nbytes(One()) == 0
    both = Both(a)
    both.more, both.extra = b, np.zeros(3, np.uint8)
    assert state_nbytes(both) == 800 + 40 + 3
    both.extra = a  # shared with a slot: once
    assert state_nbytes(both) == 800 + 40


def test_chunk_invariance_without_one_event_chunks_does_not_feed_them_all():
    calls = []

    class Counts(LastSeen):
        def __call__(self, c):
            calls.append(len(c))
            return super().__call__(c)

    s = random_stream(4, 300)
    assert_chunk_invariant(Counts, s, 4, one_event=False)
    assert len(calls) < 60  # the whole stream, then 3 splits of at most 15 chunks
    calls.clear()
    assert_chunk_invariant(Counts, s, 4)
    assert calls.count(1) >= 300


def test_causality_is_checked_on_two_event_streams():
    """The shortest stream with a future (the prefix is its first event): a stage peeking at its chunk's
    last event is caught there too, and so is a framer emitting a frame before the watermark closed it."""
    with pytest.raises(AssertionError, match="prefix of 1 events with a different future"):
        for seed in range(20):
            assert_causal(Peeks, random_stream(seed, 2), seed)
    assert_causal(LastSeen, random_stream(0, 2), 0)
    with pytest.raises(AssertionError, match="vs those emitted after 1 events"):
        assert_framer_causal(Premature, random_stream(0, 2).replace(cls=None, t=np.array([0, 10])), 0)
    assert_framer_causal(Windows, random_stream(0, 2).replace(cls=None, t=np.array([0, 10])), 0)


class Premature(Windows):
    """Breaks causality: also emits its open frame at the end of every chunk, before the watermark
    has closed it."""

    def push(self, chunk):
        out = super().push(chunk)
        if self.events:
            counts = np.zeros((2, chunk.geometry.height, chunk.geometry.width), np.uint16)
            for x, y, p in self.events:
                counts[p, y, x] += 1
            out.append(Frame(self.start, self.start + self.window_us, len(self.events), counts))
        return out


def test_checks_say_which_check_failed():
    frames = frames_of(FixedWindow(window_us=400), [random_stream(3, 300)])
    with pytest.raises(AssertionError, match=r"^frames: frame 0 differs"):
        assert_frames_equal([frames[1]], [frames[0]])
    with pytest.raises(AssertionError, match=r"first frames of the whole stream with its own future vs"):
        for seed in range(20):
            assert_framer_causal(lambda: Windows(peek_us=100), random_stream(seed, 300), seed)


def test_cameras_independent_with_a_camera_that_sends_nothing():
    streams = [random_stream(1, 300), random_stream(2, 0)]
    assert_cameras_independent(LastSeen, streams, 1)


class FlushesOnTightWatermark(Windows):
    """Breaks causality only when a chunk's watermark is its last event's time (as a source's last
    chunk has): it then flushes its open frame as if the stream had ended."""

    def push(self, chunk):
        out = super().push(chunk)
        if len(chunk) and self.events and chunk.t_end == chunk.t[-1]:
            counts = np.zeros((2, chunk.geometry.height, chunk.geometry.width), np.uint16)
            for x, y, p in self.events:
                counts[p, y, x] += 1
            out.append(Frame(self.start, self.start + self.window_us, len(self.events), counts))
            self.events = []
        return out


def test_framer_causality_gives_the_prefix_the_watermark_of_its_last_event():
    """The prefix's watermark is its last event's time, not an earlier one: a framer that misbehaves
    exactly there is caught."""
    with pytest.raises(AssertionError, match="first frames of the whole stream"):
        for seed in range(20):
            s = random_stream(seed, 300)  # distinct times: an earlier event's time is never the last one's
            assert_framer_causal(FlushesOnTightWatermark, s.replace(cls=None, t=37 * np.arange(300)), seed)
