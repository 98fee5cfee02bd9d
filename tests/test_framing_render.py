"""Pictures of frames and representations (evstream/framing/render.py) in-process, against what each
style promises in the module's doc."""

from __future__ import annotations

import types

import numpy as np
import pytest

from evstream.events import Frame
from evstream.framing.render import (
    COLOUR_MAPS,
    PngWriter,
    coloured,
    mosaic,
    paper,
    png_bytes,
    render,
    render_representation,
    robust_scale,
    signed,
)


def _frame(on, off):
    counts = np.stack([off, on]).astype(np.uint16)
    return Frame(0, 10, int(counts.sum()), counts)


FRAME = _frame(np.array([[9, 0, 1], [0, 0, 0]]), np.array([[0, 3, 1], [0, 40, 0]]))


def test_render_picks_the_style_and_passes_the_scale():
    np.testing.assert_array_equal(render(FRAME), paper(FRAME))
    np.testing.assert_array_equal(render(FRAME, "paper"), paper(FRAME))
    np.testing.assert_array_equal(render(FRAME, "signed", 2.0), signed(FRAME, 2.0))
    assert not np.array_equal(signed(FRAME, 2.0), signed(FRAME))


def test_signed_clips_both_ways():
    np.testing.assert_array_equal(signed(np.array([[-10, 0, 10]]), scale=1), [[1, 128, 255]])


def test_robust_scale_is_the_99th_percentile_of_the_nonzero_values():
    v = np.array([1.0] * 99 + [1000.0, 0.0])
    assert robust_scale(v) == pytest.approx(float(np.percentile(v[v != 0], 99))) and robust_scale(v) < 20


def test_sequential_maps_colour_the_magnitude_of_an_array():
    img = np.array([[-3, 0, 2]])
    s = float(np.percentile([3, 2], 99))
    want = COLOUR_MAPS["hot"][(255 * np.clip(np.abs(img) / s, 0, 1)).round().astype(np.uint8)]
    np.testing.assert_array_equal(coloured(img, "hot"), want)
    with pytest.raises(ValueError, match=r"^unknown colour map 'nope'; choose from coolwarm, bwr, viridis, hot$"):
        coloured(FRAME, "nope")


def test_mosaic_lays_gray_pictures_out_left_to_right():
    a, b = np.full((2, 2), 7, np.uint8), np.full((2, 3), 9, np.uint8)
    m = mosaic([[a, b]], gap=1, background=0)
    assert m.shape == (2, 6)
    np.testing.assert_array_equal(m, [[7, 7, 0, 9, 9, 9]] * 2)


def test_png_ends_with_its_iend_chunk():
    assert png_bytes(np.zeros((2, 2), np.uint8))[-8:-4] == b"IEND"


def _rep(kind, data):
    return types.SimpleNamespace(kind=kind, data=np.asarray(data, np.float32))


def test_representation_pictures():
    ts = render_representation(_rep("timesurface", [[[0.0, 0.5, 1.0]], [[0.2, 0.1, 0.0]]]))
    np.testing.assert_array_equal(ts, COLOUR_MAPS["viridis"][[[51, 128, 255]]])
    vox = render_representation(_rep("voxel", np.ones((2, 1, 1))))
    assert vox.shape == (1, 1 + 4 + 1, 3) and (vox[0, 1:5] == 0).all()  # the gap between bins is black
    with pytest.raises(ValueError, match=r"^no rendering for representation 'nope'$"):
        render_representation(_rep("nope", np.zeros((1, 1, 1))))


def test_png_writer_makes_its_folders_and_uses_its_style_and_scale(tmp_path):
    out = tmp_path / "a" / "b"
    w = PngWriter(out, style="signed", scale=2.0)
    w.write(types.SimpleNamespace(frames=[FRAME]))
    assert (out / "frame_000000.png").read_bytes() == png_bytes(signed(FRAME, 2.0))
    PngWriter(tmp_path / "c").write(types.SimpleNamespace(frames=[FRAME]))  # paper by default
    assert (tmp_path / "c" / "frame_000000.png").read_bytes() == png_bytes(paper(FRAME))
    with pytest.raises(ValueError, match=r"^unknown frame style 'x'; choose from paper, signed, coolwarm"):
        PngWriter(tmp_path / "d", style="x")
