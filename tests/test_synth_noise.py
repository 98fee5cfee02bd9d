import numpy as np
import pytest

from evstream.events import Geometry, NoiseClass
from evstream.noise import NoiseSpec, inject
from evstream.synth import SensorModel, scene

G = Geometry(64, 48)


@pytest.mark.parametrize("name", ["turntable", "ball", "bar"])
def test_scene_events_are_valid_sorted_and_deterministic(name):
    a = scene(name, G, duration_us=200_000, seed=7)
    b = scene(name, G, duration_us=200_000, seed=7)
    assert len(a) > 500
    assert np.array_equal(a.t, b.t) and np.array_equal(a.x, b.x) and np.array_equal(a.p, b.p)
    assert (np.diff(a.t) >= 0).all()
    assert a.x.max() < G.width and a.y.max() < G.height
    assert (a.label == NoiseClass.SIGNAL).all()
    assert 0.3 < a.p.mean() < 0.7  # edges in both directions
    c = scene(name, G, duration_us=200_000, seed=8)
    assert not (len(c) == len(a) and np.array_equal(c.t, a.t))


def test_turntable_slows_down_and_ball_speeds_up():
    tt = scene("turntable", G, duration_us=400_000)
    first, last = np.bincount(tt.t // 200_000, minlength=2)[:2]
    assert first > 1.5 * last
    ball = scene("ball", G, duration_us=400_000)
    first, second = np.bincount(ball.t // 100_000, minlength=2)[:2]
    assert second > 1.5 * first


def test_refractory_period_is_respected():
    model = SensorModel(refractory_us=500)
    s = scene("bar", G, duration_us=300_000, model=model)
    pix = s.y.astype(np.int64) * G.width + s.x
    order = np.lexsort((s.t, pix))
    same = np.diff(pix[order]) == 0
    assert (np.diff(s.t[order])[same] >= 500).all()


def test_noise_ratio_is_met_and_labelled():
    sig = scene("bar", G, duration_us=300_000)
    noisy = inject(sig, NoiseSpec(noise_ratio=1.0, hot_share=0.2), seed=1)
    counts = noisy.class_counts("label")
    assert counts[0] == len(sig)
    assert counts[1] + counts[2] == pytest.approx(len(sig), rel=0.1)
    assert counts[2] == pytest.approx(0.2 * len(sig), rel=0.25)
    assert (np.diff(noisy.t) >= 0).all()
    hot = noisy.label == NoiseClass.HOT_PIXEL
    hot_pixels = set(zip(noisy.x[hot].tolist(), noisy.y[hot].tolist()))
    assert 1 <= len(hot_pixels) < 10  # a few pixels carry all of it


def test_physical_rate_noise():
    sig = scene("bar", G, duration_us=500_000)
    noisy = inject(sig, NoiseSpec(ba_rate_hz=5.0, hot_pixels=3, hot_rate_hz=(500, 500)), seed=2,
                   t_start_us=0, t_stop_us=500_000)
    counts = noisy.class_counts("label")
    assert counts[1] == pytest.approx(5.0 * G.n_pixels * 0.5, rel=0.1)
    assert counts[2] == pytest.approx(3 * 500 * 0.5, rel=0.15)


def test_noise_spec_errors():
    with pytest.raises(ValueError, match="exactly one"):
        NoiseSpec()
    with pytest.raises(ValueError, match="noise_ratio"):
        NoiseSpec(noise_ratio=-1)


# -- the compiled steps against their references ------------------------------------------------------
def emit_reference(log_prev, log_now, ref, thr_on, thr_off, last_t, t_prev, t_now, refractory_us, x0, y0):
    """Plain-Python `synth._emit`: each pixel's threshold crossings, in row order."""
    events = []
    h, w = log_now.shape
    for y in range(h):
        for x in range(w):
            a, b, r = float(log_prev[y, x]), float(log_now[y, x]), float(ref[y, x])
            while True:
                if b - r >= thr_on[y, x]:
                    level, pol = r + thr_on[y, x], 1
                elif r - b >= thr_off[y, x]:
                    level, pol = r - thr_off[y, x], 0
                else:
                    break
                frac = min(max((level - a) / (b - a) if b != a else 1.0, 0.0), 1.0)
                tc = t_prev + int(frac * (t_now - t_prev))
                r = level
                if tc - last_t[y, x] >= refractory_us:
                    last_t[y, x] = tc
                    events.append((tc, x0 + x, y0 + y, pol))
            ref[y, x] = r
    return events


@pytest.mark.parametrize("seed", range(6))
def test_emit_matches_its_plain_python_reference(seed):
    from evstream.synth import _emit

    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 12, 2)
    prev = rng.normal(0, 0.5, (h, w))
    now = prev + rng.normal(0, 0.6, (h, w)) * (rng.random((h, w)) < 0.7)  # some pixels unchanged
    ref = prev + rng.uniform(-0.2, 0.2, (h, w))
    on, off = rng.uniform(0.05, 0.4, (2, h, w))
    last = rng.integers(-1000, 1000, (h, w)).astype(np.int64)
    t_prev, t_now, refr, x0, y0 = int(rng.integers(0, 10_000)), 0, int(rng.integers(0, 80)), 3, 5
    t_now = t_prev + int(rng.integers(1, 200))
    want_ref, want_last = ref.copy(), last.copy()
    want = emit_reference(prev, now, want_ref, on, off, want_last, t_prev, t_now, refr, x0, y0)
    cap = 8 * h * w
    out = (np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16), np.empty(cap, np.uint8))
    n = _emit(prev, now, ref, on, off, last, t_prev, t_now, refr, x0, y0, *out)
    assert [tuple(int(a[i]) for a in out) for i in range(n)] == want
    assert np.array_equal(ref, want_ref) and np.array_equal(last, want_last)
    assert n > 0


@pytest.mark.parametrize("name", ["turntable", "ball", "bar"])
def test_each_compiled_step_samples_the_reference_field(name):
    """The compiled field agrees with the numpy one to ~1e-15 over random regions and times (thresholds
    out of reach, so a step only stores the field in `level`)."""
    from evstream import synth

    rng = np.random.default_rng(len(name))
    g = Geometry(int(rng.integers(40, 120)), int(rng.integers(30, 90)))
    field, region, stepper = synth.SCENES[name](g, duration_s=0.5)
    yy, xx = np.mgrid[0 : g.height, 0 : g.width].astype(np.float64)
    shape = (g.height, g.width)
    far = np.full(shape, 1e9)
    px = (field(0.0, xx, yy), np.zeros(shape), far, far, np.zeros(shape, np.int64))
    out = (np.empty(8, np.int64), np.empty(8, np.uint16), np.empty(8, np.uint16), np.empty(8, np.uint8))
    for t_us in sorted(rng.integers(100, 500_000, 12)):
        r0, c0 = int(rng.integers(0, g.height - 1)), int(rng.integers(0, g.width - 1))
        rows = slice(r0, int(rng.integers(r0 + 1, g.height + 1)))
        cols = slice(c0, int(rng.integers(c0 + 1, g.width + 1)))
        assert stepper(int(t_us) - 100, int(t_us), rows, cols, px, 100, out) == 0
        want = field(t_us * 1e-6, xx[rows, cols], yy[rows, cols])
        np.testing.assert_allclose(px[0][rows, cols], want, rtol=0, atol=1e-13)


@pytest.mark.parametrize("seed", range(4))
def test_compiled_scenes_give_the_reference_events(seed):
    """`scene()` (compiled steps) and `scene(compiled=False)` (numpy field every step): the same events, on
    random sensors, seeds, durations and scene parameters."""
    rng = np.random.default_rng(100 + seed)
    g = Geometry(int(rng.integers(32, 100)), int(rng.integers(24, 80)))
    duration = int(rng.integers(20, 120)) * 1000
    for name, params in (("turntable", {"sectors": int(rng.integers(2, 9)), "rev_hz": (float(rng.uniform(1, 6)), 0.5)}),
                         ("ball", {"speed_px_s": (float(rng.uniform(20, 100)), float(rng.uniform(200, 900)))}),
                         ("bar", {"speed_px_s": float(rng.uniform(50, 2000)), "width_px": float(rng.uniform(2, 20))})):
        fast = scene(name, g, duration_us=duration, seed=seed, **params)
        ref = scene(name, g, duration_us=duration, seed=seed, compiled=False, **params)
        assert len(fast) == len(ref) > 0, name
        for a in "txyp":
            assert np.array_equal(getattr(fast, a), getattr(ref, a)), (name, a)
