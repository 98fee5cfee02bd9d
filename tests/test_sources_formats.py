"""Each reader on files we write: round trips, detection by content (not extension), chunking by count
and by time, watermarks, geometry override, timestamp policies, clock unwrapping, constant memory."""

import re
import struct
import tracemalloc
import zlib

import numpy as np
import pytest
from evstream.sources import EventWarning, aedat2, hdf5, open_source, prophesee_raw, text
from evstream.sources import numpy_files as npf
from hypothesis import given
from hypothesis import strategies as st

from evstream.events import EventChunk, EventError, Geometry, concat
from evstream.testing import random_stream

G = Geometry(128, 128)


def stream(n=3000, seed=0, g=G, t0=0):
    s = random_stream(seed, n, g)
    return s.replace(t=s.t + t0, label=None)


def same(a: EventChunk, b: EventChunk):
    for k in "txyp":
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)


# -- writers for formats we only read ---------------------------------------------------------------
def write_dat(path, s: EventChunk, t_raw=None, header=b""):
    rec = np.empty((len(s), 2), "<u4")
    rec[:, 0] = (s.t if t_raw is None else t_raw) & 0xFFFFFFFF
    rec[:, 1] = s.x.astype(np.uint32) | (s.y.astype(np.uint32) << 14) | (s.p.astype(np.uint32) << 28)
    path.write_bytes(b"% Data file containing Event2d events.\n% Version 2\n" + header + bytes([0, 8])
                     + rec.tobytes())


def write_nmnist(path, s: EventChunk):
    r = np.zeros((len(s), 5), np.uint8)
    t = s.t.astype(np.uint32)
    r[:, 0], r[:, 1] = s.x, s.y
    r[:, 2] = (s.p << 7) | ((t >> 16) & 0x7F)
    r[:, 3], r[:, 4] = (t >> 8) & 0xFF, t & 0xFF
    path.write_bytes(r.tobytes())


def _mat_element(kind, payload: bytes) -> bytes:
    return struct.pack("<II", kind, len(payload)) + payload + b"\0" * (-len(payload) % 8)


def write_mat(path, name: str, a: np.ndarray, compress: bool):
    a = np.asarray(a, np.int32)
    body = (_mat_element(6, struct.pack("<II", 12, 0)) + _mat_element(5, struct.pack("<ii", *a.shape))
            + _mat_element(1, name.encode()) + _mat_element(5, a.T.astype("<i4").tobytes()))
    matrix = _mat_element(14, body)
    element = _mat_element(15, zlib.compress(matrix)) if compress else matrix
    head = b"MATLAB 5.0 MAT-file, written by evstream tests".ljust(116, b" ") + b"\0" * 8 + b"\x00\x01IM"
    path.write_bytes(head + element)


# -- round trips ------------------------------------------------------------------------------------
def test_evt3_and_evt2_raw_round_trip(tmp_path):
    s = stream(5000, g=Geometry(640, 480), t0=123_456)
    for version in ("evt3", "evt2"):
        path = tmp_path / f"a_{version}.raw"
        prophesee_raw.save(path, [s[:2000], s[2000:]], version=version)
        src = open_source(path)
        assert src.format == version and src.geometry == Geometry(640, 480)
        same(concat(list(src)), s)


def test_raw_writer_keeps_absolute_time_through_an_origin(tmp_path):
    s = stream(1000, t0=1_605_537_493_718_345)
    path = tmp_path / "abs.raw"
    prophesee_raw.save(path, s)
    assert path.stat().st_size < 10_000
    assert b"% t_origin_us " in path.read_bytes()[:300]
    same(concat(list(open_source(path))), s)


def test_dat_round_trip_and_32_bit_clock_unwrap(tmp_path):
    s = stream(4000, g=Geometry(304, 240), t0=(1 << 32) - 50_000)
    write_dat(tmp_path / "a.dat", s)
    src = open_source(tmp_path / "a.dat")
    assert src.format == "dat" and src.geometry == Geometry(304, 240)
    same(concat(list(src)), s)
    assert src.counters["clock_wraps"] == 1


def test_dat_geometry_lines_are_read(tmp_path):
    s = stream(100, g=Geometry(640, 480))
    write_dat(tmp_path / "g.dat", s, header=b"% Width 640\n% Height 480\n")
    assert open_source(tmp_path / "g.dat").geometry == Geometry(640, 480)


def test_nmnist_round_trip_and_fitted_geometry(tmp_path):
    s = stream(2000, g=Geometry(34, 34))
    write_nmnist(tmp_path / "a.bin", s)
    src = open_source(tmp_path / "a.bin")
    assert src.format == "nmnist" and src.geometry == Geometry(34, 34)
    same(concat(list(src)), s)


@pytest.mark.parametrize("fmt, g, field, value", [
    ("nmnist", Geometry(300, 34), "x", 299), ("nmnist", Geometry(34, 34), "t", 1 << 23),
    ("dat", Geometry(20000, 240), "x", 16384), ("dat", Geometry(304, 240), "t", 1 << 32)])
def test_dat_and_nmnist_save_refuse_events_their_columns_cannot_hold(tmp_path, fmt, g, field, value):
    """`sources.nmnist.save` / `sources.dat.save` (the ahead-of-time build's recordings) wrote x = 299 into a
    uint8 column as 43, t = 2^23 as 0: a file of other events, without a word. Now a ValueError naming the
    event; what fits reads back as it was."""
    from evstream.sources import dat, nmnist

    module, ext = {"nmnist": (nmnist, ".bin"), "dat": (dat, ".dat")}[fmt]
    s = stream(200, g=Geometry(34, 34) if fmt == "nmnist" else Geometry(304, 240))
    module.save(tmp_path / f"ok{ext}", s)
    same(concat(list(open_source(tmp_path / f"ok{ext}"))), s)
    column = getattr(s, field).copy()
    column[150:] = np.maximum(column[150:], value) if field == "t" else value
    with pytest.raises(ValueError, match=rf"bad\{ext}: event 150 \(t=.*\) does not fit"):
        module.save(tmp_path / f"bad{ext}", s.replace(geometry=g, **{field: column}))


def test_aedat2_round_trip_with_jaer_address_convention(tmp_path):
    s = stream(3000, t0=(1 << 32) - 50_000)
    aedat2.save(tmp_path / "a.aedat", s.t, s.x, s.y, s.p)
    raw = (tmp_path / "a.aedat").read_bytes()
    body = raw[raw.index(b"evstream\r\n") + 10:]
    addr = np.frombuffer(body, ">u4")[0]
    assert 127 - ((addr >> 1) & 127) == s.x[0] and (addr & 1) == 1 - s.p[0]  # jAER: bit 0 set = OFF
    src = open_source(tmp_path / "a.aedat")
    assert src.format == "aedat2" and src.geometry == Geometry(128, 128)
    same(concat(list(src)), s)
    assert src.counters["clock_wraps"] == 1


@pytest.mark.parametrize("unit", ["s", "us"])
def test_text_round_trip_with_detected_time_unit(tmp_path, unit):
    s = stream(1500)
    text.save(tmp_path / "a.txt", s, time_unit=unit)
    src = open_source(tmp_path / "a.txt", block_bytes=4096)
    assert src.format == "text" and src.time_unit == unit and src.geometry == G
    same(concat(list(src)), s)


def test_text_with_comments_size_line_and_signed_polarity(tmp_path):
    (tmp_path / "b.txt").write_text("# t x y p\n240 180\n0.000001 1 2 -1\n0.000002 239 179 1\n")
    src = open_source(tmp_path / "b.txt")
    ev = concat(list(src))
    assert src.geometry == Geometry(240, 180)
    assert ev.t.tolist() == [1, 2] and ev.x.tolist() == [1, 239] and ev.p.tolist() == [0, 1]


def test_hdf5_layouts(tmp_path):
    import h5py  # declared (dev) dependency: a broken install fails
    s = stream(2500)
    hdf5.save(tmp_path / "a.h5", s)
    same(concat(list(open_source(tmp_path / "a.h5", block_bytes=1024))), s)
    with h5py.File(tmp_path / "b.h5", "w") as f:  # compound /events, float seconds, no size
        f.create_dataset("events", data=np.rec.fromarrays(
            [s.t / 1e6, s.x, s.y, s.p.astype(np.int8) * 2 - 1], names="timestamp,x,y,polarity"))
    src = open_source(tmp_path / "b.h5")
    assert src.geometry == G and src.time_unit == "s"
    same(concat(list(src)), s)
    with h5py.File(tmp_path / "c.h5", "w") as f:  # root datasets
        for k, name in zip("txyp", ("ts", "xs", "ys", "ps")):
            f[name] = getattr(s, k)
    same(concat(list(open_source(tmp_path / "c.h5"))), s)


def test_numpy_layouts(tmp_path):
    s = stream(2000)
    np.save(tmp_path / "a.npy", s.to_structured())
    np.save(tmp_path / "b.npy", np.stack([s.t, s.x, s.y, s.p], axis=1))
    np.savez(tmp_path / "c.npz", t=s.t, x=s.x, y=s.y, p=s.p, sensor_size=np.array([200, 150]))
    for name, fmt in (("a.npy", "npy"), ("b.npy", "npy"), ("c.npz", "npz")):
        src = open_source(tmp_path / name)
        assert src.format == fmt
        same(concat(list(src)), s)
    assert open_source(tmp_path / "c.npz").geometry == Geometry(200, 150)
    assert open_source(tmp_path / "a.npy").geometry == G
    assert npf.probe(b"\x93NUMPY", str(tmp_path / "a.npy"))


@pytest.mark.parametrize("compress", [False, True])
def test_mat_v5_numeric_matrix(tmp_path, compress):
    s = stream(1000)
    write_mat(tmp_path / "a.mat", "events", np.stack([s.x, s.y, s.p.astype(int) * 2 - 1, s.t], axis=1),
              compress)
    src = open_source(tmp_path / "a.mat")
    assert src.format == "mat" and src.geometry == G
    same(concat(list(src)), s)


def test_detection_is_by_content_not_extension(tmp_path):
    s = stream(500, g=Geometry(640, 480))
    prophesee_raw.save(tmp_path / "raw.dat", s)
    write_dat(tmp_path / "dat.raw", s)
    hdf5.save(tmp_path / "h5.raw", s)
    np.save(tmp_path / "npy.npy", s.to_structured())
    (tmp_path / "npy.npy").rename(tmp_path / "npy.h5")
    for name, fmt in (("raw.dat", "evt3"), ("dat.raw", "dat"), ("h5.raw", "hdf5"), ("npy.h5", "npy")):
        assert open_source(tmp_path / name).format == fmt, name


# -- chunking, watermarks, options ---------------------------------------------------------------------
def test_chunking_by_count_and_time_gives_the_same_events(tmp_path):
    s = stream(20_000, g=Geometry(640, 480))
    prophesee_raw.save(tmp_path / "a.raw", s)
    whole = concat(list(open_source(tmp_path / "a.raw")))
    same(whole, s)
    for opts in (dict(chunk_events=777, block_bytes=1024), dict(chunk_us=3_000, block_bytes=2048),
                 dict(chunk_events=1)):
        chunks = list(open_source(tmp_path / "a.raw", **opts))
        same(concat(chunks), s)
        if "chunk_us" in opts:
            assert all(c.duration_us < 3_000 for c in chunks)
        else:
            assert all(len(c) == opts["chunk_events"] for c in chunks[:-1])
        for a, b in zip(chunks, chunks[1:]):
            assert a.t[-1] <= a.t_end <= b.t[0]


def test_strict_policy_watermark_is_the_next_event(tmp_path):
    s = stream(1000)
    text.save(tmp_path / "a.txt", s, time_unit="us")
    chunks = list(open_source(tmp_path / "a.txt", chunk_events=100))  # text: policy 'error'
    assert all(a.t_end == b.t[0] for a, b in zip(chunks, chunks[1:]))


def test_geometry_override_and_a_too_small_one(tmp_path):
    s = stream(300, g=Geometry(640, 480))
    prophesee_raw.save(tmp_path / "a.raw", s)
    assert open_source(tmp_path / "a.raw", geometry=(700, 500)).geometry == Geometry(700, 500)
    assert open_source(tmp_path / "a.raw", geometry="800x600").geometry == Geometry(800, 600)
    with pytest.raises(EventError, match=r"a.raw at byte \d+: event \d+: .* outside the 10x10 sensor"):
        list(open_source(tmp_path / "a.raw", geometry=(10, 10)))
    write_dat(tmp_path / "a.dat", s)
    with pytest.raises(EventError, match=r"a.dat at byte \d+: event"):
        list(open_source(tmp_path / "a.dat", geometry=(10, 10)))


def test_timestamp_policies_on_a_stream_stepping_back(tmp_path):
    s = stream(1000, g=Geometry(640, 480))
    t = s.t.copy()
    t[500:510] = t[499] - 3  # a few events stepping back (EVT3 TIME_LOW glitches look like this)
    # spell each event with its own TIME_HIGH/TIME_LOW so the stream can step back
    words = []
    for ti, xi, yi, pi in zip(t, s.x, s.y, s.p):
        words += [0x8000 | (int(ti) >> 12) & 0xFFF, 0x6000 | int(ti) & 0xFFF, int(yi), 0x2000 | int(pi) << 11 | int(xi)]
    path = tmp_path / "back.raw"
    path.write_bytes(b"% evt 3.0\n% geometry 640x480\n% end\n" + np.array(words, "<u2").tobytes())
    ev = concat(list(open_source(path)))  # default for RAW: sort
    assert np.all(np.diff(ev.t) >= 0) and len(ev) >= 990
    with pytest.raises(EventError, match=r"back.raw: event \d+: timestamp .* goes back"):
        list(open_source(path, timestamps="error"))
    src = open_source(path, timestamps="drop")
    with pytest.warns(EventWarning, match="dropped"):
        n = sum(map(len, src))
    assert n + src.dropped == 1000 and src.dropped > 0


def _peak_replay_bytes(path) -> int:
    src = open_source(path, chunk_events=20_000, block_bytes=256 << 10)
    tracemalloc.start()
    n = sum(len(c) for c in src)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return n, peak


def test_replay_runs_at_constant_memory(tmp_path):
    sizes = (200_000, 1_000_000)
    for n in sizes:
        s = stream(n, g=Geometry(640, 480))
        prophesee_raw.save(tmp_path / f"{n}.raw", (s[i : i + 100_000] for i in range(0, n, 100_000)))
    del s
    _peak_replay_bytes(tmp_path / f"{sizes[0]}.raw")  # warm up: numba loads its kernels once
    peaks = {}
    for n in sizes:
        got, peaks[n] = _peak_replay_bytes(tmp_path / f"{n}.raw")
        assert got == n
    # five times the events, the same working set (a block and a chunk or two), well under the
    # 13 MB the big stream decodes to
    assert peaks[1_000_000] < 1.25 * peaks[200_000] + (256 << 10), peaks
    assert peaks[1_000_000] < 13_000_000 / 2, peaks


# -- the text parser kernel against Python's float() --------------------------------------------------
number_text = st.one_of(
    st.integers(-10**12, 10**12).map(str),
    st.floats(-1e6, 1e6, allow_nan=False).map(lambda v: f"{v:.9f}"),
    st.floats(-1e6, 1e6, allow_nan=False).map(repr),
    st.floats(1e-9, 1e3).map(lambda v: f"{v:.3e}"),
)


@given(st.lists(st.tuples(st.lists(number_text, min_size=4, max_size=4), st.sampled_from([" ", "\t", "  "]),
                          st.sampled_from(["\n", "\r\n", " \n"]), st.booleans()), max_size=30))
def test_text_kernel_matches_python_float(lines):
    from evstream.sources.text import _parse_kernel

    text_ = ""
    want = []
    for fields, sep, end, comment in lines:
        if comment:
            text_ += "# a comment line\n"
        text_ += sep.join(fields) + end
        want.append([float(f) for f in fields])
    data = text_.encode()
    out = np.empty((data.count(b"\n") + 1, 4))
    rows, bad = _parse_kernel(np.frombuffer(data, np.uint8), out)
    assert bad == -1 and rows == len(want)
    np.testing.assert_allclose(out[:rows], np.array(want).reshape(-1, 4), rtol=1e-14, atol=1e-290)  # subnormals aside


@pytest.mark.parametrize("number", ["0.000000000123456789012345678", "000000000000000000001.5",
                                    "-0.00000000000000000000", "1.23456789012345678901e-5",
                                    "12345678901234567890123"])
def test_text_kernel_keeps_18_significant_digits_after_leading_zeros(number):
    from evstream.sources.text import _parse_kernel

    out = np.empty((2, 4))
    rows, bad = _parse_kernel(np.frombuffer(f"{number} 1 2 0\n".encode(), np.uint8), out)
    assert (rows, bad) == (1, -1)
    assert out[0, 0] == pytest.approx(float(number), rel=1e-15, abs=0)


@given(st.text(alphabet="0123456789.-+eE \t\nx#", max_size=60))
def test_text_kernel_flags_malformed_lines_like_python(s):
    from evstream.sources.text import _parse_kernel

    data = s.encode()
    out = np.empty((data.count(b"\n") + 1, 4))
    rows, bad = _parse_kernel(np.frombuffer(data, np.uint8), out)
    good = []
    first_bad = -1
    pos = 0
    for line in data.split(b"\n"):
        body = line.strip(b" \t\r")
        if body and not body.startswith((b"#", b"%", b"//")):
            fields = body.split()
            try:
                if len(fields) != 4 or any(f.lower().startswith((b"inf", b"nan")) for f in fields):
                    raise ValueError
                good.append([float(f) for f in fields])
            except ValueError:
                first_bad = pos
                break
        pos += len(line) + 1
    assert bad == first_bad
    assert rows == len(good)
    np.testing.assert_allclose(out[:rows], np.array(good).reshape(-1, 4), rtol=1e-14, atol=1e-290)


# -- column orders and HDF5 variants ------------------------------------------------------------------
@pytest.mark.parametrize("order", ["txyp", "xytp", "xypt", "ptxy"])
def test_column_order_is_recognised(tmp_path, order):
    s = stream(1000)
    cols = {"t": s.t / 1e6, "x": s.x, "y": s.y, "p": s.p.astype(int) * 2 - 1}
    table = np.stack([cols[k] for k in order], axis=1)
    np.save(tmp_path / "a.npy", table)
    np.savetxt(tmp_path / "a.txt", table, fmt=["%.6f" if k == "t" else "%d" for k in order])
    write_mat(tmp_path / "a.mat", "events", np.stack([cols[k] if k != "t" else s.t for k in order], axis=1),
              compress=False)
    for name in ("a.npy", "a.txt", "a.mat"):
        src = open_source(tmp_path / name)
        same(concat(list(src)), s)


def test_hdf5_mvsec_and_dsec_layouts(tmp_path):
    import h5py  # declared (dev) dependency: a broken install fails
    s = stream(2000, g=Geometry(346, 260))
    with h5py.File(tmp_path / "mvsec.h5", "w") as f:  # /davis/left/events: x, y, t (s), p (±1)
        f["davis/left/events"] = np.stack([s.x, s.y, s.t / 1e6 + 1500.0, s.p * 2.0 - 1], axis=1)
    src = open_source(tmp_path / "mvsec.h5")
    ev = concat(list(src))
    np.testing.assert_array_equal(ev.t, s.t + 1_500_000_000)
    same(ev.replace(t=ev.t - 1_500_000_000), s)
    with h5py.File(tmp_path / "dsec.h5", "w") as f:  # /events/{t,x,y,p} relative to /t_offset
        for k in "txyp":
            f[f"events/{k}"] = getattr(s, k)
        f["t_offset"] = np.int64(47_000_000)
    same(concat(list(open_source(tmp_path / "dsec.h5"))), s.replace(t=s.t + 47_000_000))


def test_to_events_normalises_every_column_and_names_a_bad_value_by_event_and_byte(tmp_path):
    """The one conversion every reader's columns go through: t to int64 µs (rounded, any unit), x and y
    to uint16 pixel indices, p to 1 = ON; a value that cannot be one names its event, column and byte."""
    from evstream.sources._base import FileSource, guess_time_unit, to_events

    (tmp_path / "f.csv").write_text("")
    src = FileSource(tmp_path / "f.csv")
    b = to_events(src, np.array([1, 2], np.uint32), [0, 65535], np.array([3, 4], np.int64), [-1, 2], "us")
    assert b.t.dtype == np.int64 and b.t.tolist() == [1, 2] and b.x.tolist() == [0, 65535] and b.y.tolist() == [3, 4]
    assert b.x.dtype == b.y.dtype == np.uint16 and b.p.dtype == np.uint8 and b.p.tolist() == [0, 1]
    assert (b.byte_start, b.byte_end, b.record_bytes) == (0, 0, 0)
    b = to_events(src, [1.4, 2.6], [1.0, 2.0], [0, 0], np.array([True, False]), "us", 10, 30, 8)
    assert b.t.tolist() == [1, 3] and b.x.tolist() == [1, 2] and b.p.tolist() == [1, 0] and b.p.dtype == np.uint8
    assert guess_time_unit(np.array([0.5], np.float32)) == guess_time_unit(np.array([0.5])) == "s"
    assert guess_time_unit(np.array([5], np.uint32)) == "us"
    assert (b.byte_start, b.byte_end, b.record_bytes) == (10, 30, 8)
    assert to_events(src, np.array([2, 3], np.int64), [0, 0], [0, 0], [0, 0], "ms").t.tolist() == [2000, 3000]
    big = np.array([2**53 + 1, 2**62 + 3], np.int64)  # integer µs stay exact (no trip through float64)
    assert to_events(src, big, [0, 0], [0, 0], [0, 0], "us").t.tolist() == big.tolist()
    b = to_events(src, np.array([2.6, 3.2], np.float32), [0, 0], [0, 0], [0, 0], "us")
    assert b.t.dtype == np.int64 and b.t.tolist() == [3, 3]
    assert to_events(src, [1.5e-6, 2.5e-3], [0, 0], [0, 0], [0, 0], "s").t.tolist() == [2, 2500]
    with pytest.raises(ValueError, match=r"^time_unit 'h': choose from s, ms, us, ns$"):
        to_events(src, [1], [0], [0], [0], "h")
    # (the value as numpy writes it: "np.float64(nan)" under NumPy 2, "nan" before)
    for t, x, y, at, event, what in (([1.0, np.nan], [0, 0], [0, 0], 10, 1, r"timestamp \S*nan"),
                                     ([1.0, 2.0, np.inf], [0, 0, 0], [0, 0, 0], 0, 2, r"timestamp \S*inf"),
                                     ([1, 2], [0, 65536], [0, 0], 10, 1, r"x = \S*65536\W*: not a pixel index"),
                                     ([1, 2], [0, 1], [0, -1], 10, 1, r"y = \S*-1\W*: not"),
                                     ([1, 2], [65535, 65536], [0, 0], 10, 1, r"x = \S*65536\W*: not"),
                                     ([1, 2], [1.0, 2.5], [0, 0], 10, 1, r"x = \S*2\.5"),
                                     ([1, 2], [0.0, 0.0], [-1.0, 0.0], 0, 0, r"y = \S*-1\.0"),
                                     ([1, 2], [70000.0, 1.0], [0, 0], 10, 0, r"x = \S*70000\.0"),
                                     ([1, 2], np.array([1, 2.5], np.float32), [0, 0], 10, 1, r"x = \S*2\.5")):
        where = f" at byte {at}" if at else ""
        with pytest.raises(EventError, match=rf"^{re.escape(src.path)}{where}: event {event} of a block has {what}"):
            to_events(src, t, x, y, [0] * len(t), "s" if isinstance(t[0], float) else "us", at)
