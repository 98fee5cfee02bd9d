"""Threaded runs (evstream.threads, `Pipeline.run(threads=True)`): the same items in the same order as a
serial run, the same output bytes, bounded queues, and errors raised where the caller next looks."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from evstream.sinks.mcap_sink import McapSink
from evstream.sources import native, open_source
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from evstream.events import EventChunk, EventError, Geometry
from evstream.pipeline import Pipeline, build
from evstream.testing import random_stream
from evstream.threads import ReadAhead, WriteBehind
from evstream.threads import enabled as threads_enabled
from evstream.writers import FileSink

G = Geometry(64, 48)
EVSTREAM = str(Path(sys.executable).parent / "evstream")


class Counted:
    """An iterable of 0..n-1 that records how far ahead of its consumer it has been."""

    def __init__(self, n: int, fail_at: int | None = None):
        self.n, self.fail_at = n, fail_at
        self.made = 0
        self.closed = False

    def __iter__(self):
        try:
            for i in range(self.n):
                if i == self.fail_at:
                    raise EventError(f"item {i}: broken")
                self.made += 1
                yield i
        finally:
            self.closed = True


@settings(max_examples=30, deadline=None)
@given(n=st.integers(0, 60), depth=st.integers(1, 5))
def test_read_ahead_yields_every_item_in_order_and_stays_bounded(n, depth):
    src = Counted(n)
    ahead = []
    got = []
    for item in ReadAhead(src, depth=depth):
        ahead.append(src.made - len(got))  # made but not yet handed on
        got.append(item)
    assert got == list(range(n))
    # the consumer's item, `depth` queued, one the reader holds while the queue is full
    assert max(ahead, default=0) <= depth + 2
    assert src.closed


def test_read_ahead_raises_the_source_error_after_the_items_before_it():
    got = []
    with pytest.raises(EventError, match="item 7: broken"):
        for item in ReadAhead(Counted(20, fail_at=7), depth=3):
            got.append(item)
    assert got == list(range(7))


def test_read_ahead_closed_early_stops_its_source():
    src = Counted(10_000)
    reader = ReadAhead(src, depth=2)
    for item in reader:
        if item == 5:
            break
    reader.close()
    assert src.closed and src.made <= 5 + 4


@settings(max_examples=30, deadline=None)
@given(n=st.integers(0, 60), depth=st.integers(1, 5))
def test_write_behind_writes_every_item_in_order_and_stays_bounded(n, depth):
    written = []
    waiting = []
    lock = threading.Lock()
    put = [0]

    def write(item):
        with lock:
            waiting.append(put[0] - len(written))
        written.append(item)

    w = WriteBehind(write, depth=depth)
    for i in range(n):
        w.put(i)
        put[0] += 1
    w.close()
    assert written == list(range(n))
    assert max(waiting, default=0) <= depth + 2


def test_write_behind_error_is_raised_by_a_later_put_or_close_and_drops_the_rest():
    written = []

    def write(item):
        if item == 3:
            raise OSError("disk said no")
        written.append(item)

    w = WriteBehind(write, depth=2)
    with pytest.raises(OSError, match="disk said no"):
        for i in range(1000):
            w.put(i)
        w.close()
    w.close(check=False)
    assert written == [0, 1, 2]
    assert isinstance(w.error, OSError)
    w.close()  # said once: cleaning up after it (closing the sinks) is not stopped by it again
    w2 = WriteBehind(write, depth=1)
    for i in range(4):  # item 3 fails after the last put: only close can say so
        w2.put(i)
    with pytest.raises(OSError, match="disk said no"):
        w2.close()


def _rechunk(chunk: EventChunk, cuts) -> list[EventChunk]:
    bounds = [0, *sorted(set(cuts)), len(chunk)]
    return [chunk[a:b] for a, b in zip(bounds[:-1], bounds[1:]) if b >= a]


def _messages(path) -> tuple:
    with open(path, "rb") as f:
        reader = make_reader(f)
        msgs = [(ch.topic, m.log_time, m.sequence, m.data) for _, ch, m in reader.iter_messages(log_time_order=False)]
        meta = [(md.name, {k: v for k, v in md.metadata.items()
                           if k not in ("created_utc", "run_wall_s", "run_throughput_hz")})
                for md in reader.iter_metadata()]
    return msgs, meta


def _archive(chunks, out, threads: bool) -> None:
    pipe = Pipeline([build("stage", {"kind": "paper"})], build("framer", {"kind": "fw", "window_us": 20_000}))
    sink = McapSink(out, keep_noise=True, frames=True, points=True, flush_s=1e9, chunk_bytes=64 << 10,
                    geometry=G)
    pipe.run(iter(chunks), [sink], threads=threads)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), cuts=st.lists(st.integers(0, 30_000), max_size=12))
def test_threaded_archive_writes_the_serial_archive(tmp_path_factory, seed, cuts):
    """Same messages (every byte of every packet, frame and point cloud), same chunking of the file, same
    metadata but the run's wall time; file sizes equal up to the digits of that time."""
    folder = tmp_path_factory.mktemp("mcap")
    chunks = _rechunk(random_stream(seed, 30_000, G, mean_dt_us=20.0), cuts)
    _archive(chunks, folder / "serial.mcap", threads=False)
    _archive(chunks, folder / "threaded.mcap", threads=True)
    assert _messages(folder / "serial.mcap") == _messages(folder / "threaded.mcap")
    with open(folder / "serial.mcap", "rb") as a, open(folder / "threaded.mcap", "rb") as b:
        ra, rb = make_reader(a).get_summary(), make_reader(b).get_summary()
    assert [(c.message_start_time, c.compressed_size) for c in ra.chunk_indexes] == [
        (c.message_start_time, c.compressed_size) for c in rb.chunk_indexes]


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), cuts=st.lists(st.integers(0, 20_000), max_size=12),
       suffix=st.sampled_from([".raw", ".npz"]))
def test_threaded_run_into_a_file_sink_writes_the_same_bytes(tmp_path_factory, seed, cuts, suffix):
    folder = tmp_path_factory.mktemp("files")
    chunks = _rechunk(random_stream(seed, 20_000, G, mean_dt_us=20.0), cuts)
    for threads in (False, True):
        pipe = Pipeline([build("stage", {"kind": "stcf"})])
        sink = FileSink(folder / f"{threads}{suffix}", geometry=G, keep_noise=True)
        pipe.run(iter(chunks), [sink], threads=threads)
    assert (folder / f"False{suffix}").read_bytes() == (folder / f"True{suffix}").read_bytes()


class BadClasses:
    """A stage that writes an impossible noise class from its `at`-th chunk: the sink's error, raised on
    the writer thread."""

    def __init__(self, at: int):
        self.at, self.seen = at, 0

    def __call__(self, chunk):
        self.seen += 1
        cls = np.full(len(chunk), 9 if self.seen > self.at else 0, np.uint8)
        return chunk.replace(cls=cls)


@pytest.mark.parametrize("threads", [False, True])
def test_a_sink_error_on_the_writer_thread_fails_the_run_as_serially(tmp_path, threads):
    out = tmp_path / "a.mcap"
    out.write_bytes(b"an older archive")
    chunks = _rechunk(random_stream(1, 20_000, G, mean_dt_us=20.0), range(1000, 20_000, 1000))
    with pytest.raises(EventError, match="noise class 9"):
        Pipeline([BadClasses(at=5)]).run(iter(chunks), [McapSink(out, geometry=G)], threads=threads)
    assert out.read_bytes() == b"an older archive"  # the target as it was; the partial file beside it
    parts = list(tmp_path.glob("a.mcap*.part"))
    assert len(parts) == 1
    with open(parts[0], "rb") as f:
        assert make_reader(f).get_summary() is not None  # closed whole up to the failure


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "rec.npz"
    native.save(path, random_stream(3, 200_000, Geometry(346, 260), mean_dt_us=5.0), compress=False)
    return path


@pytest.mark.parametrize("threads", ["0", "1"])
def test_a_damaged_recording_is_one_line_and_exit_1_threaded_or_not(recording, tmp_path, threads):
    """The reader thread's error: one line naming the file, exit 1, no archive left, the same as serially."""
    cut = tmp_path / "cut.npz"
    data = bytearray(recording.read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = b"\xff" * 64  # a member's bytes no longer match its CRC
    cut.write_bytes(bytes(data))
    out = tmp_path / "a.mcap"
    env = {**os.environ, "EVSTREAM_THREADS": threads}
    proc = subprocess.run([EVSTREAM, "archive", str(cut), str(out), "--denoise", "paper", "-q"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("evstream: error: ") and str(cut) in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()


def test_open_source_read_ahead_matches(recording):
    serial = list(open_source(recording))
    ahead = list(ReadAhead(open_source(recording)))
    assert len(serial) == len(ahead)
    for a, b in zip(serial, ahead):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.x, b.x)


def _rrd_content(path) -> dict:
    """Entity -> every logged row (time, component values), sorted; the 3D view's points as one sorted list
    of points per class. Rerun batches rows by wall-clock time, and the sink sends its points on a
    wall-clock cadence (how they group into rows, and the slab's rows, differ between two serial runs)."""
    from rerun.chunk import RrdReader

    rows: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.is_static or chunk.entity_path == "/events":  # the slab transform: a row per send
            continue
        rb = chunk.to_record_batch()
        names = sorted(n for n in rb.schema.names if ":" in n and not n.startswith("rerun."))
        columns = [rb.column(rb.schema.names.index(n)).to_pylist() for n in names]
        if chunk.entity_path.startswith("/events/"):  # points: each one, whatever row it came in
            at = names.index("Points3D:positions")
            rows.setdefault(chunk.entity_path, []).extend(repr(p) for row in columns[at] for p in row)
            continue
        times = rb.column(rb.schema.names.index("event_time")).cast("int64").to_pylist()
        rows.setdefault(chunk.entity_path, []).extend(repr(v) for v in zip(times, *columns))
    return {entity: sorted(v) for entity, v in rows.items()}


def test_threaded_replay_logs_what_the_serial_replay_logs(tmp_path):
    from evstream.sinks.rerun_sink import RerunSink
    from evstream.sinks.rerun_viewer import open_output

    chunks = _rechunk(random_stream(5, 30_000, G, mean_dt_us=20.0), range(700, 30_000, 2100))
    for threads in (False, True):
        out = open_output(save=str(tmp_path / f"{threads}.rrd"))
        pipe = Pipeline([build("stage", {"kind": "paper"})], build("framer", {"kind": "fw", "window_us": 20_000}))
        pipe.run(iter(chunks), [RerunSink(out.rec, geometry=G, framer="fw")], threads=threads)
        out.finish()
    serial, threaded = _rrd_content(tmp_path / "False.rrd"), _rrd_content(tmp_path / "True.rrd")
    assert len(serial["/events/signal"]) > 1000 and len(serial["/frames/fw"]) > 10
    assert serial == threaded


@pytest.mark.parametrize("value, default, expected", [
    (None, True, True), (None, False, False), ("", False, False),
    ("1", False, True), ("yes", False, True), ("0", True, False), ("off", True, False), ("false", True, False),
])
def test_each_command_keeps_its_measured_default_unless_evstream_threads_says(monkeypatch, value, default, expected):
    """archive defaults to threads, replay and convert to serial (docs/archive.md says why); the variable
    overrides either way."""
    if value is None:
        monkeypatch.delenv("EVSTREAM_THREADS", raising=False)
    else:
        monkeypatch.setenv("EVSTREAM_THREADS", value)
    assert threads_enabled(default) is expected
