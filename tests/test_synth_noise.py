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
    out = (np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16), np.empty(cap, np.uint8),
           np.empty(cap, np.int64))
    n = _emit(prev, now, ref, on, off, last, t_prev, t_now, refr, x0, y0, out)
    assert [tuple(int(a[i]) for a in out[:4]) for i in range(n)] == want
    assert np.array_equal(ref, want_ref) and np.array_equal(last, want_last)
    assert n > 0


def test_wake_is_the_first_step_that_may_have_moved_enough():
    """`_wake` (galloping search) against a plain search of the cumulative motion."""
    from evstream.synth import _wake

    rng = np.random.default_rng(3)
    for _ in range(300):
        moves = rng.exponential(1.0, int(rng.integers(1, 60))) * (rng.random() < 0.9)  # some standing still
        travel = np.concatenate(([0.0], np.cumsum(moves)))
        s0 = int(rng.integers(1, 1000))
        i = int(rng.integers(0, len(travel)))
        need = float(rng.choice([rng.uniform(-1, 0), rng.uniform(0, 2 * travel[-1] + 1), 0.0]))
        later = [j for j in range(i + 1, len(travel)) if travel[j] >= travel[i] + need]
        want = s0 + i if need <= 0 else s0 - 1 + (later[0] if later else len(travel))
        assert _wake(travel, i, s0 - 1 + i, s0, need) == want


def test_turntable_safe_edge_range_cannot_cross():
    """Inside `_tt_safe`'s range of edge values, the pixel's value (as the run computes it) crosses neither
    threshold; just outside a finite end, a little further, it does."""
    from evstream.synth import _crosses, _tt_safe, _tt_value

    rng = np.random.default_rng(5)
    checked = 0
    for _ in range(400):
        inside = float(rng.choice([0.0, 1.0, rng.uniform(0, 1), 10 ** rng.uniform(-6, 0)]))
        outside = 0.45 * (1 - inside)
        dark, light = np.log(outside + inside * 0.25 + 0.05), np.log(outside + inside * 0.75 + 0.05)
        ref = rng.uniform(dark - 0.3, light + 0.3)
        on, off = rng.uniform(0.05, 0.4, 2)
        lo, hi = _tt_safe(ref, on, off, outside, inside, dark, light)
        edges = rng.uniform(max(lo, -25.0), min(hi, 25.0), 50) if lo < hi else np.zeros(0)
        for e in edges:
            assert not _crosses(_tt_value(e, outside, inside, dark, light), ref, on, off), (lo, hi, e)
            checked += 1
        for end, step in ((hi, 0.05), (lo, -0.05)):  # not needlessly small: a bit past an end, it crosses
            if abs(end) < 4 and 1e-3 < inside:
                assert _crosses(_tt_value(end + step, outside, inside, dark, light), ref, on, off)
    assert checked > 5_000


def test_ball_reach_is_safe():
    """While the ball travels no further than `_ball_reach` allows from where a pixel was looked at, in any
    direction (the spin following its x), the pixel's log argument stays inside its thresholds' bounds."""
    from evstream import synth

    rng = np.random.default_rng(6)
    radius = 25.4
    grow = synth._ball_grow(radius)
    checked = far = 0
    for _ in range(1500):
        x, y = int(rng.integers(0, 80)), int(rng.integers(0, 80))
        cx, cy = rng.uniform(0, 80, 2)
        bg = float(rng.uniform(0.3, 0.4))
        spin = cx / radius
        off, v, e_pattern, e_edge, r = synth._ball_value(x, y, cx, cy, radius, np.cos(spin), np.sin(spin), bg)
        b = np.log(bg + 0.05) if off else np.log(v)
        on, thr_off = rng.uniform(0.05, 0.4, 2)
        ref = b + rng.uniform(-thr_off, on)
        v_lo, v_hi = np.exp(ref - thr_off + synth.MARGIN), np.exp(ref + on - synth.MARGIN)
        k = synth._ball_reach(off, e_pattern, e_edge, r, bg, grow, int(rng.integers(0, grow.shape[1])), v_lo, v_hi)
        if k < 0:
            continue
        far += synth.REACH_PX[k] >= 0.8
        for _ in range(10):
            d = synth.REACH_PX[k] * rng.choice([rng.uniform(0, 1), 1 - rng.uniform(0, 1e-3)]) * (1 - 1e-9)
            a = rng.uniform(0, 2 * np.pi)
            nx, ny = cx + d * np.cos(a), cy + d * np.sin(a)
            o, u, *_ = synth._ball_value(x, y, nx, ny, radius, np.cos(nx / radius), np.sin(nx / radius), bg)
            b = np.log(bg + 0.05) if o else np.log(u)
            assert not synth._crosses(b, ref, on, thr_off), (x, y, cx, cy, d, k)
            checked += 1
    assert checked > 5_000 and far > 100


@pytest.mark.parametrize("seed", range(6))
def test_compiled_scenes_give_the_reference_events(seed, monkeypatch):
    """`scene()` (compiled runs, skipping what cannot cross, in 1-3 row bands side by side, with buffers that
    fill after 10, 1000 or 2^18 events) and `scene(compiled=False)` (numpy field at every step, every pixel
    of the region): the same events, on random sensors, seeds, durations, sensor models and scene
    parameters (turntables turning either way, bars fast enough to wrap)."""
    from evstream import synth

    monkeypatch.setattr(synth, "THREADS", 1 + seed % 3)
    monkeypatch.setattr(synth, "BUFFER_EVENTS", (10, 1000, 1 << 18)[seed // 2])
    rng = np.random.default_rng(100 + seed)
    g = Geometry(int(rng.integers(32, 100)), int(rng.integers(24, 80)))
    duration = int(rng.integers(20, 120)) * 1000
    model = SensorModel(threshold=float(rng.uniform(0.1, 0.4)), threshold_sigma=float(rng.uniform(0, 0.06)),
                        refractory_us=int(rng.choice([0, 50, 100, 500])))
    for name, params in (("turntable", {"sectors": int(rng.integers(2, 9)),
                                        "rev_hz": (float(rng.uniform(-6, 6)), float(rng.uniform(-2, 2)))}),
                         ("ball", {"speed_px_s": (float(rng.uniform(20, 100)), float(rng.uniform(200, 2000)))}),
                         ("bar", {"speed_px_s": float(rng.uniform(50, 5000)), "width_px": float(rng.uniform(1, 20))})):
        fast = scene(name, g, duration_us=duration, seed=seed, model=model, **params)
        ref = scene(name, g, duration_us=duration, seed=seed, model=model, compiled=False, **params)
        assert len(fast) == len(ref) > 0, name
        for a in "txyp":
            assert np.array_equal(getattr(fast, a), getattr(ref, a)), (name, a)


@pytest.mark.parametrize("name, seed, duration_us", [("turntable", 1, 1_000_000), ("ball", 2, 1_000_000),
                                                     ("bar", 3, 500_000)])
def test_shipped_recordings_signal_is_what_synth_makes(name, seed, duration_us):
    """The shipped recordings (`make recordings`) hold exactly the signal events `scene` makes today: the
    learned model and the docs' tables are built from them."""
    from pathlib import Path

    import evstream

    shipped = evstream.read(Path(__file__).resolve().parents[1] / "recordings" / f"{name}.npz")
    signal = shipped.label == NoiseClass.SIGNAL
    made = scene(name, duration_us=duration_us, seed=seed)
    assert len(made) == signal.sum()
    for a in "txyp":
        assert np.array_equal(getattr(made, a), getattr(shipped, a)[signal]), a
