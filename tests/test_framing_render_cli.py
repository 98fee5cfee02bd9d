"""Frame rendering (paper, signed, colour maps), PNG files, frame statistics, `evstream frames` and
`replay --framer`."""

import json
import zlib

import numpy as np
import pytest
from evstream.sources import native

from evstream.cli import main
from evstream.events import Frame, Geometry
from evstream.framing import FixedCount, FixedWindow
from evstream.framing.render import COLOUR_MAPS, _table, mosaic, paper, png_bytes, render, signed, write_png
from evstream.framing.stats import FrameStats, frame_stats
from evstream.pipeline import Pipeline
from evstream.testing import frames_of, random_stream

G = Geometry(24, 18)


def _frame(on, off):
    counts = np.stack([off, on]).astype(np.uint16)
    return Frame(0, 10, int(counts.sum()), counts)


def test_paper_rendering_is_gray_with_on_white_and_off_black():
    on = np.array([[2, 0, 1], [0, 0, 0]])
    off = np.array([[0, 3, 1], [0, 0, 5]])
    img = paper(_frame(on, off))
    assert img.dtype == np.uint8
    assert img.tolist() == [[255, 0, 128], [128, 128, 0]]


def test_signed_rendering_scales_symmetrically():
    on = np.array([[4, 0, 2, 0]])
    off = np.array([[0, 4, 0, 0]])
    assert signed(_frame(on, off), scale=4).tolist() == [[255, 1, 192, 128]]
    assert signed(_frame(on * 100, off), scale=4)[0, 0] == 255  # clipped


def test_colour_maps_are_rgb_and_diverge_around_zero():
    on = np.array([[9, 0, 0]])
    off = np.array([[0, 9, 0]])
    rgb = render(_frame(on, off), "coolwarm", scale=9)
    assert rgb.shape == (1, 3, 3) and rgb.dtype == np.uint8
    assert rgb[0, 0].tolist() == COLOUR_MAPS["coolwarm"][255].tolist()  # ON: red end
    assert rgb[0, 1].tolist() == COLOUR_MAPS["coolwarm"][1].tolist()  # OFF: blue end
    assert rgb[0, 0, 0] > rgb[0, 0, 2] and rgb[0, 1, 2] > rgb[0, 1, 0]
    seq = render(_frame(on, off), "viridis", scale=9)
    assert seq[0, 0].tolist() == seq[0, 1].tolist() == COLOUR_MAPS["viridis"][255].tolist()
    with pytest.raises(ValueError, match="unknown frame style"):
        render(_frame(on, off), "rainbow")


def _decode_png(data: bytes) -> np.ndarray:
    """A minimal reader for what png_bytes writes (one IDAT, filter 0), to check the bytes exactly."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, {}
    while pos < len(data):
        n = int.from_bytes(data[pos : pos + 4], "big")
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        assert int.from_bytes(data[pos + 8 + n : pos + 12 + n], "big") == zlib.crc32(kind + body)
        chunks[kind] = body
        pos += 12 + n
    w, h = int.from_bytes(chunks[b"IHDR"][:4], "big"), int.from_bytes(chunks[b"IHDR"][4:8], "big")
    channels = 3 if chunks[b"IHDR"][9] == 2 else 1
    raw = np.frombuffer(zlib.decompress(chunks[b"IDAT"]), np.uint8).reshape(h, 1 + w * channels)
    assert (raw[:, 0] == 0).all()
    return raw[:, 1:].reshape((h, w, 3) if channels == 3 else (h, w))


@pytest.mark.parametrize("shape", [(18, 24), (5, 7, 3), (1, 1)])
def test_png_round_trip(tmp_path, shape):
    img = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    assert np.array_equal(_decode_png(png_bytes(img)), img)
    write_png(tmp_path / "a.png", img)
    from PIL import Image  # an independent decoder (Pillow comes with rerun-sdk)
    with Image.open(tmp_path / "a.png") as im:
        assert np.array_equal(np.asarray(im), img)


def test_png_rejects_what_it_cannot_encode():
    with pytest.raises(ValueError, match="uint8"):
        png_bytes(np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match="at least one pixel"):
        png_bytes(np.zeros((0, 3), np.uint8))


def test_mosaic_lays_out_rows_with_gaps():
    a = np.zeros((2, 3), np.uint8)
    b = np.full((2, 2, 3), 7, np.uint8)
    m = mosaic([[a, a], [b]], gap=1, background=255)
    assert m.shape == (5, 7, 3)
    assert (m[0, 3] == 255).all() and (m[3:5, 0:2] == 7).all() and (m[0:2, 0:3] == 0).all()


def test_frame_stats_match_numpy():
    n = np.random.default_rng(1).integers(0, 5000, 137)
    n[::4] = 0  # 35 empty frames of 137: not as many as the full ones, so counting either passes for neither
    s = FrameStats(duration_us=2_000_000)
    for v in n:
        s.add(int(v))
    assert s.frames == 137 and s.frame_rate_hz == pytest.approx(68.5) and s.empty_frames == 35
    assert s.mean_events == pytest.approx(n.mean()) and s.variance_events == pytest.approx(n.var())
    fw = frames_of(FixedWindow(window_us=1000), [random_stream(2, 800, G)])
    d = frame_stats(fw, 40_000).as_dict()
    assert d["frames"] == len(fw) and d["mean_events"] == pytest.approx(np.mean([f.n_events for f in fw]))


@pytest.fixture
def recording(tmp_path):
    s = random_stream(3, 3000, G, mean_dt_us=20)
    path = tmp_path / "rec.npz"
    native.save(path, s)
    return path, s


def test_frames_command_prints_the_papers_statistics(recording, capsys):
    path, s = recording
    assert main(["frames", str(path), "--framer", "fw,fn,oa,adaptive", "--denoise", "none",
                 "--window-us", "2000", "--n-events", "300", "--n-base", "50", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    rows = {r["framer"]["kind"]: r for r in out["results"]}
    assert set(rows) == {"fw", "fn", "oa", "adaptive"}
    assert rows["oa"]["framer"]["window_us"] == 2000 and rows["fn"]["framer"]["n_events"] == 300
    fw = frames_of(FixedWindow(window_us=2000), [s])
    n_fw = [f.n_events for f in fw[:-1]]  # the last frame is the one the end of the stream closed
    assert rows["fw"]["frames"] == len(n_fw) and rows["fw"]["frames_at_end"] == 1
    assert rows["fw"]["mean_events"] == pytest.approx(np.mean(n_fw))
    assert rows["fw"]["variance_events"] == pytest.approx(np.var(n_fw))
    assert rows["fw"]["frame_rate_hz"] == pytest.approx(len(n_fw) / ((s.t[-1] - s.t[0]) * 1e-6))
    assert rows["fn"]["mean_events"] == 300 and rows["fn"]["variance_events"] == 0
    assert rows["adaptive"]["frames"] >= rows["fw"]["frames"]  # denser than N_base: more overlap


def test_frames_command_writes_png_frames(recording, tmp_path, capsys):
    path, s = recording
    out = tmp_path / "frames"
    assert main(["frames", str(path), "--framer", "fn", "--n-events", "500", "--denoise", "none",
                 "--out", str(out), "--style", "signed"]) == 0
    text = capsys.readouterr().out
    assert "fn" in text and "wrote 6 PNG frames" in text
    files = sorted(out.glob("frame_*.png"))
    assert len(files) == 6
    expected = frames_of(FixedCount(n_events=500), [s])
    img = _decode_png(files[2].read_bytes())
    assert img.shape == (G.height, G.width) and np.array_equal(img, signed(expected[2]))


@pytest.mark.parametrize("argv, message", [
    (["--framer", "fw", "--stride-us", "10"], "--stride-us does not apply"),
    (["--framer", "oa", "--window-us", "10", "--stride-us", "20"], "must not exceed"),
    (["--framer", "blob"], "unknown framer blob"),
    (["--framer", "none"], "name a framer"),
    (["--framer", "fw", "--style", "mauve"], None),
])
def test_frames_command_usage_errors_exit_2(recording, capsys, argv, message):
    path, _ = recording
    with pytest.raises(SystemExit) if message is None else _no_raise():
        assert main(["frames", str(path), *argv]) == 2
    if message:
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1


class _no_raise:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_replay_takes_a_framer_and_frames_reach_the_sink(recording, tmp_path, capsys):
    path, s = recording
    rrd = tmp_path / "out.rrd"
    assert main(["replay", str(path), "--denoise", "none", "--save", str(rrd), "--framer", "adaptive",
                 "--window-us", "2000", "--n-base", "40", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    from evstream.framing import AdaptiveOverlap

    want = frames_of(AdaptiveOverlap(window_us=2000, n_base=40), [s])
    assert summary["frames"] == len(want) > 0
    # read the frames back from the .rrd (rerun's own reader): one image per frame, each the paper's
    # look of that frame's counts, rendered here (white where ON outnumber OFF, black where OFF do)
    from test_rerun_sink import column_rows, read_rrd

    times, images = column_rows(read_rrd(rrd)["/frames/adaptive"], "Image:buffer")
    assert len(images) == len(want)
    for k, i in enumerate(np.argsort(times, kind="stable")):
        off, on = want[k].counts[0].astype(np.int64), want[k].counts[1].astype(np.int64)
        np.testing.assert_array_equal(np.asarray(images[i], np.uint8).reshape(G.height, G.width),
                                      np.select([on > off, off > on], [255, 0], 128), err_msg=f"frame {k}")


def test_a_toml_pipeline_builds_a_framer(tmp_path):
    toml = tmp_path / "p.toml"
    toml.write_text('[framer]\nkind = "oa"\nwindow_us = 4000\nstride_us = 1000\n')
    p = Pipeline.from_toml(toml)
    assert p.describe()["framer"] == {"kind": "oa", "window_us": 4000, "stride_us": 1000,
                                      "all_events": False, "max_empty_frames": 1000}
    toml.write_text('[framer]\nkind = "adaptive"\noverlap_max_us = 20000\n')
    with pytest.raises(ValueError, match="less than window_us"):
        Pipeline.from_toml(toml)


def test_colour_tables_run_through_their_anchors():
    """A table of 256 colours interpolated between its anchors, the first at 0 and the last at 255."""
    grey = _table(((0, 0, 0), (255, 255, 255)))
    assert grey.dtype == np.uint8 and grey.shape == (256, 3)
    np.testing.assert_array_equal(grey, np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1))
    three = _table(((0, 0, 0), (200, 100, 0), (0, 0, 0)))
    assert tuple(three[0]) == (0, 0, 0) and tuple(three[255]) == (0, 0, 0) and tuple(three[128]) == (199, 100, 0)
