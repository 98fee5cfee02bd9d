"""The learned denoiser: the feature kernel against its plain-Python definition, the stage's streaming
invariants, the model file (round trip, damaged and foreign files refused), and the shipped model."""

import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evstream.denoise.learned import FEATURES, LearnedFilter, Model, ModelError, load
from evstream.denoise.learned.features import (
    FAR_TICKS,
    FEATURE_VERSION,
    HOT_SCORE,
    N_BINS,
    REBASE_TICKS,
    TICK_US,
    reference_features,
)
from evstream.denoise.learned.model import DEFAULT_MODEL
from evstream.denoise.learned.neighbours import WORD_TAIL, nb8_support, reference_nb8
from evstream.denoise.learned.train import KEEP_GRID, Samples, features_of, fit, fit_logistic, fit_mlp
from evstream.events import Geometry, NoiseClass
from evstream.jit import njit
from evstream.noise import NoiseSpec, inject
from evstream.pipeline import build
from evstream.synth import scene
from evstream.testing import assert_bounded_state, assert_causal, assert_chunk_invariant, random_stream

NF = len(FEATURES)


# Small recordings for the tests that train, calibrate or evaluate (a 48x36 scene of 400 ms; files with
# the synth command's default 50 % noise, as recordings/*.npz have): they check the same as on the shipped
# 346x260 recordings, and the feature kernel meets ~20x fewer events (the noise injected at a rate per
# pixel grows with the sensor): tests/mutation.py runs that kernel as plain Python, ~50 us an event.
def small_recording(folder: Path, name: str = "bar", seed: int = 1, width: int = 48, height: int = 36,
                    duration_ms: int = 400) -> Path:
    """`evstream synth NAME` written to folder/NAME.npz."""
    from evstream.cli import main

    path = folder / f"{name}.npz"
    assert main(["synth", name, str(path), "--seed", str(seed), "--width", str(width), "--height", str(height),
                 "--duration-ms", str(duration_ms), "-q"]) == 0
    return path


def small_scene(name: str = "bar", seed: int = 1):
    """The signal of a small recording (all SIGNAL, no noise)."""
    return scene(name, Geometry(48, 36), duration_us=400_000, seed=seed)


def random_model(seed, kind="mlp", hidden=8) -> Model:
    rng = np.random.default_rng(seed)
    rows = hidden if kind == "mlp" else 1
    return Model(w1=rng.normal(0, 1, (rows, NF)), b1=rng.normal(0, 1, rows), w2=rng.normal(0, 1, rows),
                 b2=float(rng.normal()), mean=rng.normal(0, 1, NF), std=rng.uniform(0.5, 2, NF),
                 keep_grid=KEEP_GRID.copy(), threshold_grid=np.linspace(1, -1, len(KEEP_GRID)),
                 meta={"kind": kind, "hidden": hidden if kind == "mlp" else 0})


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32), st.integers(0, 300), st.sampled_from([20.0, 300.0, 3000.0]),
       st.sampled_from([Geometry(24, 18), Geometry(40, 33)]))
def test_features_match_the_definition(seed, n, mean_dt_us, geometry):
    s = random_stream(seed, n, geometry, mean_dt_us=mean_dt_us)
    got = features_of(s)
    want = reference_features(s.t, s.x, s.y, s.p, geometry.width, geometry.height)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 2**32), st.sampled_from([1, 8, 16]))
def test_an_mlp_stages_features_match_the_definition(seed, hidden):
    """An MLP's kernel keeps a batch's features in a matrix and scores them after the batch (features.py):
    the feature rows it gives, across several batches, are still the definition's."""
    s = random_stream(seed, 300, Geometry(24, 18), mean_dt_us=300.0)
    stage = LearnedFilter(model=random_model(seed, "mlp", hidden))
    want = reference_features(s.t, s.x, s.y, s.p, 24, 18)
    np.testing.assert_allclose(stage.features(s.replace(label=None)), want, rtol=0, atol=1e-9)


@njit(cache=True)
def _nb8_all(word, bins, centres, wp, tick, pis, b8):
    out = np.zeros((len(centres), 3), np.int64)
    for k in range(len(centres)):
        out[k, 0], out[k, 1], out[k, 2] = nb8_support(word, bins, centres[k], wp, tick, pis[k], b8)
    return out


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32), st.integers(1, 40), st.integers(1, 30),
       st.sampled_from([130, 700, 4000, 70_000, 2**23 - 1]), st.sampled_from([1, 2621]))
def test_vector_neighbour_pass_matches_its_definition(seed, width, height, spread, most):
    """Ages on both sides of each support limit and of the DC idle limit, both polarities, last active
    bins within and past the 64 counted (and across the modulo-256 wrap), random bitmaps, random 20 ms
    counts and ON counts up to the most a box can sum (25 × 2621 < 65536), every pixel; the map's
    padding and tail as the stage allocates them, random too."""
    rng = np.random.default_rng(seed)
    wp = width + 4
    size = (height + 4) * wp + WORD_TAIL
    now = int(rng.integers(spread, 2**23))
    b8 = int(rng.integers(0, 256))
    last = now - rng.integers(0, spread + 1, size)
    last_bin = (b8 - rng.integers(0, 80, size)) % 256
    count = rng.integers(0, most + 1, size)
    on = rng.integers(0, count + 1)
    word = ((on << 48) | (count << 32) | (last_bin << 24) | (last << 1) | rng.integers(0, 2, size)).astype(np.int64)
    bins = rng.integers(-(2**63), 2**63 - 1, size, dtype=np.int64)
    word[rng.random(size) < 0.2] = 0  # never fired
    centres = np.array([(y + 2) * wp + x + 2 for y in range(height) for x in range(width)], np.intp)
    pis = rng.integers(0, 2, len(centres)).astype(np.int64)
    got = _nb8_all(word, bins, centres, wp, now, pis, b8)
    want = [reference_nb8(word, bins, int(c), wp, now, int(q), b8) for c, q in zip(centres, pis)]
    np.testing.assert_array_equal(got, np.array(want, np.int64).reshape(-1, 3))


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 2**32), st.integers(-15_000, 15_000))
def test_features_match_the_definition_across_the_rebase(seed, offset_us):
    """The first rebase of the last-event map (its 23-bit ticks moved 2^23 - 2^20 ticks of 16 µs after
    the first event) falls among events whose own pixels and neighbours fired a few ms before it."""
    s = random_stream(seed, 200, mean_dt_us=500.0)
    t = s.t.copy()
    t[70:] += (REBASE_TICKS - FAR_TICKS) * TICK_US - (t[105] - t[0]) + offset_us
    s = s.replace(t=t)
    want = reference_features(s.t, s.x, s.y, s.p, s.geometry.width, s.geometry.height)
    np.testing.assert_allclose(features_of(s), want, rtol=0, atol=1e-9)


@settings(max_examples=5, deadline=None)
@given(st.integers(0, 2**32), st.integers(0, 2**40))
def test_features_match_the_definition_across_long_gaps(seed, gap_us):
    """Gaps of minutes, hours and days: the last-event map's 23-bit ticks are rebased, which changes no
    feature."""
    s = random_stream(seed, 200, mean_dt_us=500.0)
    t = s.t.copy()
    t[70:] += gap_us
    t[140:] += 3 * (1 << 34)  # past the rebase point (2^23 ticks of 16 µs) from any start
    s = s.replace(t=t)
    want = reference_features(s.t, s.x, s.y, s.p, s.geometry.width, s.geometry.height)
    np.testing.assert_allclose(features_of(s), want, rtol=0, atol=1e-9)


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2**32), st.sampled_from(["logistic", "mlp"]), st.booleans())
def test_scores_and_codes_match_numpy_inference(seed, kind, leave_out):
    """Also for models that leave features out (zero weight), each with probability 1/2."""
    s = random_stream(seed, 400, mean_dt_us=100.0)
    model = random_model(seed, kind)
    unweighted = np.random.default_rng(seed).random(NF) < 0.5 if leave_out else np.zeros(NF, bool)
    model.w1[:, unweighted] = 0.0
    stage = LearnedFilter(model=model, keep=0.7)
    codes, score = stage.classify_scored(s.replace(label=None))
    feats = features_of(s)
    own, n = np.round(np.expm1(feats[:, 2])), np.round(np.expm1(feats[:, 0]))
    dc_own, dc_nb = np.round(feats[:, 9] * N_BINS), np.round(feats[:, 10] * 8 * N_BINS)
    # the hot-pixel rules (features.py): the 20 ms count, and the DC margin (dc_lam of 8 · 64 bins)
    hot = ((own >= 4) & (3 * own > n)) | (8 * dc_own - dc_nb > np.floor(stage.dc_lam * 8 * N_BINS))
    want = np.where(hot, HOT_SCORE, model.score(feats))
    np.testing.assert_allclose(score, want, rtol=1e-9, atol=1e-9)
    assert (codes[hot] == NoiseClass.HOT_PIXEL).all()
    thr = model.threshold(0.7)
    clear = np.abs(score - thr) > 1e-7  # a score on the threshold may round either way
    np.testing.assert_array_equal(codes[clear] == NoiseClass.SIGNAL, (score >= thr)[clear])


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**32))
def test_stage_is_chunk_invariant_and_causal(seed):
    model = random_model(seed)
    s = random_stream(seed, 500, mean_dt_us=200.0)
    make = lambda: LearnedFilter(model=model)  # noqa: E731
    assert_chunk_invariant(make, s, seed)
    assert_causal(make, s, seed)


def test_stage_sees_only_live_events_after_another_stage():
    """Behind another stage, the learned stage judges (and remembers) only the events still SIGNAL."""
    s = random_stream(3, 2000, mean_dt_us=100.0)
    model = random_model(3)
    first = build("stage", {"kind": "refractory"})
    after = first(s.replace(label=None))
    live = after.cls == NoiseClass.SIGNAL
    out = LearnedFilter(model=model)(after)
    alone = LearnedFilter(model=model)(s[live].replace(label=None))
    np.testing.assert_array_equal(out.cls[live], alone.cls)
    np.testing.assert_array_equal(out.cls[~live], after.cls[~live])


def test_state_is_bounded():
    model = random_model(0)
    assert_bounded_state(lambda: LearnedFilter(model=model),
                         lambda n: random_stream(1, n, mean_dt_us=100.0), n=3000)


def test_model_file_round_trip_and_same_bytes(tmp_path):
    m = random_model(5)
    m.meta.update({"feature_version": FEATURE_VERSION, "features": list(FEATURES), "keep": 0.85})
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    m.save(a)
    m.save(b)
    assert a.read_bytes() == b.read_bytes()
    back = load(a)
    feats = np.random.default_rng(0).normal(size=(50, NF))
    np.testing.assert_array_equal(back.score(feats), m.score(feats))
    assert back.threshold(0.85) == pytest.approx(m.threshold(0.85))
    assert not list(tmp_path.glob(".*tmp*"))


def test_bad_model_files_are_one_line_errors(tmp_path):
    m = random_model(6)
    m.meta.update({"feature_version": FEATURE_VERSION, "features": list(FEATURES), "keep": 0.85})
    good = tmp_path / "good.npz"
    m.save(good)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:300])
    other = tmp_path / "other.npz"
    m.meta["feature_version"] = 99
    m.save(other)
    plain = tmp_path / "plain.npz"
    np.savez(plain, x=np.zeros(3))
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip at all")
    for path, words in [(cut, "not a readable"), (other, "feature version 99"), (plain, "missing"),
                        (junk, "not an .npz archive"), (tmp_path / "none.npz", "no such model file")]:
        with pytest.raises(ModelError) as e:
            load(path)
        msg = str(e.value)
        assert "\n" not in msg and str(path) in msg and words in msg, msg


def test_model_file_holds_no_pickle(tmp_path):
    m = random_model(7, "logistic")
    m.meta.update({"feature_version": FEATURE_VERSION, "features": list(FEATURES), "keep": 0.85})
    m.save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)
        assert json.loads(str(z["meta"]))["kind"] == "logistic"
    with zipfile.ZipFile(tmp_path / "m.npz") as zf:
        assert all(i.date_time == (1980, 1, 1, 0, 0, 0) for i in zf.infolist())


@pytest.mark.skipif(not DEFAULT_MODEL.exists(), reason="no shipped model")
def test_shipped_model_removes_noise_and_hot_pixels():
    """On a scene none of its training data came from (the default seed differs), at 100 % noise:
    most background and hot-pixel events removed, most of the signal kept."""
    g = Geometry(128, 96)
    sig = scene("ball", g, duration_us=400_000, seed=77)
    noisy = inject(sig, NoiseSpec(noise_ratio=1.0), seed=5, t_start_us=0, t_stop_us=400_000)
    stage = build("stage", {"kind": "learned"})
    cls = stage(noisy.replace(label=None)).cls
    warm = noisy.t >= stage.history_us
    lab, kept = noisy.label[warm], cls[warm] == NoiseClass.SIGNAL
    assert kept[lab == NoiseClass.SIGNAL].mean() > 0.9
    assert kept[lab == NoiseClass.BACKGROUND].mean() < 0.1
    # at the default point (signal kept 99 % here) a few events of hot pixels in the ball's path pass;
    # asked to keep less, fewer than 1 % do
    assert kept[lab == NoiseClass.HOT_PIXEL].mean() < 0.03
    strict = build("stage", {"kind": "learned", "keep": 0.7})
    kept = strict(noisy.replace(label=None)).cls[warm] == NoiseClass.SIGNAL
    assert kept[lab == NoiseClass.SIGNAL].mean() > 0.85
    assert kept[lab == NoiseClass.HOT_PIXEL].mean() < 0.01


@pytest.mark.skipif(not DEFAULT_MODEL.exists(), reason="no shipped model")
@pytest.mark.parametrize("name, least", [("dvs128_lifetime_garfield.mat", 0.6), ("dvxplorer_320x240_tonic.aedat4", 0.5),
                                         ("nmnist_sample.bin", 0.6)])
def test_shipped_model_keeps_most_of_clean_real_recordings_it_never_saw(real_data, name, least):
    """Real recordings of sensors unlike its training data (DVS128, DVXplorer, ATIS; no noise added):
    the shipped model keeps most events, as the cascade does (78-95 %), not the 10-35 % of a model
    trained without the thinned copies (docs/learned.md)."""
    from evstream import api

    events = api.read(real_data / name)
    kept = build("stage", {"kind": "learned"})(events.replace(label=None, cls=None)).cls == NoiseClass.SIGNAL
    assert kept.mean() > least


def test_train_says_where_it_is_when_its_output_is_piped(tmp_path):
    """`evstream train ... 2>&1 | tee log` printed nothing until the model was written (a minute on real
    recordings): progress went only to a terminal. Piped, each step is a line on stderr as it happens:
    the first arrives while the model is not written yet."""
    import subprocess
    import sys

    out = tmp_path / "m.npz"
    proc = subprocess.Popen([sys.executable, "-m", "evstream.cli", "train", "recordings/bar.npz", "recordings/ball.npz",
                             "--out", str(out), "--events-per-stream", "3000"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[1])
    try:
        first = proc.stderr.readline()
        assert first.startswith("evstream train: ") and "reading 2 recording(s)" in first, first
        assert not out.exists()  # said before the work, not after
        rest = proc.communicate(timeout=600)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0 and out.exists()
    lines = [first.rstrip("\n"), *rest.splitlines()]
    assert "\r" not in rest and "\x1b" not in rest  # plain lines for a log, not a terminal's bar
    assert all(line.startswith("evstream train: ") for line in lines), lines
    assert sum(" seed " in line for line in lines) == 12 and "fitting logistic" in lines[-3], lines
    assert [line.split(": ", 2)[2] for line in lines[-2:]] == [  # the cross-fitting, a fit per recording
        "operating points: bar left out (1 of 2 fits)", "operating points: ball left out (2 of 2 fits)"], lines
    quiet = subprocess.run([sys.executable, "-m", "evstream.cli", "train", "recordings/bar.npz", "--out",
                            str(tmp_path / "q.npz"), "--events-per-stream", "3000", "--quiet"], capture_output=True,
                           text=True, cwd=Path(__file__).resolve().parents[1])
    assert quiet.returncode == 0 and quiet.stderr == ""


def test_train_command_writes_a_model_the_pipeline_uses(tmp_path):
    """`evstream train` on one recording writes a model; `--denoise learned --model` runs it in a
    pipeline; a damaged model is a one-line error with exit 1."""
    from evstream.cli import main

    out = tmp_path / "m.npz"
    bar = str(small_recording(tmp_path))
    assert main(["train", bar, "--out", str(out), "--events-per-stream", "3000",
                 "--without", "dc_own,dc_nb8"]) == 0
    m = load(out)
    left_out = [FEATURES.index("dc_own"), FEATURES.index("dc_nb8")]
    assert (m.w1[0, left_out] == 0).all() and (m.w1[0] != 0).sum() == NF - 2
    assert m.meta["features_left_out"] == ["dc_own", "dc_nb8"]
    assert main(["train", bar, "--out", str(tmp_path / "x.npz"), "--without", "nope"]) == 2
    assert m.meta["trained_on"][0]["file"] == "bar.npz" and len(m.meta["trained_on"][0]["sha256"]) == 64
    assert m.meta["noise_conditions"] == ["50%", "100%", "200%", "1Hz", "3Hz", "5Hz"]
    arch = tmp_path / "a.mcap"
    assert main(["archive", bar, str(arch), "--denoise", "learned", "--model", str(out), "--keep", "0.8"]) == 0
    assert arch.stat().st_size > 0
    bad = tmp_path / "bad.npz"
    bad.write_bytes(out.read_bytes()[:100])
    assert main(["archive", bar, str(tmp_path / "b.mcap"), "--denoise", "learned", "--model", str(bad)]) == 1
    assert main(["archive", bar, str(tmp_path / "c.mcap"), "--model", str(out)]) == 2


def test_eval_scores_the_learned_method_leave_one_recording_out():
    """The model scoring a recording was trained on the others only: its metadata names them."""
    from evstream import evaluation

    recs = {name: small_scene("bar", seed) for name, seed in (("a", 1), ("b", 2), ("c", 3))}
    models = evaluation.loo_models(recs)
    for name, model in models.items():
        trained = {r["recording"] for r in model.meta["trained_on"]} if "trained_on" in model.meta else None
        assert model.meta["name"] == f"trained without {name}"
        assert trained is None or name not in trained
    rows = evaluation.run(recs, [evaluation.Condition(noise_ratio=1.0)], [0], ["stcf", "learned"])
    learned = [r for r in rows if r["method"] == "learned"]
    assert len(learned) == 3 and all(r["auc"] > 0.9 for r in learned)
    assert "leave-one-recording-out" in evaluation.report(rows)
    one = evaluation.run({"a": recs["a"]}, [evaluation.Condition(noise_ratio=1.0)], [0], ["stcf", "learned"])
    assert {r["method"] for r in one} == {"stcf"}  # nothing to train on but the recording itself


def test_no_reference_mesr_and_its_random_baseline():
    from evstream import metrics, no_reference

    g = Geometry(96, 72)
    sig = scene("ball", g, duration_us=500_000, seed=4)
    noisy = inject(sig, NoiseSpec(noise_ratio=1.0), seed=2, t_start_us=0, t_stop_us=500_000)
    parts = no_reference.mesr_parts(noisy, 5_000)
    assert parts["mesr"] == pytest.approx(metrics.mean_esr(noisy.x, noisy.y, g, 5_000))
    assert parts["mesr"] == pytest.approx(np.mean([np.sqrt(a * b) for a, b, _ in (
        metrics.esr_parts(noisy.x[i:i + 5000], noisy.y[i:i + 5000], g)
        for i in range(0, parts["packets"] * 5000, 5000))]))
    rows = no_reference.evaluate("ball", noisy, {"stcf": lambda: build("stage", {"kind": "stcf"})},
                                 packet_events=5_000)
    raw, stcf = rows
    assert raw["kept"] == 1.0 and raw["random_mesr"] == raw["mesr"]
    assert 0.3 < stcf["kept"] < 0.9
    kept = build("stage", {"kind": "stcf"})(noisy.replace(label=None)).cls == NoiseClass.SIGNAL
    assert stcf["mesr"] == pytest.approx(no_reference.mesr_parts(noisy[kept], 5_000)["mesr"])
    u = np.random.default_rng(0).random(len(noisy))
    assert stcf["random_mesr"] == pytest.approx(no_reference.mesr_parts(noisy[u < kept.mean()], 5_000)["mesr"])
    text = no_reference.report(rows)
    assert "random" in text and "stcf" in text


def test_thinned_copies_join_their_recording_and_leave_the_rest_unchanged():
    """`samples(thin=...)`: each recording's signal thinned to each fraction is more rows of the same
    recording (its calibration fold) under conditions of their own; the unthinned rows are the same."""
    from evstream.denoise.learned.train import TRAIN_CONDITIONS, samples

    recs = {"bar": small_scene()}
    plain = samples(recs, per_stream=1000)
    thinned = samples(recs, per_stream=1000, thin=(0.3,))
    n = len(plain.y)
    assert np.array_equal(thinned.X[:n], plain.X) and np.array_equal(thinned.y[:n], plain.y)
    assert len(thinned.y) > n and (thinned.group == 0).all()
    assert set(thinned.cond[n:]) == set(range(len(TRAIN_CONDITIONS), 2 * len(TRAIN_CONDITIONS)))
    with pytest.raises(ValueError, match="thin"):
        samples(recs, per_stream=1000, thin=(1.5,))


def test_thinned_copies_set_the_operating_point_not_the_weights():
    """`train(thin=...)`: the weights are fitted on the recordings as they are (the same as without
    thinned copies); the thresholds are calibrated on the thinned copies too, so a sparse scene's lower
    signal scores pull them down; `fit_thinned=True` fits the weights on the copies as well.
    `time_scale` copies enter the fit."""
    from evstream.denoise.learned.train import train

    recs = {"bar": small_scene()}  # one recording: its unthinned rows are the same
    plain = train(recs, per_stream=1000)
    thinned = train(recs, per_stream=1000, thin=(0.1,))
    both = train(recs, per_stream=1000, thin=(0.1,), fit_thinned=True)
    assert np.array_equal(thinned.w1, plain.w1) and np.array_equal(thinned.mean, plain.mean)
    assert thinned.threshold(0.85) < plain.threshold(0.85)
    assert not np.array_equal(both.w1, plain.w1)
    assert thinned.meta["thinned_copies"] == "operating point only" and "thinned_copies" not in plain.meta
    assert 0.2 < plain.meta["signal_share"] < 0.8 and plain.meta["training_events"] > 1000
    slow = train(recs, per_stream=1000, time_scale=(2,))  # stretched copies: in the fit
    assert not np.array_equal(slow.w1, plain.w1) and slow.meta["signal_time_scaled_by"] == [2.0]
    with pytest.raises(ValueError, match="time scale"):
        train(recs, per_stream=1000, time_scale=(0,))


def test_stretched_and_off_thinned_copies_join_their_recording():
    """`samples(time_scale=..., off_keep=...)`: more rows of the same recording under condition indices
    after the thinned copies'; the plain rows unchanged; a stretched copy spans `factor` × the time."""
    from evstream.denoise.learned.train import TRAIN_CONDITIONS, samples, stretched

    rec = small_scene()
    recs = {"bar": rec}
    plain = samples(recs, per_stream=1000)
    aug = samples(recs, per_stream=1000, thin=(0.3,), time_scale=(2.0,), off_keep=(0.5,))
    n, nc = len(plain.y), len(TRAIN_CONDITIONS)
    assert np.array_equal(aug.X[:n], plain.X) and (aug.group == 0).all()
    assert set(aug.cond) == set(range(4 * nc))
    s = stretched(rec, 2.0)
    assert s.t[-1] - s.t[0] == 2 * (rec.t[-1] - rec.t[0]) and np.array_equal(s.x, rec.x)


def test_label_free_calibration_keeps_near_what_is_asked(tmp_path):
    """`calibrate_to` sets the operating point from a stream's own events, no labels: on the bar scene
    with 50 % noise (64x48, 500 ms: 4,000 signal events after 256 ms) the shipped model's fixed threshold
    keeps all the signal when 85 % is asked; the calibrated one keeps close to 85 %, more for a higher
    keep. Labels given or not, the same result; a stream too short to say leaves the thresholds as they
    were."""
    from evstream import api
    from evstream.denoise.learned.train import calibrate_to, stream_threshold

    ev = api.read(small_recording(tmp_path, "bar", width=64, height=48, duration_ms=500))
    bare = ev.replace(label=None)
    model = load()
    cal = calibrate_to(model, {"bar": ev})
    assert np.array_equal(cal.threshold_grid, calibrate_to(model, {"bar": bare}).threshold_grid)
    assert cal.meta["calibrated_on"]["bar"]["noise_share"] == pytest.approx(1 / 3, abs=0.06)
    assert stream_threshold(model, bare, 0.85) == pytest.approx(cal.threshold(0.85))
    late = (ev.label == NoiseClass.SIGNAL) & (ev.t > ev.t[0] + 256_000)
    kept = {}
    for name, m in (("fixed", model), ("calibrated", cal)):
        for keep in (0.7, 0.85, 0.95):
            codes, _ = LearnedFilter(model=m, keep=keep).classify_scored(bare)
            kept[name, keep] = ((codes == NoiseClass.SIGNAL) & late).sum() / late.sum()
    assert kept["fixed", 0.85] > 0.97
    assert abs(kept["calibrated", 0.85] - 0.85) < 0.08
    assert kept["calibrated", 0.7] < kept["calibrated", 0.85] < kept["calibrated", 0.95]
    short = calibrate_to(model, {"short": bare[:1000]})
    assert np.array_equal(short.threshold_grid, model.threshold_grid)


def test_calibrate_command(tmp_path):
    """`evstream calibrate REC --out M`: a model file with the recording's operating point, that the
    pipeline runs; no recording long enough, or the output as an input, is a usage error."""
    from evstream.cli import main

    out = tmp_path / "cal.npz"
    bar = str(small_recording(tmp_path))
    assert main(["calibrate", bar, "--out", str(out)]) == 0
    m = load(out)
    assert "label-free" in m.meta["calibration"] and "bar" in m.meta["calibrated_on"]
    assert m.threshold() != load().threshold()
    assert main(["archive", bar, str(tmp_path / "a.mcap"), "--denoise", "learned", "--model", str(out)]) == 0
    short = tmp_path / "short.npz"
    assert main(["synth", "bar", str(short), "--duration-ms", "30", "--width", "32", "--height", "24",
                 "-q"]) == 0
    assert main(["calibrate", str(short), "--out", str(tmp_path / "x.npz")]) == 2
    assert main(["calibrate", bar, "--model", str(out), "--out", str(out)]) == 2


def test_calibrate_never_writes_over_the_shipped_model(tmp_path, capsys):
    """Without --model, the model calibrated is the shipped one: --out naming it (or a link to it) is the
    input as output, a usage error, and the shipped file is left as it was."""
    from evstream.cli import main

    before = DEFAULT_MODEL.read_bytes()
    link = tmp_path / "default.npz"
    link.symlink_to(DEFAULT_MODEL)
    for out in (DEFAULT_MODEL, link):
        assert main(["calibrate", "recordings/bar.npz", "--out", str(out)]) == 2
        assert "that is the model being calibrated" in capsys.readouterr().err
    assert DEFAULT_MODEL.read_bytes() == before


def test_a_keep_beyond_the_models_calibration_is_refused_not_clamped(capsys):
    """The threshold for `keep` is interpolated on the model's calibration grid (0.50-0.99 for the shipped
    model): a keep outside it used to run silently as the grid's end."""
    from evstream.cli import main

    m = load()
    low, high = float(KEEP_GRID.min()), float(KEEP_GRID.max())
    assert m.threshold(low) != m.threshold(high)
    for keep in (low / 2, (1 + high) / 2):
        with pytest.raises(ValueError, match="outside what this model was calibrated for"):
            m.threshold(keep)
        with pytest.raises(ValueError, match="calibrated for"):
            LearnedFilter(keep=keep)
    assert main(["replay", "recordings/bar.npz", "--denoise", "learned", "--keep", "0.3", "--save",
                 "/nonexistent-folder/x.rrd"]) == 1  # refused before anything is read or written
    assert "calibrated for" in capsys.readouterr().err


def test_eval_scores_a_users_model_on_recordings_it_never_saw_and_refuses_its_own(tmp_path, capsys):
    """`evstream eval REC --model M.npz`: the model scored as it is, a method `model:STEM` beside the rules,
    with the same rows as the stage run by hand; on a recording it was trained on (same SHA-256), one line
    and exit 1 before any work."""
    import evstream
    from evstream import evaluation
    from evstream.cli import main

    model = tmp_path / "mine_from_bar.npz"
    bar, ball = small_recording(tmp_path, "bar"), small_recording(tmp_path, "ball")
    assert main(["train", str(bar), "--out", str(model), "--events-per-stream", "3000"]) == 0
    capsys.readouterr()
    rows_file = tmp_path / "rows.json"
    assert main(["eval", str(ball), "--model", str(model), "--methods", "paper", "--ratios", "1",
                 "--rates-hz", "--seeds", "1", "--json", str(rows_file)]) == 0
    printed = capsys.readouterr().out
    assert "model:mine_from_bar" in printed
    for block in printed.split("\n\n"):  # the tables' columns line up past the longer method name
        lines = [line for line in block.splitlines()[1:]
                 if line.split(" ")[0] in ("method", "paper", "model:mine_from_bar")]
        if lines and lines[0].startswith("method"):
            assert len({len(line) for line in lines}) == 1, block
    rows = {r["method"]: r for r in json.loads(rows_file.read_text())}
    assert set(rows) == {"paper", "model:mine_from_bar"}
    ball = evaluation.as_signal(evstream.read(ball))[0]
    name = "model:mine_from_bar"
    by_hand = evaluation.evaluate("ball", ball, evaluation.Condition(noise_ratio=1.0), 0, [name],
                                  fixed={name: load(model)})[0]
    for metric in ("edp", "auc", "tpr"):
        assert rows["model:mine_from_bar"][metric] == pytest.approx(by_hand[metric]), metric
    assert main(["eval", str(bar), "--model", str(model), "--ratios", "1", "--rates-hz"]) == 1
    assert f"was trained on {bar}" in capsys.readouterr().err


@pytest.mark.parametrize("params, message", [
    ({"keep": 0}, "learned: keep must be a fraction in (0, 1], got 0"),
    ({"keep": 1.5}, "learned: keep must be a fraction in (0, 1], got 1.5"),
    ({"keep": "0.8"}, "learned: keep must be a fraction in (0, 1], got '0.8'"),
    ({"hot_min": 0}, "learned: hot_min must be a positive integer, got 0"),
    ({"hot_min": 2.0}, "learned: hot_min must be a positive integer, got 2.0"),
    ({"dc_lam": -0.1}, "learned: dc_lam must be in [0, 1] (1: no DC rule), got -0.1"),
    ({"dc_lam": 1.5}, "learned: dc_lam must be in [0, 1] (1: no DC rule), got 1.5"),
    ({"dc_lam": "0.2"}, "learned: dc_lam must be in [0, 1] (1: no DC rule), got '0.2'")])
def test_bad_stage_parameters_are_refused_by_name(params, message):
    """Each bad parameter is refused with its own message (no test checked them: a dc_lam of 1.5, a DC rule
    that never fires, ran silently once the check said `or`); the edges of each range are taken."""
    with pytest.raises(ValueError) as e:
        LearnedFilter(model=random_model(0), **params)
    assert str(e.value) == message
    for ok in ({"keep": 0.99}, {"keep": 0.5}, {"hot_min": 1}, {"dc_lam": 0}, {"dc_lam": 1}):
        assert LearnedFilter(model=random_model(0), **ok).params()[next(iter(ok))] == next(iter(ok.values()))


def reference_mlp(Z, y, hidden, seed, epochs=60, batch=4096, lr=3e-3, l2=1e-5):
    """`fit_mlp` written out sample by sample: one hidden ReLU layer, the mean logistic loss of each minibatch
    plus l2/2 of the squared weights (not the biases), Adam (0.9, 0.999, 1e-8, bias-corrected); the same
    seeded draws (the first layer's N(0, 2/d), the second's N(0, 1/hidden), a permutation per epoch)."""
    rng = np.random.default_rng(seed)
    n, d = Z.shape
    w1 = rng.normal(0, np.sqrt(2.0 / d), (hidden, d)).tolist()
    b1 = [0.0] * hidden
    w2 = rng.normal(0, np.sqrt(1.0 / hidden), hidden).tolist()
    b2 = 0.0
    params = {("w1", j, c): w1[j][c] for j in range(hidden) for c in range(d)}
    params.update({("b1", j): b1[j] for j in range(hidden)})
    params.update({("w2", j): w2[j] for j in range(hidden)})
    params[("b2",)] = b2
    m = dict.fromkeys(params, 0.0)
    v = dict.fromkeys(params, 0.0)
    t = 0
    for _ in range(epochs):
        order = rng.permutation(n)
        for a in range(0, n, batch):
            rows = order[a:a + batch]
            grad = {k: (l2 * params[k] if k[0] in ("w1", "w2") else 0.0) for k in params}
            for r in rows:
                pre = [sum(params["w1", j, c] * Z[r, c] for c in range(d)) + params["b1", j] for j in range(hidden)]
                out = sum(max(p, 0.0) * params["w2", j] for j, p in enumerate(pre)) + params["b2",]
                g = (1 / (1 + math.exp(-out)) - y[r]) / len(rows)
                grad["b2",] += g
                for j in range(hidden):
                    grad["w2", j] += max(pre[j], 0.0) * g
                    if pre[j] > 0:
                        grad["b1", j] += g * params["w2", j]
                        for c in range(d):
                            grad["w1", j, c] += g * params["w2", j] * Z[r, c]
            t += 1
            for k, gk in grad.items():
                m[k] = 0.9 * m[k] + 0.1 * gk
                v[k] = 0.999 * v[k] + 0.001 * gk * gk
                params[k] -= lr * (m[k] / (1 - 0.9**t)) / (math.sqrt(v[k] / (1 - 0.999**t)) + 1e-8)
    return (np.array([[params["w1", j, c] for c in range(d)] for j in range(hidden)]),
            np.array([params["b1", j] for j in range(hidden)]), np.array([params["w2", j] for j in range(hidden)]),
            params["b2",])


@pytest.mark.parametrize("options", [{}, {"epochs": 3, "batch": 5, "lr": 0.05, "l2": 0.01}])
def test_the_mlp_fit_is_adam_on_the_logistic_loss(options):
    """`fit_mlp` against its definition written out (no test trained an MLP: its step, its loss gradient and
    its defaults were never checked); its defaults (60 epochs, batches of 4096, lr 3e-3, l2 1e-5) and small
    batches with a short last one."""
    rng = np.random.default_rng(3)
    Z = rng.normal(size=(12, 3))
    y = (Z[:, 0] + 0.5 * rng.normal(size=12) > 0).astype(np.float64)
    got = fit_mlp(Z, y, 4, seed=7, **options)
    want = reference_mlp(Z, y, 4, seed=7, **options)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12)
    assert isinstance(got[3], float)


def test_the_logistic_fit_is_the_penalised_optimum():
    """`fit_logistic` returns the minimum of the summed logistic loss plus l2·n/2 of the squared weights,
    the intercept not penalised (l2 = 1e-3 by default): the gradient there is zero. Unbalanced classes,
    so the intercept is far from 0."""
    rng = np.random.default_rng(5)
    Z = rng.normal(size=(400, 4))
    y = (Z @ [1.5, -2.0, 0.5, 0.0] + 1.2 + rng.logistic(size=400) > 0).astype(np.float64)
    for l2, args in ((1e-3, {}), (0.05, {"l2": 0.05})):
        w, b = fit_logistic(Z, y, **args)
        assert isinstance(b, float) and w.shape == (4,) and b > 0.5
        pr = 1 / (1 + np.exp(-(Z @ w + b)))
        np.testing.assert_allclose(Z.T @ (pr - y) + l2 * len(y) * w, 0, atol=1e-7)
        assert abs(np.sum(pr - y)) < 1e-7


def synthetic_samples(seed: int, groups: int = 2, conds: int = 2, per: int = 200) -> Samples:
    """Feature rows without the kernel: `per` rows per (recording, condition), half signal, the signal's
    first three features shifted up; for the fitting and calibration steps alone."""
    rng = np.random.default_rng(seed)
    n = groups * conds * per
    y = (rng.random(n) < 0.5).astype(np.float64)
    X = rng.normal(size=(n, NF))
    X[:, :3] += 1.5 * y[:, None]
    group = np.repeat(np.arange(groups), conds * per)
    cond = np.tile(np.repeat(np.arange(conds), per), groups)
    return Samples(X, y, group, cond, [f"r{g}" for g in range(groups)])


def test_the_operating_points_are_cross_fitted_over_two_or_more_recordings():
    """With two recordings each is scored by a model fitted on the other (`calibrate`), with one by the
    training quantiles; the held-out keeps it reports are fractions near those asked; thresholds fall as
    the keep rises and are float32 values (the same bytes on every machine); an MLP's fold models are
    seeded as the final one (the same model twice), 16 hidden units unless told."""
    S = synthetic_samples(1)
    m = fit(S)
    assert m.meta["calibration"] == "cross-fitted over recordings"
    held = m.meta["held_out_keep_at_training_keep"]
    assert set(held) == {"0.80", "0.85", "0.90"}
    assert all(abs(v - float(k)) < 0.1 and 0 < v < 1 for k, v in held.items()), held
    grid = m.threshold_grid
    assert (np.diff(grid) <= 0).all() and grid[0] > grid[-1]
    assert np.array_equal(grid, grid.astype(np.float32).astype(np.float64))
    one = fit(S.subset(S.group == 0))
    assert one.meta["calibration"] == "training quantiles (one recording)"
    a, b = fit(S, "mlp", hidden=4, seed=3), fit(S, "mlp", hidden=4, seed=3)
    assert np.array_equal(a.threshold_grid, b.threshold_grid) and np.array_equal(a.w1, b.w1)
    alone = fit(S, "mlp", calibrate_folds=False)
    assert alone.w1.shape == (16, NF) and alone.meta["calibration"] == "training quantiles"


def test_a_recording_and_condition_with_fewer_than_50_signal_events_sets_no_threshold():
    """`_fold_levels` takes a row of thresholds per (recording, condition) with at least 50 signal events."""
    from evstream.denoise.learned.train import _fold_levels

    S = synthetic_samples(2)
    model = fit(S, calibrate_folds=False)
    signal = S.y == 1
    rank = np.zeros(len(S.y), np.int64)
    for g, c in ((1, 0), (1, 1)):
        sel = signal & (S.group == g) & (S.cond == c)
        rank[sel] = np.arange(sel.sum())
    keep = ~signal | (S.group == 0) | ((S.cond == 0) & (rank < 49)) | ((S.cond == 1) & (rank < 50))
    assert _fold_levels(model, S.subset(keep), KEEP_GRID).shape == (3, len(KEEP_GRID))


def test_train_names_the_features_it_does_not_know():
    from evstream.denoise.learned.train import train

    with pytest.raises(ValueError) as e:
        train({"bar": small_scene()}, without=["dc_own", "nope", "f0"])
    assert str(e.value) == f"unknown feature(s) nope, f0; the features are {', '.join(FEATURES)}"


def test_a_model_of_an_unknown_kind_is_a_one_line_error(tmp_path):
    m = random_model(8)
    m.meta.update({"feature_version": FEATURE_VERSION, "features": list(FEATURES), "keep": 0.85, "kind": "forest"})
    m.save(tmp_path / "forest.npz")
    with pytest.raises(ModelError) as e:
        load(tmp_path / "forest.npz")
    assert str(e.value) == f"{tmp_path / 'forest.npz'}: unknown model kind 'forest' (logistic or mlp)"


def test_large_counts_take_the_log_of_their_64th_and_stop_at_2_to_the_22():
    """`_log1p_count` (and the reference's `_ref_log1p`), the block-count feature's logarithm: exact below
    2^16 events, then log1p(c >> 6) + log 64, the same from 2^22 on (a block never counts that many events in
    20 ms in the tests that compare the features: the cap was never reached)."""
    from evstream.denoise.learned.features import LOG_CELLS, TABLES, _log1p_count, _ref_log1p

    for c in (0, 1, 700, LOG_CELLS - 1):
        assert _log1p_count(TABLES, c) == pytest.approx(math.log1p(c), rel=1e-15)
    for c in (LOG_CELLS, 3 << 19, (1 << 22) - 1):
        assert _log1p_count(TABLES, c) == pytest.approx(math.log1p(c >> 6) + math.log(64), rel=1e-15)
        assert abs(_log1p_count(TABLES, c) - math.log1p(c)) < 1e-3 * math.log1p(c)
    for c in (1 << 22, 1 << 40):
        assert _log1p_count(TABLES, c) == pytest.approx(math.log1p(LOG_CELLS - 1) + math.log(64), rel=1e-15)
    for c in (0, 700, LOG_CELLS - 1, LOG_CELLS, 3 << 19, 1 << 22, 1 << 40):  # the reference's, the same
        assert _ref_log1p(c) == pytest.approx(_log1p_count(TABLES, c), rel=1e-15)


def test_a_recording_of_fewer_than_100_signal_events_is_refused_by_name():
    from evstream.denoise.learned.train import samples
    from evstream.noise import Condition

    signal, once = small_scene(), [Condition(noise_ratio=0.5)]
    assert len(samples({"r": signal[:100]}, once, per_stream=30).y) == 30
    with pytest.raises(ValueError) as e:
        samples({"r": signal[:99]}, once, per_stream=30)
    assert str(e.value) == "r: fewer than 100 signal events, nothing to learn from"


def test_features_are_standardised_by_their_spread_unless_constant():
    """`_standardise`: each feature's mean and standard deviation, a constant one (spread below 1e-9) divided
    by 1; a small spread is kept as it is."""
    from evstream.denoise.learned.train import _standardise

    X = np.column_stack([np.arange(6.0), 1e-3 * np.arange(6.0), np.full(6, 4.0)])
    mean, std = _standardise(X)
    np.testing.assert_allclose(mean, [2.5, 2.5e-3, 4.0])
    np.testing.assert_allclose(std, [np.std(np.arange(6.0)), 1e-3 * np.std(np.arange(6.0)), 1.0])


def test_thinned_copies_are_the_same_for_the_same_seed():
    """The thinning draws from its own seeded generator: the same samples twice, other ones for another seed."""
    from evstream.denoise.learned.train import samples
    from evstream.noise import Condition

    recs, once = {"bar": small_scene()}, [Condition(noise_ratio=0.5)]
    a, b = (samples(recs, once, per_stream=200, thin=(0.3,)) for _ in range(2))
    assert np.array_equal(a.X, b.X) and np.array_equal(a.y, b.y)
    other = samples(recs, once, per_stream=200, thin=(0.3,), rng_seed=1)
    assert not np.array_equal(a.X[200:], other.X[200:])


def test_a_model_file_that_does_not_fit_says_why(tmp_path):
    """The messages name the kind whose shapes do not fit and the error a damaged archive raised."""
    m = random_model(9, "logistic")
    m.meta.update({"feature_version": FEATURE_VERSION, "features": list(FEATURES), "keep": 0.85})
    m.w1 = np.zeros((2, NF))
    m.save(tmp_path / "shapes.npz")
    with pytest.raises(ModelError) as e:
        load(tmp_path / "shapes.npz")
    assert str(e.value) == f"{tmp_path / 'shapes.npz'}: array shapes do not fit a logistic model of {NF} features"
    m.w1 = np.zeros((1, NF))
    m.save(tmp_path / "good.npz")
    (tmp_path / "cut.npz").write_bytes((tmp_path / "good.npz").read_bytes()[:300])
    with pytest.raises(ModelError) as e:
        load(tmp_path / "cut.npz")
    assert str(e.value).startswith(f"{tmp_path / 'cut.npz'}: not a readable evstream model file (BadZipFile: ")


def test_every_stretched_copy_enters_the_fit_and_an_off_kept_copy_keeps_that_share_of_off():
    """One noise condition: the stretched copy is the only other condition, so its rows must change the
    weights (train 59 left out the first stretched condition); an `off_keep` copy keeps every ON event and
    about that share of the OFF ones (samples 87 kept all or none by one draw)."""
    from evstream.denoise.learned.train import samples, train
    from evstream.noise import Condition

    recs, once = {"bar": small_scene()}, [Condition(noise_ratio=0.5)]
    plain = train(recs, per_stream=300, conditions=once)
    slow = train(recs, per_stream=300, conditions=once, time_scale=(2,))
    assert not np.array_equal(slow.w1, plain.w1)
    S = samples(recs, once, per_stream=10**9, off_keep=(0.5,))
    sig = recs["bar"]
    share = (sig.p == 1).mean() + 0.5 * (sig.p == 0).mean()
    kept = S.y[S.cond == 1].sum() / S.y[S.cond == 0].sum()
    assert abs(kept - share) < 0.05, (kept, share)
