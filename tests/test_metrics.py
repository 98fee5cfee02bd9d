"""Metrics against hand-computed examples and brute force (ROC by direct thresholding, AUC by pair counting)."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evstream import metrics
from evstream.denoise.baf import BackgroundActivityFilter
from evstream.denoise.stcf import SpatioTemporalCorrelationFilter
from evstream.events import Geometry, NoiseClass
from evstream.noise import NoiseSpec, inject
from evstream.synth import scene

LABEL = np.array([0, 0, 0, 1, 1, 2], np.uint8)
CLS = np.array([0, 0, 1, 0, 1, 1], np.uint8)  # signal kept 2 of 3, background kept 1 of 2, hot removed


def test_hand_computed_operating_point():
    c = metrics.confusion(LABEL, CLS)
    assert c == {"tp": 2, "fp": 1, "fn": 1, "tn": 2}
    assert metrics.edp(LABEL, CLS) == pytest.approx(200 / 3)
    assert metrics.esnr(LABEL, CLS) == pytest.approx(10 * math.log10(2))
    assert metrics.tpr(LABEL, CLS) == pytest.approx(2 / 3)
    assert metrics.fpr(LABEL, CLS) == pytest.approx(1 / 3)
    assert metrics.removal_rates(LABEL, CLS) == pytest.approx(
        {"background": 0.5, "hot_pixel": 1.0, "noise": 2 / 3, "signal": 1 / 3})
    assert metrics.summary(LABEL, CLS) == metrics.summary(LABEL, CLS == 0)  # codes or booleans


def test_edge_cases_are_documented_values_not_errors():
    sig = np.zeros(4, np.uint8)
    assert metrics.esnr(sig, np.ones(4, bool)) == math.inf  # no noise kept
    assert metrics.edp(sig, np.ones(4, bool)) == 100.0
    assert math.isnan(metrics.fpr(sig, np.ones(4, bool)))  # no noise at all
    assert math.isnan(metrics.removal_rates(sig, np.ones(4, bool))["hot_pixel"])
    noise = np.ones(3, np.uint8)
    assert math.isnan(metrics.tpr(noise, np.ones(3, bool)))  # no signal at all
    assert metrics.esnr(noise, np.ones(3, bool)) == -math.inf  # only noise kept
    assert math.isnan(metrics.edp(LABEL, np.zeros(6, bool)))  # nothing kept
    assert math.isnan(metrics.esnr(LABEL, np.zeros(6, bool)))
    empty = np.zeros(0, np.uint8)
    assert math.isnan(metrics.edp(empty, empty)) and math.isnan(metrics.roc_auc(empty, np.zeros(0)))
    with pytest.raises(ValueError, match="events"):
        metrics.edp(LABEL, CLS[:3])
    with pytest.raises(ValueError, match="events"):
        metrics.roc_curve(LABEL, np.zeros(2))
    with pytest.raises(ValueError, match="labels"):
        metrics.tpr(None, CLS)  # an unlabelled recording


def test_hand_computed_roc():
    label = np.array([0, 1, 0, 1], np.uint8)
    score = np.array([0.9, 0.8, 0.7, 0.1])
    f, t, thr = metrics.roc_curve(label, score)
    np.testing.assert_allclose(f, [0, 0, 0.5, 0.5, 1])
    np.testing.assert_allclose(t, [0, 0.5, 0.5, 1, 1])
    np.testing.assert_array_equal(thr, [np.inf, 0.9, 0.8, 0.7, 0.1])
    assert metrics.auc(f, t) == pytest.approx(0.75)
    assert metrics.roc_auc(label, score) == pytest.approx(0.75)
    assert metrics.operating_point(label, score, 0.5) == pytest.approx(
        {"threshold": 0.9, "tpr": 0.5, "fpr": 0.0, "edp": 100.0, "esnr_db": math.inf, "tp": 1, "fp": 0})
    assert metrics.edp_at_tpr(label, score, 0.75) == pytest.approx(200 / 3)  # threshold 0.7
    with pytest.raises(ValueError, match="tpr_target"):
        metrics.edp_at_tpr(label, score, 0)


def test_unscored_events_are_never_kept():
    label = np.array([0, 0, 1, 1], np.uint8)
    score = np.array([1.0, np.nan, 0.5, np.nan])
    f, t, _ = metrics.roc_curve(label, score)
    assert (f[-1], t[-1]) == (0.5, 0.5)
    # closed with a straight segment to (1, 1): 0.5*0.5 (upper-left square part) ... by trapezoids
    assert metrics.roc_auc(label, score) == pytest.approx(0.5 * 0.5 + 0.5 * (0.5 + 1) / 2)
    assert math.isnan(metrics.edp_at_tpr(label, score, 0.9))  # no threshold keeps 90 % of the signal


scores_st = st.lists(st.sampled_from([-np.inf, -2.0, -1.0, 0.0, 0.5, 1.0, 3.0, np.inf, np.nan]), min_size=1,
                     max_size=40)


@given(scores=scores_st, data=st.data())
def test_roc_matches_thresholding_every_score(scores, data):
    score = np.array(scores)
    label = np.array(data.draw(st.lists(st.integers(0, 2), min_size=len(score), max_size=len(score))), np.uint8)
    f, t, thr = metrics.roc_curve(label, score)
    distinct = np.unique(score[~np.isnan(score)])[::-1]
    np.testing.assert_array_equal(thr[1:], distinct)
    assert thr[0] == np.inf and f[0] == 0 or math.isnan(f[0])
    for i, theta in enumerate(thr[1:], start=1):
        keep = score >= theta  # NaN >= theta is False: never kept
        want_t, want_f = metrics.tpr(label, keep), metrics.fpr(label, keep)
        assert t[i] == pytest.approx(want_t, nan_ok=True) and f[i] == pytest.approx(want_f, nan_ok=True)
    # the operating point is the first threshold reaching the target
    target = data.draw(st.floats(0.05, 1.0))
    op = metrics.operating_point(label, score, target)
    ok = [theta for theta in thr[1:] if metrics.tpr(label, score >= theta) >= target - 1e-12]
    if ok:
        assert op["threshold"] == ok[0]
        assert op["edp"] == pytest.approx(metrics.edp(label, score >= ok[0]))
    else:
        assert math.isnan(op["edp"])


@given(scores=scores_st, data=st.data())
def test_auc_is_the_probability_signal_outranks_noise(scores, data):
    score = np.array([s for s in scores if not np.isnan(s)] or [0.0])
    label = np.array(data.draw(st.lists(st.integers(0, 2), min_size=len(score), max_size=len(score))), np.uint8)
    pos, neg = score[label == 0], score[label != 0]
    if not len(pos) or not len(neg):
        assert math.isnan(metrics.roc_auc(label, score))
        return
    wins = sum(float(a > b) + 0.5 * float(a == b) for a in pos for b in neg)
    assert metrics.roc_auc(label, score) == pytest.approx(wins / (len(pos) * len(neg)))


def test_esr_hand_computed():
    g = Geometry(2, 2)
    # n = [2, 1, 0, 0]: N = 3, M = 2, NTSS = 2/6, L_N = 4 - (1/9 + 1/3 + 1 + 1) = 14/9
    assert metrics.esr([0, 0, 1], [0, 0, 0], g) == pytest.approx(math.sqrt(14 / 27))
    assert math.isnan(metrics.esr([0], [0], g))


def test_esr_extremes_and_order():
    g = Geometry(64, 48)
    # all on one pixel: NTSS = 1, L_N = 1 - (1/3)^N  ->  ESR ~ 1;  one event per pixel: NTSS = 0
    assert metrics.esr(np.zeros(30, int), np.zeros(30, int), g) == pytest.approx(math.sqrt(1 - 3.0**-30))
    assert metrics.esr(np.arange(64), np.zeros(64, int), g) == 0.0
    rng = np.random.default_rng(0)
    x, y = rng.integers(20, 24, 3000), rng.integers(0, 48, 3000)
    perm = rng.permutation(3000)
    assert metrics.esr(x[perm], y[perm], g) == pytest.approx(metrics.esr(x, y, g))
    halves = [metrics.esr(x[:1500], y[:1500], g), metrics.esr(x[1500:], y[1500:], g)]
    assert metrics.mean_esr(x, y, g, packet_events=1500) == pytest.approx(np.mean(halves))
    assert math.isnan(metrics.mean_esr(x[:1000], y[:1000], g, packet_events=1500))  # no full packet


@pytest.mark.parametrize("name", ["turntable", "bar"])
def test_esr_falls_as_noise_is_added_to_a_scene(name):
    """Measured (96x72, 3000-event packets): turntable 0.95 -> 0.79 -> 0.72, bar 0.82 -> 0.76 -> 0.69
    at noise ratio 0, 1, 2."""
    g = Geometry(96, 72)
    s = scene(name, g, duration_us=400_000, seed=1)
    esr = [metrics.mean_esr(n.x, n.y, g, 3000)
           for n in [s] + [inject(s, NoiseSpec(noise_ratio=r, hot_share=0.0), seed=2) for r in (1.0, 2.0)]]
    assert esr[0] > esr[1] > esr[2]


def test_one_pass_scores_reproduce_the_stage_decision():
    """The BAF score at its own tau gives exactly the classification's metrics, and ranks well."""
    g = Geometry(96, 72)
    s = inject(scene("bar", g, duration_us=400_000, seed=3), NoiseSpec(ba_rate_hz=5.0, hot_pixels=2), seed=4)
    for stage, thr in ((BackgroundActivityFilter(tau_us=2000), -2000), (SpatioTemporalCorrelationFilter(), -25_000)):
        codes, score = stage.classify_scored(s)
        keep = score > thr
        np.testing.assert_array_equal(keep, codes == NoiseClass.SIGNAL)
        assert metrics.summary(s.label, codes) == metrics.summary(s.label, keep)
        assert metrics.roc_auc(s.label, score) > 0.85
        assert metrics.edp_at_tpr(s.label, score, 0.8) > metrics.edp(s.label, np.ones(len(s), bool)) + 20
