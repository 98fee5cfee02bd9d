"""Pictures of frames and representations (evstream/framing/render.py) in-process, against what each
style promises in the module's doc."""

from __future__ import annotations

import types

import numpy as np
import pytest

from evstream.events import Frame
from evstream.framing.render import (
    COLOUR_MAPS,
    GRAY,
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


def test_count_and_voxel_pictures_use_one_robust_scale():
    """A count image's pixels past the 99th percentile are at the top of `hot` (clipped at 1, not
    wrapped round a uint8); a voxel grid's bins share one scale, so a bin ten times weaker is dimmer."""
    total = np.array([[1.0] * 99 + [1000.0]], np.float32)
    count = render_representation(_rep("count", total[None]))
    s = robust_scale(total)
    np.testing.assert_array_equal(count, COLOUR_MAPS["hot"][(255 * np.clip(total / s, 0, 1)).round().astype(np.uint8)])
    assert (count[0, -1] == COLOUR_MAPS["hot"][255]).all()
    bins = np.array([[[10.0, -10.0]], [[1.0, -1.0]]], np.float32)
    vox = render_representation(_rep("voxel", bins))
    shared = robust_scale(bins)
    want = mosaic([[COLOUR_MAPS["coolwarm"][signed(b, shared)] for b in bins]], background=0)
    np.testing.assert_array_equal(vox, want)
    assert not np.array_equal(vox[0, :2], vox[0, -2:])  # the weak bin is not drawn as bright as the strong one


def test_robust_scale_is_at_least_one_and_below_two_when_the_values_are():
    assert robust_scale(np.array([1.5, 1.5, 0.0])) == 1.5
    assert robust_scale(np.array([0.25, -0.5])) == 1.0 and robust_scale(np.zeros(3)) == 1.0


def test_png_header_level_and_message():
    """The IHDR is width, height, 8 bits, the colour type and three zero bytes (deflate, filter 0, no
    interlace: a reader refuses other values); `level` is zlib's level; an empty image is refused."""
    img = np.zeros((3, 5), np.uint8)
    data = png_bytes(img)
    assert data[8:33] == b"\x00\x00\x00\x0dIHDR" + b"\x00\x00\x00\x05\x00\x00\x00\x03" + b"\x08\x00\x00\x00\x00" \
        + data[29:33]
    big = np.zeros((64, 64), np.uint8)
    assert len(png_bytes(big, level=0)) > len(png_bytes(big, level=9))
    with pytest.raises(ValueError, match=r"^PNG needs at least one pixel$"):
        png_bytes(np.zeros((0, 4), np.uint8))
    # RGBA, 16-bit, 1-D
    for bad in (np.zeros((2, 2, 4), np.uint8), np.zeros((2, 2), np.uint16), np.zeros(4, np.uint8)):
        with pytest.raises(ValueError, match=r"^PNG needs uint8 \(H, W\) or \(H, W, 3\), got "):
            png_bytes(bad)


def test_histogram_picture_is_on_minus_off():
    """A histogram is drawn in coolwarm over ON − OFF (channel 1 less channel 0): a pixel of ON events only is
    warm, one of OFF only cool, one of both equally the map's middle (a sum would draw all three alike warm)."""
    off, on = [[0.0, 3.0, 2.0]], [[3.0, 0.0, 2.0]]
    img = render_representation(_rep("histogram", [off, on]))
    np.testing.assert_array_equal(img, COLOUR_MAPS["coolwarm"][signed(np.array(on) - np.array(off))])
    assert img[0, 0, 0] > img[0, 0, 2] and img[0, 1, 2] > img[0, 1, 0]  # ON: more red than blue; OFF: more blue
    assert (img[0, 2] == COLOUR_MAPS["coolwarm"][GRAY]).all()
