"""The command line over representations, transforms and time ranges: `frames --framer voxel --out DIR`
writes .npz arrays, `--start-us/--end-us` on the reading commands, transforms from a TOML pipeline."""

from __future__ import annotations

import json

import numpy as np
import pytest
from evstream.sources import native

from evstream.cli import main
from evstream.events import concat
from evstream.framing.represent import Representation
from evstream.pipeline import build
from evstream.testing import frames_of, random_stream

REC = "recordings/turntable.npz"


@pytest.fixture
def rec(tmp_path):
    path = tmp_path / "rec.npz"
    native.save(path, random_stream(3, 20_000, mean_dt_us=20))
    return path


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_frames_writes_representations_as_npz(rec, tmp_path, capsys):
    out_dir = tmp_path / "vox"
    code, out, err = run(capsys, "frames", rec, "--denoise", "none", "--framer", "voxel", "--bins", "3",
                         "--window", "fn", "--n-events", "2000", "--out", out_dir, "--json")
    assert code == 0, err
    row = json.loads(out)["results"][0]
    assert row["framer"] == {"kind": "voxel", "bins": 3, "window": "fn", "n_events": 2000, "all_events": False}
    files = sorted(out_dir.glob("*.npz"))
    assert len(files) == row["png_written"] == 10 and row["files"] == "npz"
    ev = concat(list(native.open(rec)))
    want = frames_of(build("framer", {"kind": "voxel", "bins": 3, "window": "fn", "n_events": 2000}), [ev])
    for path, rep in zip(files, want):
        with np.load(path) as z:
            assert np.array_equal(z["data"], rep.data) and int(z["t_end_us"]) == rep.t_end


def test_frames_two_representations_and_a_plain_framer(rec, tmp_path, capsys):
    code, out, err = run(capsys, "frames", rec, "--denoise", "none", "--framer", "timesurface,histogram,fw",
                         "--tau-us", "5000", "--window-us", "20000", "--out", tmp_path / "o")
    assert code == 0, err
    assert "arrays (.npz) to" in out and "PNG frames to" in out
    assert list((tmp_path / "o" / "timesurface").glob("*.npz")) and list((tmp_path / "o" / "fw").glob("*.png"))


@pytest.mark.parametrize("argv, message", [
    (["--framer", "voxel", "--n-events", "10"], "n_events does not apply to window 'fw'"),
    (["--framer", "voxel", "--bins", "0"], "bins must be an integer >= 1"),
    (["--framer", "fw", "--tau-us", "10"], "--tau-us does not apply to --framer fw"),
    (["--framer", "timesurface", "--window", "weekly"], "window must be one of fw, fn, oa, adaptive"),
    (["--framer", "fw", "--start-us", "500", "--end-us", "100"], "--start-us 500 --end-us 100: end_us (100) must"),
])
def test_bad_flags_are_one_line_usage_errors(rec, capsys, argv, message):
    code, out, err = run(capsys, "frames", rec, *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1


def test_time_range_on_reading_commands(rec, tmp_path, capsys):
    ev = concat(list(native.open(rec)))
    start, end = int(ev.t[5000]), int(ev.t[9000])
    inside = int(((ev.t >= start) & (ev.t < end)).sum())
    code, out, err = run(capsys, "frames", rec, "--denoise", "none", "--framer", "count", "--start-us", start,
                         "--end-us", end, "--json")
    assert code == 0, err
    assert json.loads(out)["results"][0]["events_in"] == inside
    code, out, err = run(capsys, "convert", rec, tmp_path / "cut.npz", "--start-us", start, "--end-us", end)
    assert code == 0, err
    cut = concat(list(native.open(tmp_path / "cut.npz")))
    assert len(cut) == inside and cut.t[0] >= start and cut.t[-1] < end
    code, out, err = run(capsys, "info", rec, "--start-us", start, "--json")
    assert code == 0, err


def test_replay_with_transforms_and_a_time_surface(rec, tmp_path, capsys):
    toml = tmp_path / "p.toml"
    toml.write_text('[[stage]]\nkind = "crop"\nx0 = 2\ny0 = 3\nwidth = 16\nheight = 10\n'
                    '[[stage]]\nkind = "rotate"\ndegrees = 90\n'
                    '[[stage]]\nkind = "rate_limit"\nrate_hz = 20000\nburst_events = 10\n'
                    '[framer]\nkind = "timesurface"\nwindow_us = 20000\n')
    code, out, err = run(capsys, "replay", rec, "--pipeline", toml, "--save", tmp_path / "r.rrd")
    assert code == 0, err
    assert "rate_limit 20000 ev/s: dropped" in out
    from rerun.chunk import RrdReader

    paths = {c.entity_path for c in RrdReader(tmp_path / "r.rrd").stream()}
    assert "/representations/timesurface" in paths and "/frames/timesurface" in paths


def test_python_api_arrays_are_ready_for_torch():
    framer = build("framer", {"kind": "timesurface", "tau_us": 20_000})
    reps = [r for c in native.open(REC) for r in framer.push(c)]
    assert reps and all(isinstance(r, Representation) for r in reps)
    assert all(r.data.flags.c_contiguous and r.data.dtype == np.float32 and r.data.flags.writeable for r in reps)
