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
