"""Files made to break the readers (issue 22's decoder findings): each was an internal error, a numpy
message of several lines, or gigabytes of memory for a file of kilobytes. Now: one EventError naming the
file, or the events, in memory bounded by what the file holds."""

import io
import os
import threading
import tracemalloc
import zipfile

import numpy as np
import pytest
from evstream.sources import native, open_source
from fuzzing import zip_bomb

from evstream.events import EventError, Geometry
from evstream.testing import random_stream

G = Geometry(64, 48)
EVENT = [("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1")]


def count(path, **options) -> int:
    return sum(len(c) for c in open_source(path, **options))


def test_dat_version_line_without_a_number(tmp_path):
    path = tmp_path / "v.dat"
    path.write_bytes(b"% Data file containing Event2d events.\n% Version \n" + bytes([0, 8]) + bytes(80))
    with pytest.raises(EventError, match=r"v.dat: DAT header version '' is not a number"):  # was IndexError
        open_source(path)


def test_structured_npy_of_two_dimensions(tmp_path):
    np.save(tmp_path / "s.npy", np.zeros((2, 3), dtype=EVENT))
    with pytest.raises(EventError, match=r"s.npy: structured array of shape \(2, 3\): expected one dimension"):
        count(tmp_path / "s.npy")  # was TypeError in events.py


def test_event_chunk_refuses_fields_of_two_dimensions():
    with pytest.raises(EventError, match=r"field 't' has shape \(2, 3\)"):
        from evstream.events import EventChunk

        EventChunk.from_arrays(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)), G)


def test_native_npz_whose_width_is_an_array(tmp_path):
    s = random_stream(0, 10, G)
    np.savez(tmp_path / "w.npz", t=s.t, x=s.x, y=s.y, p=s.p, width=np.array([64, 2]), height=np.int64(48))
    with pytest.raises(EventError, match=r"w.npz: unreadable native file: array 'width': int64 of shape \(2,\)"):
        open_source(tmp_path / "w.npz")  # was TypeError in native.py


@pytest.mark.parametrize("native_file", [True, False])
def test_npz_member_with_a_damaged_npy_header(tmp_path, native_file):
    s = random_stream(0, 10, G)
    arrays = {"t": s.t, "x": s.x, "y": s.y, "p": s.p, **({"width": np.int64(64), "height": np.int64(48)}
                                                         if native_file else {})}
    path = tmp_path / "h.npz"
    with zipfile.ZipFile(path, "w") as z:
        for k, a in arrays.items():
            b = io.BytesIO()
            np.save(b, a)
            raw = bytearray(b.getvalue())
            if k == "t":
                raw[raw.index(b"'descr'") + 2] = ord("(")  # the header's dict no longer parses
            z.writestr(f"{k}.npy", bytes(raw))
    with pytest.raises(EventError, match=r"h.npz: unreadable .*array 't': .npy header .*damaged"):
        count(path)  # was tokenize.TokenError / a numpy message


def test_npy_with_the_longest_header_version_1_allows_reads(tmp_path):
    """A 65,535-byte header is legal (.npy 1.0); numpy refused it in three lines."""
    a = np.zeros(3, dtype=EVENT)
    a["t"] = [1, 2, 3]
    b = io.BytesIO()
    np.save(b, a)
    raw = b.getvalue()
    size = int.from_bytes(raw[8:10], "little")
    header = raw[10:10 + size].rstrip()
    path = tmp_path / "long.npy"
    path.write_bytes(raw[:8] + (65535).to_bytes(2, "little") + header + b" " * (65534 - len(header)) + b"\n"
                     + raw[10 + size:])
    assert count(path, geometry=(8, 8)) == 3


@pytest.mark.parametrize("kind", ["claim", "inflate"])
def test_npz_members_claiming_gigabytes_stay_within_what_the_file_holds(tmp_path, kind):
    path = tmp_path / "bomb.npz"
    path.write_bytes(zip_bomb(kind))
    tracemalloc.start()
    try:
        with pytest.raises(EventError, match=r"bomb.npz: (unreadable native file: )?array '[tx]'"):
            count(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 << 20, f"{peak >> 20} MiB for a {path.stat().st_size >> 10} KiB file"  # was 2.2-4.3 GB


def test_zip_member_claiming_more_than_deflate_can_pack(tmp_path):
    s = random_stream(0, 100, G)
    path = tmp_path / "lie.npz"
    native.save(path, s)
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("t.npy")
    data = bytearray(path.read_bytes())
    cd = data.find(b"PK\x01\x02")  # the central directory: the first entry is t.npy's
    assert data[cd + 46:cd + 51] == b"t.npy"
    data[cd + 24:cd + 28] = (info.compress_size * 2000).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(EventError, match=r"lie.npz: .*array 't': .*more than deflate can pack"):
        count(path)


def _peak_bytes_counting(path, n: int) -> int:
    """Peak bytes allocated (tracemalloc) while `path` is read through; it holds `n` events."""
    tracemalloc.start()
    try:
        assert count(path) == n
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_native_npz_streams_in_constant_memory(tmp_path):
    """Replaying a native .npz holds a few blocks, not the recording (it loaded every member whole)."""
    peaks = []
    count(tmp_path / "small.npz") if native.save(tmp_path / "small.npz", random_stream(0, 10, G)) else None
    for n in (1_000_000, 4_000_000):
        s = random_stream(1, n, G)
        native.save(tmp_path / f"{n}.npz", s)
        peaks.append(_peak_bytes_counting(tmp_path / f"{n}.npz", n))
    assert peaks[1] < 1.2 * peaks[0] + (2 << 20), peaks  # 4x the events, the same memory (was: 4x)


@pytest.mark.parametrize("chunk_us", [None, 3000])
def test_native_stream_chunks_as_before(tmp_path, chunk_us):
    s = random_stream(2, 150_000, G)  # more than one streamed block (65,536 events)
    native.save(tmp_path / "a.npz", s)
    chunks = list(open_source(tmp_path / "a.npz", chunk_events=7000, chunk_us=chunk_us))
    assert np.array_equal(np.concatenate([c.t for c in chunks]), s.t)
    assert np.array_equal(np.concatenate([c.label for c in chunks]), s.label)
    assert all(a.t_end <= b.t[0] for a, b in zip(chunks, chunks[1:]) if len(b))
    if chunk_us is None:
        assert [len(c) for c in chunks[:-1]] == [7000] * (len(chunks) - 1)
    else:
        t0 = int(s.t[0])
        assert all((c.t[0] - t0) // chunk_us == (c.t[-1] - t0) // chunk_us for c in chunks if len(c))


def test_a_fifo_is_refused_naming_it_without_blocking(tmp_path):
    fifo = tmp_path / "f"
    os.mkfifo(fifo)
    result = []
    worker = threading.Thread(target=lambda: result.append(_error_of(fifo)), daemon=True)
    worker.start()
    worker.join(30)
    if worker.is_alive():  # unblock the reader before failing
        with open(fifo, "wb"):
            pass
        pytest.fail("open_source blocked on a FIFO with no writer")
    assert f"{fifo}: not a regular file" in result[0]


def _error_of(path) -> str:
    try:
        open_source(path)
    except EventError as e:
        return str(e)
    return "no error"


def test_plain_npz_streams_in_constant_memory(tmp_path):
    """An .npz of t, x, y, p (not evstream's own) is streamed too: its members were loaded whole."""
    peaks = []
    for n in (1_000_000, 4_000_000):
        s = random_stream(1, n, G)
        np.savez_compressed(tmp_path / f"{n}.npz", t=s.t, x=s.x, y=s.y, p=s.p)
        count(tmp_path / f"{n}.npz")  # first read: kernels loaded
        peaks.append(_peak_bytes_counting(tmp_path / f"{n}.npz", n))
    assert peaks[1] < 1.2 * peaks[0] + (2 << 20), peaks
