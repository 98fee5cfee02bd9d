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
    with pytest.raises(AssertionError, match="grows with stream length"):
        assert_bounded_state(Hoards, lambda n: random_stream(0, n))


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
