import json

import numpy as np
import pytest
from evstream.sources import native

from evstream import evaluation as ev
from evstream.cli import main
from evstream.events import EventChunk, Geometry, NoiseClass
from evstream.synth import scene

G = Geometry(64, 48)


@pytest.fixture(scope="module")
def signal():
    return scene("bar", G, duration_us=400_000, seed=1)


def test_rows_cover_every_method_and_condition_and_are_deterministic(signal):
    conds = [ev.Condition(noise_ratio=0.5), ev.Condition(ba_rate_hz=3.0)]
    methods = ["paper", "baf", "stcf"]
    a = ev.run({"bar": signal}, conds, [0, 1], methods, tune=True)
    b = ev.run({"bar": signal}, conds, [0, 1], methods, tune=True)
    assert len(a) == 2 * 2 * 3
    assert ev.as_json_rows(a) == ev.as_json_rows(b)
    for r in a:
        assert {"recording", "method", "noise_ratio", "edp", "esnr", "tpr", "fpr", "auc",
                "edp_at_tpr80", "tuned_edp"} <= set(r)
        assert 0 <= r["tpr"] <= 1 and 0 <= r["fpr"] <= 1 and 0.5 <= r["auc"] <= 1
        assert r["events"] > 0 and r["warmup_us"] <= 0.3 * 400_000
    paper = [r for r in a if r["method"] == "paper" and r["condition"] == "50%"]
    assert all(r["edp"] > 80 and r["tpr"] > 0.9 for r in paper)
    assert [r["noise_ratio"] for r in a if r["condition"] == "50%"] == [0.5] * 6


def test_cli_eval_says_when_learned_is_left_out_for_want_of_a_second_recording(tmp_path, signal, capsys):
    """One recording: nothing to train the leave-one-recording-out model on. The learned rows were left out
    without a word; now stderr says so, and asking for learned alone is a usage error (exit 2)."""
    native.save(tmp_path / "bar.npz", signal)
    args = ["eval", str(tmp_path / "bar.npz"), "--ratios", "0.5", "--rates-hz", "--seeds", "1"]
    assert main([*args, "--methods", "learned,stcf"]) == 0
    out, err = capsys.readouterr()
    assert "stcf" in out and "learned" not in out
    assert "learned: left out" in err and "second recording" in err
    assert main([*args, "--methods", "learned"]) == 2
    assert "learned: left out" in capsys.readouterr().err


def test_report_has_the_papers_layout(signal):
    rows = ev.run({"bar": signal}, [ev.Condition(noise_ratio=0.5), ev.Condition(noise_ratio=2.0)], [0],
                  ["paper", "baf"])
    text = ev.report(rows)
    assert "EDP % / signal kept % — bar" in text and "ROC AUC — bar" in text
    header = [ln for ln in text.splitlines() if ln.startswith("method")][0]
    assert header.split()[1:] == ["50%", "200%"]
    assert any(ln.startswith("paper ") for ln in text.splitlines())


def test_real_hot_pixels_are_set_aside():
    rng = np.random.default_rng(0)
    n = 5000
    x = rng.integers(0, 64, n)
    y = rng.integers(0, 48, n)
    x[:400], y[:400] = 10, 20  # one pixel fires 400 times, its neighbours about twice each
    t = np.sort(rng.integers(0, 1_000_000, n))
    ev_ = EventChunk.from_arrays(t, x, y, rng.integers(0, 2, n), G)
    assert ev.find_hot_pixels(ev_).tolist() == [20 * 64 + 10]
    sig, notes = ev.as_signal(ev_)
    assert notes == {"hot_pixels_set_aside": 1, "hot_events_set_aside": int(((x == 10) & (y == 20)).sum())}
    assert len(sig) == n - notes["hot_events_set_aside"] and (sig.label == NoiseClass.SIGNAL).all()


def test_labelled_recordings_keep_only_their_signal(signal):
    from evstream.noise import NoiseSpec, inject

    noisy = inject(signal, NoiseSpec(noise_ratio=1.0), seed=0)
    sig, notes = ev.as_signal(noisy)
    assert len(sig) == len(signal) and notes["hot_pixels_set_aside"] == 0


def test_cli_eval_prints_tables_and_writes_json_and_roc(tmp_path, signal, capsys):
    native.save(tmp_path / "bar.npz", signal)
    out = tmp_path / "rows.json"
    roc = tmp_path / "roc.png"
    assert main(["eval", str(tmp_path / "bar.npz"), "--methods", "paper,stcf", "--ratios", "0.5",
                 "--rates-hz", "--seeds", "1", "--json", str(out), "--roc", str(roc)]) == 0
    text = capsys.readouterr().out
    assert "EDP % at signal kept >= 80 %" in text
    rows = json.loads(out.read_text())
    assert {r["method"] for r in rows} == {"paper", "stcf"} and rows[0]["noise_ratio"] == 0.5
    assert roc.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
