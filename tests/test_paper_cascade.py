"""The paper's cascade: numba kernels against plain-Python brute force, invariants, parameters."""

import math
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream.denoise import timeseries
from evstream.denoise.cascade import PaperCascade
from evstream.denoise.density import EXPIRE_GROUP, DensityFilter, _head_group, reference_head_group
from evstream.denoise.timeseries import TimeSeriesFilter
from evstream.events import EventChunk, Geometry, NoiseClass
from evstream.jit import njit
from evstream.testing import (
    assert_bounded_state,
    assert_causal,
    assert_chunk_invariant,
    classify_all,
    random_bounds,
    random_stream,
    split,
    state_nbytes,
)

G = Geometry(24, 18)


# -- plain-Python references ------------------------------------------------------------------------
def density_reference(s: EventChunk, f: DensityFilter):
    """Brute force: for each event, scan every earlier event."""
    r, w, h = f.radius_px, s.geometry.width, s.geometry.height
    L = 2 * r + 1
    keep, score = [], []
    for m in range(len(s)):
        t, x, y, p = int(s.t[m]), int(s.x[m]), int(s.y[m]), int(s.p[m])
        in_window = [j for j in range(m) if t - f.window_us < s.t[j] <= t]
        g = sum(1 for j in in_window if not f.match_polarity or s.p[j] == p)
        n = sum(1 for j in in_window
                if abs(int(s.x[j]) - x) <= r and abs(int(s.y[j]) - y) <= r and (not f.match_polarity or s.p[j] == p))
        if f.clip_border:
            area = (min(x + r, w - 1) - max(x - r, 0) + 1) * (min(y + r, h - 1) - max(y - r, 0) + 1)
        else:
            area = L * L
        if f.mode == "absolute":
            keep.append(n >= f.density_hz * area * f.window_us * 1e-6 - 1e-9)
            score.append(n / (area * f.window_us * 1e-6))
        else:
            gg = 2 * g if f.match_polarity else g
            keep.append(n >= max(1.0, f.rho_rel * area * gg / (w * h)))
            mean_count = area * gg / (w * h)  # the score: density relative to the sensor's mean
            score.append(n / mean_count if mean_count > 0 else (math.inf if n > 0 else 0.0))
    return np.array(keep, bool), np.array(score)


def dc_reference(s: EventChunk, f: TimeSeriesFilter):
    """Brute force: rebuild every pixel's set of active bins from all earlier events."""
    r, w, h, n = f.radius_px, s.geometry.width, s.geometry.height, f.n_bins
    active: dict[tuple[int, int], set[int]] = {}
    hot, score = [], []
    for m in range(len(s)):
        b = int(s.t[m]) // f.bin_us
        x, y = int(s.x[m]), int(s.y[m])
        active.setdefault((x, y), set()).add(b)

        def dc(px, b=b):
            return sum(1 for k in active.get(px, ()) if b - n < k <= b) / n

        nbs = [(x + dx, y + dy) for dy in range(-r, r + 1) for dx in range(-r, r + 1)
               if (dx, dy) != (0, 0) and 0 <= x + dx < w and 0 <= y + dy < h]
        mean = sum(dc(q) for q in nbs) / len(nbs) if nbs else 0.0
        d = dc((x, y))
        # the decision in whole bins, as exact as the definition: DC - mean > λ, DC > λ·mean
        own, nb_active = round(d * n), round(mean * len(nbs) * n)
        if f.form == "difference":
            hot.append(own * len(nbs) - nb_active > (f.lam * n) * len(nbs) if nbs else own > f.lam * n)
            score.append(d - mean)
        else:
            hot.append(own * len(nbs) > f.lam * nb_active if nb_active > 0 else own > f.lam)
            score.append(d / mean if mean > 0 else math.inf)
    return np.array(hot, bool), np.array(score)


density_params = st.fixed_dictionaries({
    "radius_px": st.integers(0, 3),
    "window_us": st.sampled_from([1, 50, 400, 3000]),
    "mode": st.sampled_from(["relative", "absolute"]),
    "density_hz": st.sampled_from([0.0, 500.0, 5000.0, 50_000.0]),
    "rho_rel": st.sampled_from([0.0, 0.5, 1.0, 3.0]),
    "match_polarity": st.booleans(),
    "clip_border": st.booleans(),
})

dc_params = st.fixed_dictionaries({
    "rate_hz": st.sampled_from([1000.0, 10_000.0, 250.0]),
    "n_bins": st.sampled_from([1, 7, 64, 200]),
    "lam": st.sampled_from([0.0, 0.05, 0.3, 0.5]),  # 0.5: ratio-form ties (own·n_nb = λ·active) occur
    "form": st.sampled_from(["difference", "ratio"]),
    "radius_px": st.integers(1, 2),
})


# numba's kernels raise on a division by zero (its "python" error model); as plain Python (tests/mutation.py)
# numpy only warns: here an error too
@pytest.mark.filterwarnings("error::RuntimeWarning")
@given(st.integers(0, 2**32), st.integers(0, 250), density_params)
def test_density_kernel_matches_brute_force(seed, n, params):
    s = random_stream(seed, n, G, mean_dt_us=30)
    f = DensityFilter(**params)
    keep, score = density_reference(s, f)
    parts = split(s, random_bounds(seed, n))
    got = [f.classify_scored(c) for c in parts]
    codes = np.concatenate([c for c, _ in got]) if got else np.zeros(0, np.uint8)
    scores = np.concatenate([sc for _, sc in got]) if got else np.zeros(0)
    assert np.array_equal(codes == NoiseClass.SIGNAL, keep)
    assert np.allclose(scores, score)
    _check_unscored_variants(lambda: DensityFilter(**params), s, seed, lambda sub: density_reference(sub, f)[0],
                             NoiseClass.BACKGROUND)
    if params["mode"] == "relative":  # kept iff the score reaches rho_rel (and N >= 1)
        assert np.array_equal(keep, (score >= params["rho_rel"] - 1e-9) & (score > 0))


def test_density_fifo_grows_past_its_initial_capacity():
    s = random_stream(1, 20_000, G, mean_dt_us=0.5)  # the whole stream fits in one window
    f = DensityFilter(window_us=10**9, mode="absolute", density_hz=0.0)
    codes, score = f.classify_scored(s)
    assert len(f._state["fifo_t"]) >= 20_000 and f._state["fifo_state"][1] == 20_000
    keep, ref = density_reference(s[:300], DensityFilter(window_us=10**9, mode="absolute", density_hz=0.0))
    assert np.allclose(score[:300], ref) and (codes == 0).all()


@pytest.mark.parametrize("far", [False, True])
@pytest.mark.parametrize("height", [32_687, 32_760])
def test_density_polarity_planes_on_the_tallest_sensors(height, far, monkeypatch):
    """With match_polarity the FIFO keeps an ON event's row plus height + 2r + 1 (up to 2·height + 2r): in 16
    bits up to 32,687 rows at r = 32, in 32 past that (at 32,760 rows the ON plane's last rows pass 65,535, and
    16 bits would wrap them onto the OFF plane's first). Events on the last rows, both polarities, with the
    head expiring: the brute force's classes and scores."""
    from evstream.denoise import density

    monkeypatch.setattr(density, "FAR_BYTES", 0 if far else 2**62)  # the map is 4 MB: `far` unless told not
    rng = np.random.default_rng(height)
    n = 300
    t = np.cumsum(rng.integers(0, 20, n))
    s = EventChunk.from_arrays(t, rng.integers(0, 3, n), rng.integers(height - 6, height, n), rng.integers(0, 2, n),
                               Geometry(3, height))
    make = lambda: DensityFilter(radius_px=32, window_us=400, match_polarity=True, rho_rel=0.02)  # noqa: E731
    keep, score = density_reference(s, make())
    f = make()
    got = [f.classify_scored(c) for c in split(s, [0, 100, n])]
    assert f._far == far
    assert np.array_equal(np.concatenate([c for c, _ in got]) == NoiseClass.SIGNAL, keep)
    assert np.allclose(np.concatenate([sc for _, sc in got]), score)
    assert 0 < keep.sum() < n  # both classes


def test_density_far_expiry_of_an_on_event_at_the_first_pixel(monkeypatch):
    """Over a far map with match_polarity and r = 0 an ON event at (0, 0) adds to the ON plane's first cell (its
    map position is the OFF plane's size): its expiry takes it off the ON events' count, as the brute force."""
    from evstream.denoise import density

    monkeypatch.setattr(density, "FAR_BYTES", 0)
    rng = np.random.default_rng(5)
    n = 300
    at_origin = rng.random(n) < 0.6
    x = np.where(at_origin, 0, rng.integers(0, G.width, n))
    y = np.where(at_origin, 0, rng.integers(0, G.height, n))
    p = np.where(at_origin, 1, rng.integers(0, 2, n))
    s = EventChunk.from_arrays(np.cumsum(rng.integers(0, 20, n)), x, y, p, G)
    f = DensityFilter(radius_px=0, window_us=100, match_polarity=True, rho_rel=0.5)
    keep, score = density_reference(s, f)
    codes, got = f.classify_scored(s)
    assert f._far
    assert np.array_equal(codes == NoiseClass.SIGNAL, keep) and np.allclose(got, score)


@pytest.mark.parametrize("far", [False, True])
@pytest.mark.parametrize("t0_us", [2**53 + 1, 2**62])
def test_density_classes_do_not_depend_on_the_clock_offset(t0_us, far, monkeypatch):
    """Windows are exact in whole µs at any time: the same stream from t0 (past float64's whole numbers)
    gets the classes and scores it gets from 0."""
    from evstream.denoise import density

    monkeypatch.setattr(density, "FAR_BYTES", 0 if far else density.FAR_BYTES)
    make = lambda: DensityFilter(window_us=400)  # noqa: E731
    s = random_stream(4, 600, G, mean_dt_us=10)
    want_codes, want_score = make().classify_scored(s)
    codes, score = make().classify_scored(s.replace(t=s.t + t0_us))
    assert np.array_equal(codes, want_codes) and np.array_equal(score, want_score)
    assert 0 < np.count_nonzero(codes) < 600  # both classes


@pytest.mark.parametrize("far", [False, True])
def test_density_map_widens_before_a_row_holds_more_events_than_its_cells(far):
    """70,000 events on one pixel, all in one window: the event m counts m earlier ones, past the uint16
    cells' 65,535 (they would wrap to m - 65,536 unless the map widens to int32 first), chunked or not."""
    from evstream.denoise import density

    n = 70_000
    s = EventChunk.from_arrays(np.arange(n) // 8, np.full(n, 3), np.full(n, 2), np.ones(n), G)
    saved = density.FAR_BYTES
    density.FAR_BYTES = 0 if far else saved
    try:
        for bounds in ([0, n], [0, 30_000, 65_534, 65_536, n]):
            f = DensityFilter(window_us=10**9, mode="absolute", density_hz=0.0)
            score = np.concatenate([f.classify_scored(c)[1] for c in split(s, bounds)])
            assert f._far == far and f._state["hsum"].dtype == np.int32
            assert np.array_equal(np.rint(score * 25 * 1e3), np.arange(n))  # N(m) / (L² · Δt), Δt = 1000 s
    finally:
        density.FAR_BYTES = saved


@given(st.integers(0, 2**32), st.integers(0, 250), density_params, st.booleans())
def test_density_kernel_widening_its_map_matches_brute_force(seed, n, params, far):
    """With the uint16 cells' row limit lowered to 3 events, the map widens within a call or between calls
    at any point: every variant still matches the reference (the widened cells are the same counts)."""
    from evstream.denoise import density

    saved = density.UINT8_CELL_MAX, density.FAR_BYTES
    density.UINT8_CELL_MAX = 3
    density.FAR_BYTES = 0 if far else saved[1]
    try:
        test_density_kernel_matches_brute_force.hypothesis.inner_test(seed, n, params)
    finally:
        density.UINT8_CELL_MAX, density.FAR_BYTES = saved


@pytest.mark.parametrize("record", [1, 2])
@pytest.mark.parametrize("head, size", [(0, 0), (0, 8), (5, 8), (7, 8), (3, 5), (6, 2)])
def test_grow_fifo_unrolls_a_wrapped_ring_from_its_head(head, size, record):
    from evstream.denoise.base import grow_fifo

    cap = 8
    ring = np.arange(100, 100 + cap * record, dtype=np.int64)
    state = {"a": ring.copy(), "b": ring.astype(np.uint16), "fifo_state": np.array([head, size, 9])}
    grow_fifo(state, ("a", "b"), record=record)
    slots = [(head + k) % cap for k in range(size)]
    want = [int(ring[q * record + c]) for q in slots for c in range(record)]
    for k in ("a", "b"):
        assert len(state[k]) == 2 * cap * record and state[k].dtype == (np.int64 if k == "a" else np.uint16)
        assert state[k][: size * record].tolist() == want and not state[k][size * record :].any()
    assert state["fifo_state"].tolist() == [0, size, 9]


def test_dc_activation_fifo_grows_past_its_initial_capacity():
    # 9,000 events on 432 pixels within one window of 200 bins: ~8,000 activations held at once
    s = random_stream(2, 9_000, G, mean_dt_us=0.02)
    make = lambda: TimeSeriesFilter(rate_hz=1e6, n_bins=200, lam=0.05)  # noqa: E731
    f = make()
    got = np.concatenate([f.classify_scored(c)[1] for c in split(s, [0, 3_000, 9_000])])
    assert len(f._state["fifo_pos"]) > 4096 and f._state["fifo_state"][1] > 4096
    assert np.allclose(got, dc_reference(s, make())[1])


@given(st.integers(0, 2**32), st.integers(0, 250), dc_params)
def test_dc_kernel_matches_brute_force(seed, n, params):
    s = random_stream(seed, n, G, mean_dt_us=params["n_bins"] * 1e6 / params["rate_hz"] / 40)
    f = TimeSeriesFilter(**params)
    hot, score = dc_reference(s, f)
    got = [f.classify_scored(c) for c in split(s, random_bounds(seed, n))]
    codes = np.concatenate([c for c, _ in got]) if got else np.zeros(0, np.uint8)
    scores = np.concatenate([sc for _, sc in got]) if got else np.zeros(0)
    assert np.array_equal(codes == NoiseClass.HOT_PIXEL, hot)
    assert np.allclose(scores, score)
    _check_unscored_variants(lambda: TimeSeriesFilter(**params), s, seed, lambda sub: ~dc_reference(sub, f)[0],
                             NoiseClass.HOT_PIXEL)


@given(st.integers(0, 2**32), st.integers(0, 250), density_params, dc_params)
def test_prefetching_kernels_match_brute_force(seed, n, coarse, fine):
    """Over a map larger than the L2 cache (`FAR_BYTES`, here 0) the kernels prefetch: every variant
    (scored, class-only, after an earlier stage) still matches the references."""
    from evstream.denoise import density, timeseries

    saved = density.FAR_BYTES, timeseries.FAR_BYTES
    density.FAR_BYTES = timeseries.FAR_BYTES = 0
    try:
        test_density_kernel_matches_brute_force.hypothesis.inner_test(seed, n, coarse)
        test_dc_kernel_matches_brute_force.hypothesis.inner_test(seed, n, fine)
        d, f = DensityFilter(**coarse), TimeSeriesFilter(**fine)
        d(random_stream(seed, 3, G))
        f(random_stream(seed, 3, G))
        assert d._far and f._options[-1]
    finally:
        density.FAR_BYTES, timeseries.FAR_BYTES = saved


def _check_unscored_variants(make, s, seed, keep_of, noise_code):
    """The kernel variants compiled without the score (`classify`, `stage(chunk)`) and for chunks where
    an earlier stage already classed some events noise, each against the brute-force reference
    (`keep_of(sub-stream)` -> kept mask): every compiled variant is compared, not only the scored one."""
    bounds = random_bounds(seed, len(s))
    f = make()
    plain = [f.classify(c) for c in split(s, bounds)]
    plain = np.concatenate(plain) if plain else np.zeros(0, np.uint8)
    assert np.array_equal(plain, np.where(keep_of(s), NoiseClass.SIGNAL, noise_code).astype(np.uint8))
    dead = np.random.default_rng(seed).random(len(s)) < 0.3  # classed noise by an earlier stage
    earlier = NoiseClass.BACKGROUND if noise_code == NoiseClass.HOT_PIXEL else NoiseClass.HOT_PIXEL
    pre = s.replace(cls=np.where(dead, earlier, NoiseClass.SIGNAL).astype(np.uint8))
    want = pre.cls.copy()
    live = np.flatnonzero(~dead)
    want[live] = np.where(keep_of(s[live]), NoiseClass.SIGNAL, noise_code)
    assert np.array_equal(classify_all(make(), split(pre, bounds)) if len(s) else want, want)


def test_dc_bins_are_anchored_at_time_zero_not_at_the_chunk():
    # two events 1 µs apart straddling a bin edge fall in different bins wherever the chunk starts
    g = Geometry(3, 3)
    ev = EventChunk.from_arrays([3999, 4000], [1, 1], [1, 1], [1, 1], g)
    f = TimeSeriesFilter(rate_hz=250.0, n_bins=2, lam=0.0)
    _, score = f.classify_scored(ev)
    assert score.tolist() == [0.5, 1.0]  # bins 0 and 1: the second event sees two active bins of two


@pytest.mark.parametrize("idle_bins", [256, 512, 2**32])
def test_dc_sees_a_pixel_idle_for_a_multiple_of_256_bins_as_newly_active(idle_bins):
    # the last active bin is kept modulo 256: an equal residue after a long idle must not hide the activation
    g = Geometry(3, 3)
    t0 = idle_bins
    ev = EventChunk.from_arrays([0, t0, t0 + 1, t0 + 3], [1, 1, 0, 1], [1, 1, 0, 1], [1, 1, 1, 1], g)
    f = TimeSeriesFilter(rate_hz=1e6, n_bins=4, lam=0.0)
    _, score = f.classify_scored(ev)
    assert np.allclose(score, dc_reference(ev, TimeSeriesFilter(rate_hz=1e6, n_bins=4, lam=0.0))[1])
    assert score[1] == 0.25 and score[3] == 0.5 - 1 / 4 / 8  # one then two active bins of four


def test_dc_with_255_bins_counts_a_pixel_active_in_every_bin():
    # n = 255, the most the one-byte count holds: a pixel firing in every bin reaches DC 1, and its
    # bin residues wrap past 255 while it stays active
    g = Geometry(3, 3)
    t = np.arange(600)
    ev = EventChunk.from_arrays(t, np.ones(600), np.ones(600), np.ones(600), g)
    f = TimeSeriesFilter(rate_hz=1e6, n_bins=255, lam=0.0)
    _, score = f.classify_scored(ev)
    assert np.allclose(score, dc_reference(ev, TimeSeriesFilter(rate_hz=1e6, n_bins=255, lam=0.0))[1])
    assert score[254] == 1.0 and score[599] == 1.0


@pytest.mark.parametrize("n_bins, sums", [(85, np.uint8), (86, np.uint16)])
def test_dc_row_sums_hold_three_pixels_active_in_every_bin(n_bins, sums):
    """Row sums of one byte while 3 · n <= 255: three neighbours active in every bin take a row sum to 3 · n
    (255 at n = 85, exact in a byte; 258 at n = 86, in two), and the middle row's pixel sees them all."""
    g = Geometry(5, 3)
    t = np.repeat(np.arange(300), 4)
    x, y = np.tile([1, 2, 3, 2], 300), np.tile([1, 1, 1, 0], 300)  # a full row of three, and one above it
    ev = EventChunk.from_arrays(t, x, y, np.ones(len(t)), g)
    f = TimeSeriesFilter(rate_hz=1e6, n_bins=n_bins, lam=0.0)
    _, score = f.classify_scored(ev)
    assert f._state["rowsum"].dtype == sums and f._state["rowsum"].max() == 3 * n_bins
    assert np.allclose(score, dc_reference(ev, TimeSeriesFilter(rate_hz=1e6, n_bins=n_bins, lam=0.0))[1])


@pytest.mark.parametrize("make", [
    lambda: DensityFilter(window_us=500), lambda: DensityFilter(mode="absolute", window_us=2000),
    lambda: DensityFilter(match_polarity=True, clip_border=True, window_us=300),
    lambda: TimeSeriesFilter(rate_hz=10_000.0), lambda: PaperCascade(coarse={"window_us": 800},
                                                                    fine={"rate_hz": 5000.0}),
])
@given(seed=st.integers(0, 2**32))
def test_invariants(make, seed):
    s = random_stream(seed, 400, G)
    assert_chunk_invariant(make, s, seed)
    assert_causal(make, s, seed)


def test_cascade_over_far_maps_is_chunk_invariant_and_causal(monkeypatch):
    from evstream.denoise import density

    monkeypatch.setattr(density, "FAR_BYTES", 0)
    monkeypatch.setattr(timeseries, "FAR_BYTES", 0)
    make = lambda: PaperCascade(coarse={"window_us": 800}, fine={"rate_hz": 5000.0})  # noqa: E731
    for seed in range(8):
        s = random_stream(seed, 400, G)
        assert_chunk_invariant(make, s, seed)
        assert_causal(make, s, seed)
    f = make()
    f(random_stream(0, 3, G))
    assert f.density._far


@pytest.mark.parametrize("make", [lambda: DensityFilter(window_us=500), lambda: TimeSeriesFilter(),
                                  lambda: PaperCascade()])
def test_state_is_bounded(make):
    assert_bounded_state(make, lambda n: random_stream(0, n, G), n=3000)


@pytest.mark.parametrize("far", [False, True])
@pytest.mark.parametrize("options, fine_options", [({}, {}),
                                                   ({"match_polarity": True, "clip_border": True}, {"form": "ratio"}),
                                                   ({"mode": "absolute", "density_hz": 8000.0}, {})])
def test_cascade_feeds_the_fine_stage_only_what_the_coarse_stage_kept(far, options, fine_options, monkeypatch):
    """Over maps larger than the L2 cache (`FAR_BYTES`, here 0 when `far`) too, and with the stages' options
    that use each argument the cascade's kernel passes on (polarity planes, absolute mode, ratio form), the
    cascade's one kernel gives the stages' classes one after the other."""
    from evstream.denoise import density

    if far:
        monkeypatch.setattr(density, "FAR_BYTES", 0)
        monkeypatch.setattr(timeseries, "FAR_BYTES", 0)
    s = random_stream(5, 3000, G)
    cascade = PaperCascade(coarse={"window_us": 1000, **options}, fine={"rate_hz": 5000.0, **fine_options})
    got = classify_all(cascade, [s])
    coarse = DensityFilter(window_us=1000, **options)(s)
    fine = TimeSeriesFilter(rate_hz=5000.0, **fine_options)
    kept = np.flatnonzero(coarse.cls == 0)
    expected = coarse.cls.copy()
    expected[kept] = fine.classify(s[kept])
    assert np.array_equal(got, expected)
    assert set(np.unique(got)) <= {0, 1, 2}
    codes, score = PaperCascade(coarse={"window_us": 1000, **options},
                                fine={"rate_hz": 5000.0, **fine_options}).classify_scored(s)
    assert np.array_equal(codes, got)
    assert ((score >= 1) == (got == 0)).all()


@pytest.mark.parametrize("bounds", [[0, 12_000], [0, 3_000, 12_000]])
def test_cascade_grows_both_fifos_within_one_call_with_the_same_classes(bounds):
    """The cascade's kernel stops when either stage's FIFO is full; the stage grows it and the call goes on
    where it stopped (the coarse stage from its next event, the fine one without gathering again)."""
    s = random_stream(3, 12_000, G, mean_dt_us=0.02)  # one coarse window, > 4,096 fine activations held at once
    coarse, fine = {"window_us": 10**6, "rho_rel": 0.1}, {"rate_hz": 1e6, "n_bins": 200, "lam": 0.05}
    cascade = PaperCascade(coarse=coarse, fine=fine)
    got = np.concatenate([cascade(c).cls for c in split(s, bounds)])
    assert len(cascade.density._state["fifo_t"]) > 4096 and len(cascade.timeseries._state["fifo_pos"]) > 4096
    one_by_one = TimeSeriesFilter(**fine)(DensityFilter(**coarse)(s)).cls  # the stages as a pipeline runs them
    assert np.array_equal(got, one_by_one)
    assert np.all(np.bincount(got, minlength=3) > 0)


def test_cascade_keeps_no_long_chunk_buffer():
    """After a chunk longer than the fine stage's kept live buffer (KEPT_LIVE events), the cascade holds what
    it held after short chunks: neither the stage nor the cascade's bound kernel call keeps the long one's."""
    s = random_stream(4, 40_000, G, mean_dt_us=20)
    short, long = PaperCascade(), PaperCascade()
    for c in split(s, list(range(0, 40_001, 5_000))):
        short(c)
    long(s)
    assert timeseries.KEPT_LIVE < len(s) and state_nbytes(long) <= state_nbytes(short)


@given(seed=st.integers(0, 2**32), block=st.integers(1, 700), earlier=st.booleans())
def test_a_chunk_larger_than_a_block_gets_the_same_classes(seed, block, earlier):
    """A chunk longer than `block_events` runs through both stages block by block: same classes."""
    s = random_stream(seed, 1500, G)
    if earlier:  # an earlier stage already classed some events noise
        dead = np.random.default_rng(seed).random(len(s)) < 0.3
        s = s.replace(cls=np.where(dead, NoiseClass.HOT_PIXEL, NoiseClass.SIGNAL).astype(np.uint8))
    make = lambda: PaperCascade(coarse={"window_us": 800}, fine={"rate_hz": 5000.0})  # noqa: E731
    blocked = make()
    blocked.block_events = block
    assert np.array_equal(blocked(s).cls, make()(s).cls)


@given(seed=st.integers(0, 2**32), block=st.integers(1, 700), earlier=st.booleans())
def test_the_fine_stage_judges_a_long_chunk_block_by_block_with_the_same_result(seed, block, earlier):
    from evstream.denoise import timeseries

    s = random_stream(seed, 1500, G)
    if earlier:
        dead = np.random.default_rng(seed).random(len(s)) < 0.3
        s = s.replace(cls=np.where(dead, NoiseClass.BACKGROUND, NoiseClass.SIGNAL).astype(np.uint8))
    make = lambda: TimeSeriesFilter(rate_hz=5000.0, n_bins=40)  # noqa: E731
    whole, whole_scored = make()(s).cls, make().classify_scored(s)
    saved, timeseries.BLOCK_EVENTS = timeseries.BLOCK_EVENTS, block
    try:
        blocked, blocked_scored = make()(s).cls, make().classify_scored(s)
    finally:
        timeseries.BLOCK_EVENTS = saved
    assert np.array_equal(blocked, whole)
    assert np.array_equal(blocked_scored[0], whole_scored[0]) and np.array_equal(blocked_scored[1], whole_scored[1])


@pytest.mark.parametrize("make", [lambda: DensityFilter(window_us=500), lambda: TimeSeriesFilter(rate_hz=5000.0)])
def test_after_an_earlier_stage_each_stage_judges_only_the_live_events(make):
    from evstream.denoise.refractory import RefractoryFilter

    s = random_stream(9, 2000, G)
    first = RefractoryFilter(refractory_us=200)(s)
    assert (first.cls != 0).any()
    live = np.flatnonzero(first.cls == 0)
    want = first.cls.copy()
    want[live] = make().classify(s[live])
    assert np.array_equal(make()(first).cls, want)


def test_hot_pixels_are_found_and_signal_kept_on_a_synthetic_scene():
    from evstream.noise import NoiseSpec, inject
    from evstream.synth import scene

    g = Geometry(96, 72)
    sig = scene("turntable", g, duration_us=600_000, seed=3)
    noisy = inject(sig, NoiseSpec(ba_rate_hz=1.0, hot_pixels=12, hot_rate_hz=(200, 2000)), seed=4,
                   t_start_us=0, t_stop_us=600_000)
    cascade = PaperCascade()
    cls = cascade(noisy).cls
    warm = noisy.t >= cascade.history_us
    lab = noisy.label[warm]
    cls = cls[warm]
    assert (cls[lab == NoiseClass.SIGNAL] == NoiseClass.SIGNAL).mean() > 0.95
    assert (cls[lab == NoiseClass.HOT_PIXEL] != NoiseClass.SIGNAL).mean() > 0.99
    assert (cls[lab == NoiseClass.BACKGROUND] != NoiseClass.SIGNAL).mean() > 0.8


_RADIUS = "radius_px must be an integer in 0..32 (L = 2r + 1 is odd), got "
_WINDOW = "window_us must be a positive whole number of µs, got "


@pytest.mark.parametrize("bad, message", [
    ({"radius_px": -1}, _RADIUS + "-1"), ({"radius_px": 1.5}, _RADIUS + "1.5"), ({"radius_px": True}, _RADIUS + "True"),
    ({"radius_px": 100_000}, _RADIUS + "100000"), ({"window_us": 0}, _WINDOW + "0"),
    ({"window_us": 1.5}, _WINDOW + "1.5"), ({"window_us": "20ms"}, _WINDOW + "'20ms'"),
    ({"mode": "fuzzy"}, "mode must be 'relative' or 'absolute', got 'fuzzy'"),
    ({"density_hz": -1}, "density_hz must be a finite number >= 0, got -1"),
    ({"density_hz": float("inf")}, "density_hz must be a finite number >= 0, got inf"),
    ({"rho_rel": float("nan")}, "rho_rel must be a finite number >= 0, got nan"),
    ({"rho_rel": -1}, "rho_rel must be a finite number >= 0, got -1"),
    ({"rho_rel": float("inf")}, "rho_rel must be a finite number >= 0, got inf"),
])
def test_density_rejects_bad_parameters(bad, message):
    """Each check refuses its bad value with the whole message, the value as given."""
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        DensityFilter(**bad)


@pytest.mark.parametrize("make", [DensityFilter, TimeSeriesFilter])
def test_a_stage_keeps_its_state_when_a_chunk_brings_an_equal_geometry(make):
    """A source may make a new Geometry per chunk: equal sizes are the same sensor, so the state goes on."""
    s = random_stream(3, 400, G, mean_dt_us=30)
    whole = make().classify_scored(s)[1]
    f = make()
    first = f.classify_scored(s[:200])[1]
    second = f.classify_scored(s[200:].replace(geometry=Geometry(G.width, G.height)))[1]
    assert np.allclose(np.concatenate([first, second]), whole)


@pytest.mark.parametrize("make", [DensityFilter, TimeSeriesFilter])
def test_a_stage_starts_afresh_on_a_chunk_from_another_sensor(make):
    """A chunk of another Geometry (a smaller sensor, its events within a window of the last) is judged as a
    fresh stage judges it: the state is rebuilt for the new sensor, nothing of the old one counts."""
    s = random_stream(3, 300, G, mean_dt_us=10)
    other = random_stream(4, 300, Geometry(20, 16), t0_us=int(s.t[-1]), mean_dt_us=10)
    f = make()
    f.classify_scored(s)
    codes, score = f.classify_scored(other)
    want_codes, want_score = make().classify_scored(other)
    assert np.array_equal(codes, want_codes) and np.allclose(score, want_score)


_RATE = "rate_hz must divide 1 MHz (bins of whole µs), got "
_BINS = "n_bins must be an integer in 1..255 (a uint8 count per pixel), got "
_LAM = "lam must be in [0, 1) for the difference form, >= 0 for ratio; got "
_DC_RADIUS = "radius_px must be an integer in 1..32, got "


@pytest.mark.parametrize("bad, message", [
    ({"rate_hz": 0}, _RATE + "0"), ({"rate_hz": 3.0}, _RATE + "3.0"), ({"rate_hz": float("inf")}, _RATE + "inf"),
    ({"n_bins": 256}, _BINS + "256"), ({"n_bins": 0}, _BINS + "0"), ({"n_bins": 64.0}, _BINS + "64.0"),
    ({"n_bins": True}, _BINS + "True"), ({"lam": 1.5}, _LAM + "1.5"), ({"lam": -0.1}, _LAM + "-0.1"),
    ({"lam": -0.1, "form": "ratio"}, _LAM + "-0.1"), ({"lam": float("nan"), "form": "ratio"}, _LAM + "nan"),
    ({"form": "sum"}, "form must be 'difference' or 'ratio', got 'sum'"), ({"radius_px": 0}, _DC_RADIUS + "0"),
    ({"radius_px": 200, "n_bins": 200}, _DC_RADIUS + "200"), ({"radius_px": True}, _DC_RADIUS + "True"),
    ({"radius_px": 33}, _DC_RADIUS + "33"),
])
def test_dc_rejects_bad_parameters(bad, message):
    """Each check refuses its bad value with the whole message, the value as given."""
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        TimeSeriesFilter(**bad)


def test_absolute_threshold_as_a_count():
    assert DensityFilter(mode="absolute").n_threshold == 5  # 10 Hz · 25 px · 20 ms
    assert DensityFilter(mode="absolute", radius_px=1, window_us=10_000).n_threshold == 1


@pytest.mark.parametrize("coarse", [{"window_us": 1000}, {"mode": "absolute", "window_us": 2000},
                                    {"window_us": 1000, "rho_rel": 0.0}])
def test_cascade_score_is_the_coarse_reference_score_over_its_threshold(coarse):
    """The ROC score of the cascade: the coarse score over the coarse threshold in either mode, or the coarse
    score itself when that threshold is 0 (-1 where the fine stage calls the event hot), beside the
    cascade's own uint8 class codes."""
    s = random_stream(4, 600, G)
    codes, score = PaperCascade(coarse=coarse, fine={"rate_hz": 5000.0}).classify_scored(s)
    assert codes.dtype == np.uint8
    assert np.array_equal(codes, PaperCascade(coarse=coarse, fine={"rate_hz": 5000.0}).classify(s))
    d = DensityFilter(**coarse)
    threshold = d.density_hz if d.mode == "absolute" else d.rho_rel
    hot = codes == NoiseClass.HOT_PIXEL
    assert hot.any() and (score[hot] == -1).all()
    want = density_reference(s, d)[1][~hot]
    assert np.allclose(score[~hot], want / threshold if threshold else want)


def test_dc_on_a_one_pixel_sensor_judges_the_pixel_by_its_own_activity():
    """A pixel with no neighbour (a 1x1 sensor) is hot when its own active bins pass λ·n, as the
    reference says; the neighbours' mean does not apply."""
    g1 = Geometry(1, 1)
    t = np.arange(0, 2_000_000, 997)
    ev = EventChunk.from_arrays(t, np.zeros(len(t)), np.zeros(len(t)), np.ones(len(t)), g1)
    f = TimeSeriesFilter(rate_hz=1000.0, lam=0.2)
    codes, score = f.classify_scored(ev)
    want_hot, want_score = dc_reference(ev, TimeSeriesFilter(rate_hz=1000.0, lam=0.2))
    assert (codes == NoiseClass.HOT_PIXEL).any()
    assert np.array_equal(codes == NoiseClass.HOT_PIXEL, want_hot) and np.allclose(score, want_score)


def _head_groups(fifo_t, fifo_x, fifo_y, heads, oldest, x0, y0, box, out):
    for k in range(len(heads)):
        out[k] = _head_group(fifo_t, fifo_x, fifo_y, heads[k], oldest[k], x0[k], y0[k], box[k])


if _head_group is not reference_head_group:  # the intrinsic (tests/mutation.py's copy binds the name to its twin)
    _head_groups = njit(_head_groups)


@pytest.mark.parametrize("xy", [np.uint16, np.int32])
def test_the_head_group_intrinsic_matches_its_plain_twin(xy):
    """`_head_group` (density's vector test of the FIFO's head group) against `reference_head_group` (the plain
    twin tests/mutation.py runs the kernel with): times on, before and after `oldest`; coordinates in, on the
    edges of and out of the box, boxes starting left of or above the sensor (x0, y0 down to -MAX_RADIUS_PX)."""
    rng = np.random.default_rng(3)
    cap, m = 4 * EXPIRE_GROUP, 500
    fifo_t = rng.integers(0, 40, cap).astype(np.int64)
    fifo_x, fifo_y = rng.integers(0, 12, cap).astype(xy), rng.integers(0, 12, cap).astype(xy)
    heads = rng.integers(0, cap // EXPIRE_GROUP, m) * EXPIRE_GROUP
    oldest = rng.integers(-1, 41, m)
    box = rng.choice([0, 2, 4, 10, 64], m)
    x0, y0 = rng.integers(-32, 12, m) - box // 2, rng.integers(-32, 12, m) - box // 2
    got, want = np.zeros(m, np.int64), np.zeros(m, np.int64)
    _head_groups(fifo_t, fifo_x, fifo_y, heads, oldest, x0, y0, box, got)
    for k in range(m):
        want[k] = reference_head_group(fifo_t, fifo_x, fifo_y, heads[k], oldest[k], x0[k], y0[k], box[k])
    assert np.array_equal(got, want)
    assert (want & 0xFFFFFFFF).min() == 0 and (want & 0xFFFFFFFF).max() == EXPIRE_GROUP and (want >> 32).any()


def test_a_stage_after_the_cascade_judges_only_the_events_it_kept():
    """A stage on the base `Classifier` path (a baseline) after the cascade classifies the events the cascade
    kept, and only those, keeping the cascade's classes for the others; a chunk the cascade rejected whole
    reaches it empty (it sees the watermark) and passes on unchanged."""
    from evstream.denoise.refractory import RefractoryFilter

    s = random_stream(9, 2000, G)
    first = PaperCascade(coarse={"window_us": 800}, fine={"rate_hz": 5000.0})(s)
    live = np.flatnonzero(first.cls == NoiseClass.SIGNAL)
    want = first.cls.copy()
    want[live] = RefractoryFilter(refractory_us=200).classify(s[live])
    assert 0 < len(live) < len(s) and (want[live] != NoiseClass.SIGNAL).any()
    assert np.array_equal(RefractoryFilter(refractory_us=200)(first).cls, want)
    gone = s.replace(cls=np.full(len(s), NoiseClass.BACKGROUND, np.uint8))
    out = RefractoryFilter(refractory_us=200)(gone)
    assert out.cls.dtype == np.uint8 and (out.cls == NoiseClass.BACKGROUND).all() and gone.cls is not out.cls


def test_a_baseline_scores_after_the_cascade_only_the_events_it_kept():
    """`scored` (the baselines' evaluation interface, as the cascade's): after the cascade, NaN for the events
    it rejected and the stage's own scores and classes for those it kept; on an unclassified chunk, the
    stage's `classify_scored` (uint8 codes) and `score` the same scores."""
    from evstream.denoise.refractory import RefractoryFilter

    s = random_stream(9, 2000, G)
    first = PaperCascade(coarse={"window_us": 800}, fine={"rate_hz": 5000.0})(s)
    live = first.cls == NoiseClass.SIGNAL
    out, scores = RefractoryFilter(refractory_us=200).scored(first)
    codes, want = RefractoryFilter(refractory_us=200).classify_scored(s[live])
    assert np.isnan(scores[~live]).all() and np.array_equal(scores[live], want)
    assert np.array_equal(out.cls[live], codes) and np.array_equal(out.cls[~live], first.cls[~live])
    assert (codes != NoiseClass.SIGNAL).any()
    out, scores = RefractoryFilter(refractory_us=200).scored(s)
    codes, want = RefractoryFilter(refractory_us=200).classify_scored(s)
    assert out.cls.dtype == np.uint8 and np.array_equal(out.cls, codes) and np.array_equal(scores, want)
    assert np.array_equal(RefractoryFilter(refractory_us=200).score(s), want)
