"""Test kit for the streaming invariants every stage and framer must keep.

1. chunk invariance: the output is bit-identical for any split of the stream into chunks;
2. causality: the decision for event m depends only on events before it (and m itself);
3. bounded memory: state is O(width x height) plus O(window), never O(stream length).

Use from tests (with hypothesis drawing the seeds) as
`assert_chunk_invariant(lambda: MyStage(...), random_stream(seed, 500))`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .events import EventChunk, Frame, Geometry, NoiseClass, concat

SMALL = Geometry(24, 18)


def _rng(seed) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def random_stream(
    seed,
    n: int,
    geometry: Geometry = SMALL,
    *,
    t0_us: int = 0,
    mean_dt_us: float = 50.0,
    hot_pixels: int = 1,
) -> EventChunk:
    """A labelled stream that stresses kernels: clustered signal, uniform noise, a hot pixel,
    bursts of equal timestamps and events on the border pixels."""
    rng = _rng(seed)
    if n == 0:
        return EventChunk.empty(geometry, t_end=t0_us, with_label=True)
    w, h = geometry.width, geometry.height
    gaps = rng.exponential(mean_dt_us, n)
    gaps[rng.random(n) < 0.3] = 0  # bursts: equal timestamps
    t = t0_us + np.cumsum(gaps).astype(np.int64)
    kind = rng.choice(3, size=n, p=[0.6, 0.3, 0.1]).astype(np.uint8)
    if hot_pixels == 0:
        kind[kind == NoiseClass.HOT_PIXEL] = NoiseClass.BACKGROUND
    x = rng.integers(0, w, n)
    y = rng.integers(0, h, n)
    # signal: a blob wandering over the sensor, so neighbours support each other
    cx = (np.sin(t * 2e-5) * 0.5 + 0.5) * (w - 1)
    cy = (np.cos(t * 1.3e-5) * 0.5 + 0.5) * (h - 1)
    sig = kind == NoiseClass.SIGNAL
    x[sig] = np.clip(np.round(cx[sig] + rng.normal(0, 1.5, sig.sum())), 0, w - 1)
    y[sig] = np.clip(np.round(cy[sig] + rng.normal(0, 1.5, sig.sum())), 0, h - 1)
    hot = kind == NoiseClass.HOT_PIXEL
    hx = rng.choice([0, w - 1, rng.integers(0, w)], size=max(hot_pixels, 1))
    hy = rng.choice([0, h - 1, rng.integers(0, h)], size=max(hot_pixels, 1))
    pick = rng.integers(0, len(hx), hot.sum())
    x[hot], y[hot] = hx[pick], hy[pick]
    border = rng.random(n) < 0.05
    x[border] = rng.choice([0, w - 1], border.sum())
    p = rng.integers(0, 2, n)
    return EventChunk.from_arrays(t, x, y, p, geometry, label=kind)


def random_bounds(seed, n: int, *, max_chunks: int = 12) -> list[int]:
    """Chunk boundaries 0 = b0 <= b1 <= ... = n, with empty and one-event chunks likely."""
    rng = _rng(seed)
    k = int(rng.integers(1, max_chunks + 1))
    cuts = np.sort(rng.integers(0, n + 1, k - 1)) if n else np.zeros(k - 1, int)
    extra = []
    if n >= 2:  # force a one-event chunk somewhere
        i = int(rng.integers(0, n - 1))
        extra = [i, i + 1]
    return sorted({0, n, *map(int, cuts), *extra}) + ([n] if rng.random() < 0.3 else [])


def split(stream: EventChunk, bounds: Sequence[int]) -> list[EventChunk]:
    """Cut a stream at `bounds`; each piece carries the tight watermark a source would give it."""
    return [stream[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def one_event_chunks(stream: EventChunk) -> list[EventChunk]:
    return split(stream, list(range(len(stream) + 1)))


def classify_all(stage, chunks: Sequence[EventChunk]) -> np.ndarray:
    """Run a stage over chunks in order; return the concatenated `cls`."""
    outs = [stage(c) for c in chunks]
    return concat(outs, chunks[0].geometry).classes() if outs else np.zeros(0, np.uint8)


Apply = Callable[[object, Sequence[EventChunk]], object]


def _compare(a, b, what: str) -> None:
    if isinstance(a, np.ndarray):
        if a.shape != b.shape or a.dtype != b.dtype or not np.array_equal(a, b):
            diff = np.flatnonzero(a != b) if a.shape == b.shape else "shape " + str((a.shape, b.shape))
            raise AssertionError(f"{what}: outputs differ (first differing positions: {diff[:10]})")
    elif isinstance(a, list):
        assert_frames_equal(a, b, what)
    else:
        raise TypeError(f"cannot compare {type(a)}")


def assert_chunk_invariant(
    make: Callable[[], object],
    stream: EventChunk,
    seed=0,
    *,
    apply: Apply = classify_all,
    splits: int = 3,
    one_event: bool = True,
) -> None:
    """The output for `stream` in one chunk equals the output for random splits (and one-event
    chunks), bit for bit. `apply(fresh_instance, chunks)` returns an array or a list of frames."""
    rng = _rng(seed)
    whole = apply(make(), [stream])
    for _ in range(splits):
        bounds = random_bounds(rng, len(stream))
        _compare(whole, apply(make(), split(stream, bounds)), f"split at {bounds}")
    if one_event and len(stream):
        _compare(whole, apply(make(), one_event_chunks(stream)), "one-event chunks")


def _other_future(stream: EventChunk, rng) -> tuple[int, EventChunk]:
    """A random cut m and the stream with everything after its first m events replaced."""
    n = len(stream)
    m = int(rng.integers(1, n))
    other = random_stream(rng, n - m, stream.geometry, t0_us=int(stream.t[m - 1]))
    return m, concat([stream[:m], other])


def assert_causal(make: Callable[[], object], stream: EventChunk, seed=0) -> None:
    """Decisions for a prefix do not change when the events after it are replaced by others."""
    if len(stream) < 2:
        return
    m, altered = _other_future(stream, _rng(seed))
    a = classify_all(make(), [stream])[:m]
    b = classify_all(make(), [altered])[:m]
    _compare(a, b, f"prefix of {m} events with a different future")


def state_nbytes(obj, _seen=None) -> int:
    """Bytes held by an object's numpy arrays and containers, recursively (for the memory bound)."""
    seen = _seen if _seen is not None else set()
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, (list, tuple, set)) or type(obj).__name__ == "deque":
        return 8 * len(obj) + sum(state_nbytes(v, seen) for v in obj)
    if isinstance(obj, dict):
        return sum(state_nbytes(v, seen) for v in obj.values())
    # an object's attributes: its __dict__ and its classes' __slots__ (a slotted object has no __dict__)
    slots = [[k.__slots__] if isinstance(k.__slots__, str) else k.__slots__
             for k in type(obj).__mro__ if "__slots__" in vars(k)]
    held = [getattr(obj, name, None) for names in slots for name in names]
    return state_nbytes(getattr(obj, "__dict__", {}), seen) + sum(state_nbytes(v, seen) for v in held)


def assert_bounded_state(
    make: Callable[[], object],
    stream_of_length: Callable[[int], EventChunk],
    *,
    n: int = 2000,
    factor: int = 8,
    chunk: int = 257,
    feed: Callable[[object, EventChunk], object] | None = None,
    slack: float = 1.25,
) -> None:
    """State after a stream `factor` times longer (same event rate) stays within `slack` of the state
    after the short one: memory grows with the window and the sensor, not with the stream."""
    feed = feed or (lambda obj, c: obj(c))

    def peak(length):
        obj = make()
        stream = stream_of_length(length)
        most = state_nbytes(obj)
        for a in range(0, len(stream), chunk):
            feed(obj, stream[a : a + chunk])
            most = max(most, state_nbytes(obj))
        return most

    short, long = peak(n), peak(n * factor)
    if long > short * slack + 4096:
        raise AssertionError(f"state grows with stream length: {short} B after {n} events, "
                             f"{long} B after {n * factor}")


# -- framers -------------------------------------------------------------------------------------
def frames_of(framer, chunks: Sequence[EventChunk]) -> list[Frame]:
    """Push chunks through a framer and finish it; every frame produced, in order."""
    out = []
    for c in chunks:
        out.extend(framer.push(c))
    out.extend(framer.finish())
    return out


def assert_frames_equal(a: list[Frame], b: list[Frame], what: str = "frames") -> None:
    if len(a) != len(b):
        raise AssertionError(f"{what}: {len(a)} frames vs {len(b)}")
    for i, (fa, fb) in enumerate(zip(a, b)):
        same = (fa.t_start, fa.t_end, fa.n_events) == (fb.t_start, fb.t_end, fb.n_events)
        da, db = getattr(fa, "data", None), getattr(fb, "data", None)  # representations: their arrays too
        same_data = (da is None) == (db is None) and (da is None or (da.dtype == db.dtype and np.array_equal(da, db)))
        if not same or not same_data or not np.array_equal(fa.counts, fb.counts):
            raise AssertionError(
                f"{what}: frame {i} differs: ({fa.t_start}, {fa.t_end}, {fa.n_events}) vs "
                f"({fb.t_start}, {fb.t_end}, {fb.n_events})"
            )


def assert_framer_causal(make: Callable[[], object], stream: EventChunk, seed=0, *, cuts: int = 3) -> None:
    """The frames a framer emits once fed a prefix (its watermark the prefix's last event) are the
    first frames of its output for the whole stream, in one chunk, whatever events come after the
    prefix: a framer that peeks at later events in its chunk, or emits a frame before the watermark
    has closed it, differs from its own prefix output for one future or another. `cuts` random
    prefixes, each with a different future."""
    if len(stream) < 2:
        return
    rng = _rng(seed)
    own = frames_of(make(), [stream])
    for _ in range(cuts):
        m, altered = _other_future(stream, rng)
        early = make().push(stream[:m].replace(t_end=int(stream.t[m - 1])))
        for name, whole in (("its own future", own), ("a different future", frames_of(make(), [altered]))):
            assert_frames_equal(whole[: len(early)], early,
                                f"first frames of the whole stream with {name} vs those emitted after {m} events")


def assert_cameras_independent(make: Callable[[], object], streams: Sequence[EventChunk], seed=0, *,
                               framer: bool = False) -> None:
    """Several cameras, each with its own `make()` instance (a stage, or a framer if `framer`), fed
    interleaved chunks as a live subscriber does: each camera's output equals that camera's run
    alone, bit for bit. Catches state shared between instances (a class attribute, a module
    global, one object handed to every camera)."""
    rng = _rng(seed)
    pieces = [split(s, random_bounds(rng, len(s))) for s in streams]

    def step(obj, c):
        return obj.push(c) if framer else [obj(c).classes()]

    def result(obj, parts):
        if framer:
            return [*parts, *obj.finish()]
        return np.concatenate(parts) if parts else np.zeros(0, np.uint8)

    alone = []
    for chunks in pieces:
        obj = make()
        alone.append(result(obj, [out for c in chunks for out in step(obj, c)]))
    objs = [make() for _ in streams]
    outs: list[list] = [[] for _ in streams]
    done = [0] * len(streams)
    order = [k for k, chunks in enumerate(pieces) for _ in chunks]
    rng.shuffle(order)
    for k in order:  # cameras interleaved at random, each camera's own chunks in order
        outs[k].extend(step(objs[k], pieces[k][done[k]]))
        done[k] += 1
    for k in range(len(streams)):
        _compare(alone[k], result(objs[k], outs[k]), f"camera {k} of {len(streams)} vs the same camera alone")
