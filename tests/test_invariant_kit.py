"""The invariant kit must catch stages that break the invariants (else it proves nothing)."""

from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream.events import NoiseClass
from evstream.testing import (
    assert_bounded_state,
    assert_causal,
    assert_chunk_invariant,
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
    with pytest.raises(AssertionError):
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
