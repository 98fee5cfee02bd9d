"""HDF5 output streams: `/events/{t,x,y,p}` grow chunk by chunk (sources/hdf5.Writer), holding what the
whole-array writer held (the same datasets, types, attributes, compression and values), with memory that
does not grow with the recording."""

import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest
from evstream.sources import hdf5

import evstream
from evstream.cli import main
from evstream.events import EventChunk, Geometry, concat

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "recordings" / "turntable.npz"


def whole_array_file(path, events):
    """How `hdf5.save` wrote a file before it streamed: every column at once (h5py picks the chunks)."""
    with h5py.File(path, "w") as f:
        f.attrs["width"], f.attrs["height"] = events.geometry.width, events.geometry.height
        f.attrs["t_unit"] = "us"
        g = f.create_group("events")
        for k in "txyp":
            g.create_dataset(k, data=getattr(events, k), compression="gzip")


def contents(path):
    """Everything a reader can see in an events file but the chunk layout."""
    with h5py.File(path) as f:
        def describe(name, obj):
            if isinstance(obj, h5py.Dataset):
                seen[name] = (obj.dtype.str, obj.shape, obj.compression, obj.compression_opts, obj[()].tobytes())
            else:
                seen[name] = ("group", sorted(obj.attrs.items()))
        seen = {"/": sorted((k, np.asarray(v).tolist()) for k, v in f.attrs.items())}
        f.visititems(describe)
    return seen


def test_convert_to_h5_holds_what_the_whole_array_writer_held(tmp_path):
    """The shipped turntable (254 k events: four HDF5 chunks of 65,536 rows) converted by the command."""
    out = tmp_path / "t.h5"
    assert main(["convert", str(SHIPPED), str(out), "--quiet"]) == 0
    events = evstream.read(SHIPPED)
    assert len(events) > 3 * hdf5.CHUNK_ROWS
    whole_array_file(tmp_path / "before.h5", events)
    assert contents(out) == contents(tmp_path / "before.h5")
    with h5py.File(out) as f:
        assert f["events/t"].chunks == (hdf5.CHUNK_ROWS,) and f["events/t"].id.get_num_chunks() == 4
    back = evstream.read(out)
    for k in "txyp":
        assert np.array_equal(getattr(back, k), getattr(events, k))


@pytest.mark.parametrize("seed", range(3))
def test_writer_appends_uneven_chunks_across_hdf5_chunks(tmp_path, seed):
    """Chunks of any size (empty ones too) across small HDF5 chunks: the file is their concatenation."""
    rng = np.random.default_rng(seed)
    g = Geometry(64, 48)
    chunks, t0 = [], 0
    for _ in range(int(rng.integers(1, 12))):
        n = int(rng.choice([0, 1, int(rng.integers(2, 3000))]))
        t = t0 + np.sort(rng.integers(0, 10_000, n))
        t0 = int(t[-1]) if n else t0
        x, y, p = rng.integers(0, 64, n), rng.integers(0, 48, n), rng.integers(0, 2, n)
        chunks.append(EventChunk.from_arrays(t, x, y, p, g))
    path = tmp_path / "w.h5"
    with hdf5.Writer(path, chunk_rows=int(rng.integers(1, 700))) as writer:
        for c in chunks:
            writer.append(c)
    whole = concat(chunks, g)
    assert writer.events == len(whole)
    whole_array_file(tmp_path / "before.h5", whole)
    assert contents(path) == contents(tmp_path / "before.h5")


def test_writer_without_events_or_geometry_is_an_error(tmp_path):
    path = tmp_path / "e.h5"
    with pytest.raises(ValueError, match="no events and no geometry"):
        with hdf5.Writer(path):
            pass
    with hdf5.Writer(path, Geometry(8, 6)):
        pass
    assert evstream.info(path)["events"] == 0 and contents(path)["/"] == [("height", 6), ("t_unit", "us"),
                                                                         ("width", 8)]


def test_writing_h5_takes_memory_of_a_few_chunks_not_of_the_recording(tmp_path):
    """2 M events (26 MB of columns, ~8 MB as gzip HDF5) appended 100 k at a time: the peak of what Python
    and numpy allocate stays under 6 MB. The writer that built the file in memory held all of it."""
    events = evstream.read(SHIPPED)[:100_000]
    span = int(events.t[-1]) + 1
    path = tmp_path / "big.h5"
    tracemalloc.start()
    try:
        with hdf5.Writer(path, events.geometry) as writer:
            for k in range(20):
                writer.append(EventChunk.from_arrays(events.t + k * span, events.x, events.y, events.p,
                                                     events.geometry))
                if k == 0:
                    tracemalloc.reset_peak()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert writer.events == 2_000_000 and path.stat().st_size > 6e6
    assert peak < 6e6, f"peak {peak / 1e6:.1f} MB"


def test_a_failing_disk_is_a_python_oserror_not_a_crash_in_the_hdf5_library():
    """Every write to /dev/full fails (no space left): the HDF5 library must never see it (h5py 3.16 died
    by segfault when its own writes failed), and the writer raises it as an OSError. In a child process:
    a crash there fails this test instead of the run."""
    import subprocess
    import sys

    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    code = f"""
import errno
import evstream
from evstream.sources import hdf5
events = evstream.read({str(SHIPPED)!r})
try:
    with hdf5.Writer("/dev/full", events.geometry) as writer:
        writer.append(events)
except OSError as e:
    print("OSError", e.errno == errno.ENOSPC)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["OSError", "True"]
