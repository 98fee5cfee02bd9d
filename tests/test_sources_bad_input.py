"""Bad input: empty, truncated, garbage, wrong headers. Every reader either reads cleanly (with a
warning where it stopped early) or raises one EventError naming the file (and the byte where it can);
never another exception, a hang, or events outside the sensor. Fuzzed with hypothesis."""

import functools
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from evstream.sources import EventWarning, aedat2, hdf5, open_source, prophesee_raw, text
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_sources_formats import write_dat, write_mat, write_nmnist

from evstream.events import EventError, Geometry, concat
from evstream.testing import random_stream

G = Geometry(128, 128)


def read_all(path, **options):
    """Replay a file; returns the event count, or raises EventError. Anything else fails the test."""
    src = open_source(path, **options)
    n = 0
    for c in src:
        assert (c.x < src.geometry.width).all() and (c.y < src.geometry.height).all()
        assert c.p.max(initial=0) <= 1 and np.all(np.diff(c.t) >= 0)
        n += len(c)
    return n


def sample_files(d):
    """One small valid file per writable format: name -> path."""
    s = random_stream(0, 400, G).replace(label=None)
    files = {}
    for name, write in {
        "a.raw": lambda p: prophesee_raw.save(p, s),
        "b.raw": lambda p: prophesee_raw.save(p, s, version="evt2"),
        "c.dat": lambda p: write_dat(p, s),
        "d.bin": lambda p: write_nmnist(p, s),
        "e.aedat": lambda p: aedat2.save(p, s.t, s.x, s.y, s.p),
        "f.txt": lambda p: text.save(p, s),
        "g.h5": lambda p: hdf5.save(p, s, compression=None),
        "h.npy": lambda p: np.save(p, s.to_structured()),
        "i.mat": lambda p: write_mat(p, "events", np.stack([s.x, s.y, s.p, s.t], axis=1), compress=True),
    }.items():
        write(d / name)
        files[name] = d / name
    return files


@functools.cache
def _samples() -> dict:
    with tempfile.TemporaryDirectory() as d:
        return {name: path.read_bytes() for name, path in sample_files(Path(d)).items()}


@pytest.fixture
def samples():
    return _samples()


def test_empty_and_missing_files(tmp_path):
    for name in ("e.raw", "e.aedat4", "e.txt", "e.bin"):
        (tmp_path / name).write_bytes(b"")
        with pytest.raises(EventError, match=f"{name}: empty file"):
            open_source(tmp_path / name)
    with pytest.raises(EventError, match="no such file"):
        open_source(tmp_path / "nope.raw")


def test_truncated_raw_reads_what_is_there_with_a_warning(tmp_path, samples):
    data = samples["a.raw"]
    (tmp_path / "t.raw").write_bytes(data[:-1])  # half an EVT3 word at the end
    with pytest.warns(EventWarning, match=r"t.raw: truncated: the last 1 byte\(s\) at byte \d+"):
        n = read_all(tmp_path / "t.raw")
    assert 390 <= n <= 400
    (tmp_path / "t.dat").write_bytes(samples["c.dat"][:-3])
    with pytest.warns(EventWarning, match=r"t.dat: truncated: 5 byte\(s\) at byte \d+ are a partial 8-byte"):
        assert read_all(tmp_path / "t.dat") == 399


def test_garbage_after_a_raw_header_is_named_by_byte(tmp_path):
    rng = np.random.default_rng(0)
    body = rng.integers(0, 256, 100_000, dtype=np.uint8).tobytes()
    header = b"% evt 3.0\n% format EVT3;height=720;width=1280\n% end\n"
    (tmp_path / "g.raw").write_bytes(header + body)
    with pytest.raises(EventError, match=r"g.raw at byte \d+: .*(unknown types|outside the 1280x720)"):
        read_all(tmp_path / "g.raw")


def test_a_wrong_header_version_is_caught(tmp_path, samples):
    evt3_body = samples["a.raw"].split(b"% end\n", 1)[1]
    (tmp_path / "w.raw").write_bytes(b"% evt 2.0\n% geometry 128x128\n% end\n" + evt3_body * 40)
    with pytest.raises(EventError, match=r"w.raw at byte \d+: .*(not EVT2 data|outside)"):
        read_all(tmp_path / "w.raw")
    (tmp_path / "v.raw").write_bytes(b"% evt 9.0\n% end\n" + evt3_body)
    with pytest.raises(EventError, match=r"v.raw: RAW header \(bytes 0..16\) names no EVT version"):
        open_source(tmp_path / "v.raw")  # it named no byte, and advised a version= that evstream.open lacks
    assert len(concat(list(open_source(tmp_path / "v.raw", version="evt3")))) > 0  # what the error advises
    (tmp_path / "u.raw").write_bytes(b"% evt 2.1\n% end\n" + evt3_body)
    with pytest.raises(EventError, match="evt2.1 is not supported"):
        open_source(tmp_path / "u.raw")


def test_text_with_a_bad_line_names_its_byte(tmp_path):
    (tmp_path / "b.txt").write_text("0.1 1 2 1\n0.2 3 4 0\n0.3 five 6 1\n")
    with pytest.raises(EventError, match=r"b.txt at byte 20: line b'0.3 five 6 1' is not 4 numbers"):
        read_all(tmp_path / "b.txt", geometry=(10, 10))


def test_unknown_bytes_are_refused_by_name(tmp_path):
    (tmp_path / "y.xyz").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(EventError, match="y.xyz: unrecognised format"):
        open_source(tmp_path / "y.xyz")


# -- fuzzing -----------------------------------------------------------------------------------------
# each example writes and reads a file: 3/5 of the profile's count (HYPOTHESIS_PROFILE=thorough: 240)
FUZZ = settings(max_examples=max(1, settings().max_examples * 3 // 5), deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _survives(path, data: bytes):
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EventWarning)
        try:
            read_all(path)
        except EventError as e:
            assert str(path.name) in str(e)


def test_a_raw_header_whose_evt_line_is_empty_is_read_or_refused_in_one_line(tmp_path):
    """'% evt ' with no value (a file cut inside its header: hypothesis found it) was an IndexError."""
    head = _samples()["a.raw"].split(b"% evt", 1)[0]
    for tail in (b"% evt ", b"% evt \n", b"% evt \n% end\n"):
        _survives(tmp_path / "a.raw", head + tail)


@pytest.mark.parametrize("name", ["a.raw", "b.raw", "c.dat", "d.bin", "e.aedat", "f.txt", "g.h5", "h.npy",
                                  "i.mat"])
@FUZZ
@given(cut=st.floats(0, 1), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=8))
def test_fuzz_truncated_and_corrupted_files(tmp_path, name, cut, flips):
    samples = _samples()
    data = bytearray(samples[name][: max(1, int(len(samples[name]) * cut))])
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    _survives(tmp_path / name, bytes(data))


@pytest.mark.parametrize("name", ["a.raw", "b.raw", "c.dat", "e.aedat", "i.mat"])
@FUZZ
@given(body=st.binary(min_size=0, max_size=3000))
def test_fuzz_random_bodies_after_valid_headers(tmp_path, name, body):
    data = _samples()[name]
    marks = {"a.raw": (b"% end\n", 0), "b.raw": (b"% end\n", 0), "c.dat": (b"% Version 2\n", 2),
             "e.aedat": (b"evstream\r\n", 0), "i.mat": (b"IM", 0)}
    mark, extra = marks[name]
    keep = data.index(mark) + len(mark) + extra
    _survives(tmp_path / name, data[:keep] + body)


def test_fuzz_real_files_truncated(real_data, tmp_path):
    """Each real recording cut at a few places: a partial read with a warning, or a clean error."""
    for src in sorted(real_data.iterdir()):
        if src.suffix == ".md":
            continue
        data = src.read_bytes()
        for frac in (0.01, 0.5, 0.999):
            _survives(tmp_path / src.name, data[: max(1, int(len(data) * frac))])
