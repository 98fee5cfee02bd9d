"""Representations leaving the pipeline: .npz files per window, pictures, and the Rerun layout."""

from __future__ import annotations

import numpy as np
import pytest
from evstream.sinks.rerun_sink import RerunSink, blueprint
from evstream.sinks.rerun_viewer import open_output
from rerun.chunk import RrdReader

from evstream.events import Geometry
from evstream.framing.arrays import ArrayWriter
from evstream.framing.render import render_representation
from evstream.framing.represent import REPRESENTATIONS
from evstream.pipeline import Pipeline, build
from evstream.testing import frames_of, random_stream

G = Geometry(30, 20)


def test_npz_files_hold_the_arrays_and_window_times(tmp_path):
    s = random_stream(1, 3000, G)
    pipe = Pipeline([], build("framer", {"kind": "voxel", "bins": 3, "window_us": 20_000}))
    writer = ArrayWriter(tmp_path / "out" / "vox")  # the folder and the one above it are made
    pipe.run([s[:1000], s[1000:]], [writer])
    frames = frames_of(build("framer", {"kind": "voxel", "bins": 3, "window_us": 20_000}), [s])
    files = sorted((tmp_path / "out" / "vox").iterdir())
    assert [f.name for f in files] == [f"frame_{i:06d}.npz" for i in range(len(frames))] and writer.written > 3
    for path, fr in zip(files, frames):
        with np.load(path) as z:  # no allow_pickle needed: no Python objects inside
            assert z["data"].dtype == np.float32 and np.array_equal(z["data"], fr.data)
            assert (int(z["t_start_us"]), int(z["t_end_us"]), int(z["n_events"])) == (fr.t_start, fr.t_end,
                                                                                       fr.n_events)
            assert str(z["kind"]) == "voxel" and list(z["channels"]) == ["bin0", "bin1", "bin2"]
    assert not list((tmp_path / "out" / "vox").glob("*.part"))


def test_npz_output_into_a_folder_that_exists(tmp_path):
    """A second run into the same folder (or one made by hand) writes there: an existing folder is no error."""
    (tmp_path / "vox").mkdir()
    writer = ArrayWriter(tmp_path / "vox")
    Pipeline([], build("framer", {"kind": "voxel", "bins": 2, "window_us": 20_000})).run([random_stream(1, 500, G)],
                                                                                      [writer])
    assert writer.written and len(list((tmp_path / "vox").glob("*.npz"))) == writer.written


def test_a_count_image_has_one_channel_named_events():
    frames = frames_of(build("framer", {"kind": "count", "window_us": 5000}), [random_stream(1, 500, G)])
    assert frames and all(f.channels == ("events",) and f.data.shape[0] == 1 for f in frames)


def test_npz_output_refuses_plain_frames(tmp_path):
    pipe = Pipeline([], build("framer", {"kind": "fw", "window_us": 5000}))
    with pytest.raises(ValueError, match="takes a representation framer"):
        pipe.run([random_stream(1, 500, G)], [ArrayWriter(tmp_path / "x")])


@pytest.mark.parametrize("kind", REPRESENTATIONS)
def test_pictures(kind):
    fr = frames_of(build("framer", {"kind": kind, "window_us": 20_000}), [random_stream(2, 2000, G)])[1]
    img = render_representation(fr)
    assert img.dtype == np.uint8 and img.shape[2] == 3 and img.shape[0] == G.height
    assert img.shape[1] == (5 * G.width + 4 * 4 if kind == "voxel" else G.width)
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 2  # not a blank picture


@pytest.mark.parametrize("live", [False, True])  # live: sent with the sink's sends, as Image columns
def test_rerun_shows_the_time_surface_beside_the_frames(tmp_path, live):
    path = tmp_path / "ts.rrd"
    out = open_output(save=str(path))
    sink = RerunSink(out.rec, geometry=G, framer="timesurface", live=live)
    pipe = Pipeline([], build("framer", {"kind": "timesurface", "window_us": 10_000, "tau_us": 5000}))
    stats = pipe.run([random_stream(3, 3000, G)], [sink])
    out.finish()
    entities = {}
    for chunk in RrdReader(path).stream():
        entities[chunk.entity_path] = entities.get(chunk.entity_path, 0) + chunk.num_rows
    assert entities.get("/representations/timesurface", 0) == stats.frames == entities.get("/frames/timesurface")
    assert RrdReader(path).blueprints()


def _origins(item) -> list[str]:
    """The origins of every view in a blueprint container, depth first, left to right."""
    if hasattr(item, "origin"):  # a view (its `contents` is a query, not children)
        return [str(item.origin)]
    return [o for c in getattr(item, "contents", ()) for o in _origins(c)]


def test_blueprint_puts_the_representation_beside_the_frames():
    side = blueprint(G, framer="timesurface").root_container.contents[1]
    pair = side.contents[0]  # the frames row: counts, then the representation
    assert _origins(pair) == ["frames/timesurface", "representations/timesurface"]
    assert "representations" not in " ".join(_origins(blueprint(G, framer="fw").root_container))
