import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from evstream.sources import native, open_source

from evstream.cli import main
from evstream.events import EventError, Geometry
from evstream.testing import random_stream

G = Geometry(24, 18)


def test_native_round_trip_in_chunks(tmp_path):
    s = random_stream(0, 1234, G)
    native.save(tmp_path / "a.npz", s, {"scene": "test"})
    src = open_source(tmp_path / "a.npz", chunk_events=100)
    chunks = list(src)
    assert src.geometry == G and src.info()["meta"] == {"scene": "test"}
    assert [len(c) for c in chunks] == [100] * 12 + [34]
    assert np.array_equal(np.concatenate([c.t for c in chunks]), s.t)
    assert np.array_equal(np.concatenate([c.label for c in chunks]), s.label)
    assert all(a.t_end == b.t[0] for a, b in zip(chunks, chunks[1:]))


@pytest.mark.parametrize("compress", [False, True])
def test_native_members_read_as_numpy_writes_them(tmp_path, compress):
    s = random_stream(2, 5000, G)
    path = tmp_path / "a.npz"
    native.save(path, s, {"scene": "ü"}, compress=compress)
    ref = np.load(path, allow_pickle=False)
    with zipfile.ZipFile(path) as z, open(path, "rb") as f:
        for info in z.infolist():
            a = native.read_member(f, info)
            want = ref[info.filename[:-4]]
            assert a.dtype == want.dtype and a.shape == want.shape and np.array_equal(a, want)
            assert a.flags.writeable
    assert open_source(path).info()["meta"] == {"scene": "ü"}


def test_native_stored_member_with_a_flipped_byte_fails_its_crc(tmp_path):
    path = tmp_path / "a.npz"
    native.save(path, random_stream(3, 2000, G), compress=False)
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("y.npy")
    data = bytearray(path.read_bytes())
    data[info.header_offset + info.compress_size // 2] ^= 0x01  # a y value, still inside the sensor
    path.write_bytes(bytes(data))
    with pytest.raises(EventError, match=r"a.npz: unreadable native file: array 'y': bytes \d+\.\.\d+ fail their CRC"):
        list(open_source(path))


def test_native_member_of_python_objects_is_refused(tmp_path):
    path = tmp_path / "a.npz"
    s = random_stream(4, 10, G)
    np.savez(path, t=s.t, x=s.x, y=s.y, p=s.p, width=np.int64(24), height=np.int64(18),
             meta=np.array([{"a": 1}], dtype=object))
    with pytest.raises(EventError, match="array 'meta': it holds Python objects"):
        open_source(path)


def test_native_chunks_by_time(tmp_path):
    s = random_stream(1, 1000, G)
    native.save(tmp_path / "a.npz", s)
    chunks = list(open_source(tmp_path / "a.npz", chunk_us=5000))
    assert sum(map(len, chunks)) == 1000
    assert all(c.duration_us < 5000 for c in chunks)


def test_bad_files_give_clear_errors(tmp_path):
    with pytest.raises(EventError, match="no such file"):
        open_source(tmp_path / "missing.npz")
    (tmp_path / "empty.npz").write_bytes(b"")
    with pytest.raises(EventError, match="empty file"):
        open_source(tmp_path / "empty.npz")
    (tmp_path / "junk.bin").write_bytes(b"\x00\x01junk" * 100)
    with pytest.raises(EventError, match="unrecognised format"):
        open_source(tmp_path / "junk.bin")
    s = random_stream(0, 50, G)
    native.save(tmp_path / "bad.npz", s.replace(x=np.full(50, 99, np.uint16)))
    with pytest.raises(EventError, match=r"bad.npz: event 0: \(99, .*outside the 24x18 sensor"):
        list(open_source(tmp_path / "bad.npz"))


def test_info_json_reports_true_label_counts(tmp_path, capsys):
    s = random_stream(2, 700, G)
    native.save(tmp_path / "a.npz", s)
    assert main(["info", str(tmp_path / "a.npz"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["events"] == 700 and (out["width"], out["height"]) == (24, 18)
    assert out["labels"] == {"signal": int((s.label == 0).sum()), "background": int((s.label == 1).sum()),
                             "hot_pixel": int((s.label == 2).sum())}
    assert out["duration_us"] == int(s.t[-1] - s.t[0]) and out["format"] == "native"


def test_cli_exit_codes_and_one_line_errors(tmp_path):
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "info", str(tmp_path / "nope.npz")],
                       capture_output=True, text=True)
    assert r.returncode == 1
    assert r.stderr.strip().count("\n") == 0 and "no such file" in r.stderr
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "frobnicate"], capture_output=True, text=True)
    assert r.returncode == 2


def test_synth_then_replay_writes_rrd(tmp_path, capsys):
    npz, rrd = tmp_path / "bar.npz", tmp_path / "bar.rrd"
    assert main(["synth", "bar", str(npz), "--duration-ms", "100", "--width", "64", "--height", "48",
                 "--noise-ratio", "0.5"]) == 0
    assert main(["replay", str(npz), "--save", str(rrd), "--json", "--denoise", "truth"]) == 0
    stats = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert stats["events_background"] > 0 and stats["events_signal"] > 0
    assert rrd.stat().st_size > 10_000


def test_progress_bar_gives_the_percent_of_the_file(tmp_path):
    import io
    import types

    from evstream.cli import Progress
    from evstream.pipeline import RunStats

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    path = tmp_path / "r.npz"
    native.save(path, random_stream(3, 10_000))
    src = open_source(path, chunk_events=2_500)
    screen = Terminal()
    progress, stats = Progress(src, screen, min_interval_s=0, delay_s=0), RunStats()
    for chunk in src:
        stats.add(chunk, 0)
        progress(types.SimpleNamespace(stats=stats))
    shown = screen.getvalue()
    assert [p for p in ("25%", "50%", "75%", "100%") if p in shown] == ["25%", "50%", "75%", "100%"]
    assert "10,000 events" in shown
    unknown = Terminal()
    p = Progress(None, unknown, min_interval_s=0, delay_s=0)
    p(types.SimpleNamespace(stats=stats))
    p.done()
    assert "10,000 events" in unknown.getvalue() and "%|" not in unknown.getvalue()  # no percent it cannot know
    for quiet, stream in ((True, Terminal()), (False, io.StringIO())):  # --quiet, or not a terminal: nothing
        p = Progress(src, stream, quiet=quiet, min_interval_s=0, delay_s=0)
        p(types.SimpleNamespace(stats=stats))
        p.done()
        assert stream.getvalue() == ""


def test_a_native_file_is_closed_when_reading_ends_early_or_never_starts():
    """`evstream.info`, `open` without reading, and a time range that stops reading early each left the
    file open for the garbage collector (ResourceWarning: unclosed file, under pytest and `python -X dev`):
    the header check opened every column, and the column streams of a read left early stayed open."""
    import gc
    import warnings
    from pathlib import Path

    import evstream

    rec = Path(__file__).resolve().parents[1] / "recordings" / "bar.npz"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        evstream.info(rec)
        evstream.open(rec)
        assert 0 < len(evstream.read(rec, end_us=60_000)) < len(evstream.read(rec))
        gc.collect()
    assert [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)] == []


def test_info_on_an_empty_range_says_no_events(capsys):
    """`evstream info REC --start-us` past the end printed 'duration 0.000000 s  (None .. None µs)'."""
    from pathlib import Path

    rec = Path(__file__).resolve().parents[1] / "recordings" / "bar.npz"
    assert main(["info", str(rec), "--start-us", "99999999"]) == 0
    out = capsys.readouterr().out
    assert "None" not in out and "duration   -  (no events)" in out
    assert main(["info", str(rec)]) == 0
    assert "(0 .. " in capsys.readouterr().out
