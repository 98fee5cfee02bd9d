"""`evstream frames` as a user types it, at window sizes and over recordings the defaults do not reach."""

from __future__ import annotations

import json

import pytest

from evstream.cli import main

REC = "recordings/bar.npz"


def frames_json(capsys, *argv) -> dict:
    code = main(["frames", *map(str, argv), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)["results"][0]


@pytest.mark.parametrize("window_us", [100, 300])
def test_time_surface_over_windows_that_hold_only_noise(capsys, window_us):
    """At 100 µs many windows of bar.npz hold only events the cascade classed as noise: such a window is an
    empty frame (shared read-only counts), and the time surface counted its events into them (a numba
    TypingError, 'internal error', exit 1). Its windows and counts are those of fw's."""
    surface = frames_json(capsys, REC, "--framer", "timesurface", "--window-us", window_us)
    fw = frames_json(capsys, REC, "--framer", "fw", "--window-us", window_us)
    keys = ("frames", "mean_events", "variance_events", "empty_frames", "frames_at_end", "events_signal")
    assert {k: surface[k] for k in keys} == {k: fw[k] for k in keys}
