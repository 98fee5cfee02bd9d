"""sources/_base.py in-process, against plain-Python references: how `FileSource` re-chunks any split of
decoded blocks (by count and by time, with their watermarks), the byte an error names whatever the
chunk straddles, the column readers' blocks and seek, the column-order guess, headers, records, info."""

import io
import os
import re
import warnings

import numpy as np
import pytest
from evstream.sources._base import (
    Block,
    EventWarning,
    FileSource,
    as_geometry,
    check_fits,
    check_not_shrunk,
    fit_geometry,
    guess_columns,
    iter_records,
    read_header_lines,
)
from hypothesis import given
from hypothesis import strategies as st

from evstream.events import EventChunk, EventError, Geometry

G = Geometry(64, 32)
RB = 5  # bytes per record of the "records" layout


class Blocks(FileSource):
    """A reader whose decoder output is given: the blocks, as a reader's `_blocks` would yield them."""

    format = "blocks"

    def __init__(self, path, blocks, geometry_from="test", **options):
        super().__init__(path, **options)
        self.blocks = blocks
        self.set_geometry(G, geometry_from)

    def _blocks(self):
        yield from self.blocks


@st.composite
def layouts(draw, min_events=1):
    """Sorted times split into blocks of one kind: 'records' (fixed-size records; a gap in the bytes
    between some blocks), 'ranges' (a byte range per block) or 'none' (a reader that cannot tell)."""
    sizes = draw(st.lists(st.integers(0, 9), min_size=1, max_size=6))
    if sum(sizes) < min_events:
        sizes.append(min_events)
    n = sum(sizes)
    t = np.cumsum(draw(st.lists(st.integers(0, 25), min_size=n, max_size=n))).astype(np.int64) + draw(
        st.integers(0, 10**12))
    kind = draw(st.sampled_from(["records", "ranges", "none"]))
    blocks, byte_of, pos, i = [], [], draw(st.integers(0, 40)), 0
    for k in sizes:
        pos += draw(st.sampled_from([0, 0, 3])) if kind == "records" else 0
        x = np.arange(i, i + k, dtype=np.uint16) % G.width
        args = (t[i:i + k], x, (x % G.height).astype(np.uint16), (x % 2).astype(np.uint8))
        if kind == "records":
            blocks.append(Block(*args, pos, pos + k * RB, RB))
            byte_of += [(pos + j * RB, pos + j * RB + RB) for j in range(k)]
            pos += k * RB
        elif kind == "ranges":
            end = pos + 7 * k + 1
            blocks.append(Block(*args, pos, end))
            byte_of += [(pos, end)] * k
            pos = end
        else:
            blocks.append(Block(*args))
            byte_of += [(0, 0)] * k
        i += k
    return t, blocks, kind, byte_of, pos


def source(tmp_path, blocks, size, **options):
    path = tmp_path / "rec.bin"
    path.write_bytes(b"\0" * size)
    return Blocks(path, blocks, **options)


def check_chunks(chunks, t, cuts, strict):
    """Chunks hold t cut at `cuts`, each chunk's watermark the next event's time under the 'error'
    policy (the default) and its own last event's otherwise."""
    assert [c.t.tolist() for c in chunks] == [t[a:b].tolist() for a, b in zip(cuts, cuts[1:])]
    for k, c in enumerate(chunks):
        later = cuts[k + 1] < len(t)
        assert c.t_end == (int(t[cuts[k + 1]]) if strict and later else int(c.t[-1]))
        assert c.x.tolist() == (np.arange(cuts[k], cuts[k + 1]) % G.width).tolist()  # the events, not only t
        assert c.geometry == G


@given(layouts(min_events=0), st.integers(1, 12), st.sampled_from(["error", "sort"]), st.integers(-20, 30))
def test_chunks_by_count_cut_any_split_of_blocks_the_same(tmp_path_factory, layout, chunk_events, policy, more):
    t, blocks, kind, _, end = layout
    size = max(1, end + more)
    src = source(tmp_path_factory.mktemp("b"), blocks, size, chunk_events=chunk_events, timestamps=policy)
    chunks = list(src)
    check_chunks(chunks, t, sorted({*range(0, len(t), chunk_events), len(t)}), policy == "error")
    last = [b.byte_end for b in blocks if len(b) and b.byte_end]
    assert src.fraction_read == (min(1.0, last[-1] / size) if last else None)
    assert (src.dropped, src.reordered) == (0, 0)


@given(layouts(), st.integers(1, 60), st.sampled_from(["error", "drop"]))
def test_chunks_by_time_are_the_bins_from_the_first_event(tmp_path_factory, layout, chunk_us, policy):
    t, blocks, *_ = layout
    src = source(tmp_path_factory.mktemp("b"), blocks, 10, chunk_us=chunk_us, timestamps=policy)
    chunks = list(src)
    bins = (t - t[0]) // chunk_us
    cuts = [0, *(np.flatnonzero(np.diff(bins)) + 1).tolist(), len(t)]
    check_chunks(chunks, t, cuts, policy == "error")


@given(layouts(), st.integers(1, 60), st.integers(1, 6), st.integers(1, 3))
def test_chunks_by_time_are_cut_at_the_most_events_a_chunk_may_hold(tmp_path_factory, layout, chunk_us, most, count):
    """A bin of more than MAX_CHUNK_EVENTS events (4 million; here a few) is cut into pieces of that
    many, the later pieces still in the same bin."""
    from evstream.sources import _base

    t, blocks, *_ = layout
    src = source(tmp_path_factory.mktemp("b"), blocks, 10, chunk_us=chunk_us, chunk_events=count)  # (count unused)
    saved, _base.MAX_CHUNK_EVENTS = _base.MAX_CHUNK_EVENTS, most
    try:
        chunks = list(src)
    finally:
        _base.MAX_CHUNK_EVENTS = saved
    bins = (t - t[0]) // chunk_us
    starts = [0, *(np.flatnonzero(np.diff(bins)) + 1).tolist(), len(t)]
    cuts = sorted({c for a, b in zip(starts, starts[1:]) for c in range(a, b, most)} | {len(t)})
    check_chunks(chunks, t, cuts, True)


def test_chunks_by_count_may_hold_more_than_a_time_chunk(tmp_path, monkeypatch):
    """MAX_CHUNK_EVENTS bounds chunks by time only: the chunk_events a user asks for are given whole,
    the last chunk too; and a 1-byte file read whole is read whole."""
    from evstream.sources import _base

    monkeypatch.setattr(_base, "MAX_CHUNK_EVENTS", 2)
    t = np.arange(8, dtype=np.int64)
    z = np.zeros(8, np.uint16)
    src = source(tmp_path, [Block(t, z, z, z.astype(np.uint8), 0, 1)], 1, chunk_events=5)
    assert [c.t.tolist() for c in src] == [[0, 1, 2, 3, 4], [5, 6, 7]] and src.fraction_read == 1.0


@given(st.lists(st.lists(st.integers(0, 30), min_size=1, max_size=5), max_size=5), st.integers(0, 35),
       st.integers(1, 12))
def test_queue_time_cut_matches_its_reference(parts, boundary, most):
    """The first index >= 1 at or past the boundary (at most `most`), else `most` when more than that
    many wait (a cut needs the event after it), else -1. (The queue never holds an empty block.)"""
    from evstream.sources._base import _Queue

    q = _Queue()
    for part in parts:
        z = np.zeros(len(part), np.uint16)
        q.push(Block(np.array(sorted(part), np.int64), z, z, z.astype(np.uint8)))
    t = [v for part in parts for v in sorted(part)]
    g = next((i for i in range(1, len(t)) if t[i] >= boundary), None)
    assert q.n == len(t)
    assert q.time_cut(boundary, most) == (min(g, most) if g is not None else most if len(t) > most else -1)
    for i, v in enumerate(t):
        assert q.t_at(i) == v
    with pytest.raises(IndexError):
        q.t_at(len(t))


def test_chunks_by_time_skip_empty_bins_and_keep_the_anchor():
    """Bins are anchored at the first event: 10 µs bins from t = 3 are [3, 13), [13, 23), ...; an
    event at exactly a bin's start opens it, empty bins make no chunk."""
    from evstream.sources._base import _next_bin

    assert _next_bin(3, 13, 10) == 13 and _next_bin(3, 12, 10) == 3 and _next_bin(3, 57, 10) == 53
    assert _next_bin(3, 1, 10) == 1  # a time before the bin (cut by count, sorted later): a bin of its own
    assert _next_bin(3, 52, 10) == 43 and _next_bin(3, 53, 10) == 53


@given(layouts(min_events=2), st.data())
def test_a_timestamp_going_back_names_its_byte_whatever_the_chunk_straddles(tmp_path_factory, layout, data):
    """Under the 'error' policy: the event's own byte when its chunk's records are back to back, else the
    chunk's byte range, else (a reader that cannot tell bytes) no byte at all."""
    t, blocks, kind, byte_of, end = layout
    bad = data.draw(st.integers(1, len(t) - 1))
    chunk_events = data.draw(st.integers(1, 8))
    t_bad = int(t[bad - 1]) - 1
    for b, first in zip(blocks, np.cumsum([0] + [len(b) for b in blocks])):
        if first <= bad < first + len(b):
            b.t = b.t.copy()
            b.t[bad - first] = t_bad
    src = source(tmp_path_factory.mktemp("b"), blocks, end + 1, chunk_events=chunk_events)
    a = bad // chunk_events * chunk_events
    b = min(a + chunk_events, len(t))
    spans = byte_of[a:b]
    back_to_back = all(p[1] == q[0] for p, q in zip(spans, spans[1:]))
    what = (f"event {bad}: timestamp {t_bad} µs goes back from {t[bad - 1]} µs (to accept such streams: --timestamps "
            "sort|drop, timestamps=\"sort\" in Python)")
    if kind == "records" and back_to_back:
        want = f"{src.path} at byte {byte_of[bad][0]}: {what}"
    elif kind == "none":
        want = f"{src.path}: {what}"
    else:
        want = f"{src.path}: {what} [in bytes {spans[0][0]}..{spans[-1][1]}]"
    with pytest.raises(EventError, match="^" + re.escape(want) + "$"):
        list(src)


def test_the_byte_named_when_a_chunk_straddles_blocks(tmp_path):
    """Blocks of 3 events, chunks of 4: each chunk takes events from two blocks (the property test above
    meets such splits only now and then). Event `bad` goes back in time, or has polarity 2 (the
    validator's error then names no event index)."""
    def blocks(spans, record_bytes, bad, polarity, sizes=(3, 3, 3)):
        out, first = [], 0
        for (start, end), rb, n in zip(spans, record_bytes, sizes):
            t = np.arange(first, first + n, dtype=np.int64) * 10
            z = np.zeros(n, np.uint16)
            p = np.zeros(n, np.uint8)
            if first <= bad < first + n:
                (p if polarity else t)[bad - first] = 2 if polarity else 0
            out.append(Block(t, z, z, p, start, end, rb))
            first += n
        return out

    path = tmp_path / "rec.bin"
    path.write_bytes(b"\0" * 100)
    back = ("timestamp 0 µs goes back from {} µs (to accept such streams: --timestamps sort|drop, "
            "timestamps=\"sort\" in Python)")
    for spans, rb, bad, polarity, want, *sizes in (
        ([(10, 25), (25, 40), (40, 55)], [5, 5, 5], 5, False, f"{path} at byte 35: event 5: {back.format(40)}"),
        ([(10, 25), (25, 40), (43, 58)], [5, 5, 5], 5, False, f"{path}: event 5: {back.format(40)} [in bytes 30..53]"),
        ([(10, 25), (25, 37), (37, 49)], [5, 4, 4], 2, False, f"{path}: event 2: {back.format(10)} [in bytes 10..29]"),
        ([(10, 30), (30, 50), (50, 70)], [0, 0, 0], 5, False, f"{path}: event 5: {back.format(40)} [in bytes 30..70]"),
        ([(10, 25), (25, 40), (40, 55)], [5, 5, 5], 5, True,
         f"{path}: event 5: polarity 2 is not 0 or 1 [in bytes 30..50]"),
        # a chunk from three blocks; a chunk that begins a block after one ended a chunk exactly
        ([(10, 30), (30, 35), (35, 60)], [0, 0, 0], 3, False, f"{path}: event 3: {back.format(20)} [in bytes 10..60]",
         (2, 1, 2)),
        ([(10, 30), (30, 50)], [0, 0], 5, False, f"{path}: event 5: {back.format(40)} [in bytes 30..50]", (4, 4)),
    ):
        with pytest.raises(EventError, match="^" + re.escape(want) + "$"):
            list(Blocks(path, blocks(spans, rb, bad, polarity, *sizes), chunk_events=4))


@given(layouts(min_events=1), st.data(), st.booleans())
def test_an_event_outside_the_sensor_names_its_byte_and_index(tmp_path_factory, layout, data, override):
    t, blocks, kind, byte_of, end = layout
    bad = data.draw(st.integers(0, len(t) - 1))
    column = data.draw(st.sampled_from("xy"))
    located = kind == "none" and data.draw(st.booleans())
    for b, first in zip(blocks, np.cumsum([0] + [len(b) for b in blocks])):
        if first <= bad < first + len(b):
            a = getattr(b, column).copy()
            a[bad - first] = G.width if column == "x" else G.height  # the first value outside
            setattr(b, column, a)
            x, y = int(b.x[bad - first]), int(b.y[bad - first])
        if located:
            b.locate = lambda i, first=first: 1000 + 3 * (first + i)
    options = {"geometry": G} if override else {}
    src = source(tmp_path_factory.mktemp("b"), blocks, end + 1, chunk_events=data.draw(st.integers(1, 8)),
                 **options)
    where = {"records": f" at byte {byte_of[bad][0]}", "ranges": f" in bytes {byte_of[bad][0]}..{byte_of[bad][1]}",
             "none": f" at byte {1000 + 3 * bad}" if located else ""}[kind]
    hint = "" if override else " (if the file's is wrong: --geometry WxH, geometry=(W, H) in Python)"
    origin = "option" if override else "test"
    want = f"{src.path}{where}: event {bad}: ({x}, {y}) outside the 64x32 sensor (size from {origin}){hint}"
    with pytest.raises(EventError, match="^" + re.escape(want) + "$"):
        list(src)


def test_an_event_outside_the_sensor_from_a_reader_that_cannot_tell_bytes(tmp_path):
    z = np.zeros(3, np.uint16)
    src = source(tmp_path, [Block(np.arange(3), z, np.array([0, 0, 40], np.uint16), z.astype(np.uint8))], 9)
    want = f"{src.path}: event 2: (0, 40) outside the 64x32 sensor (size from test) (if the file's is wrong: --geometry"
    with pytest.raises(EventError, match="^" + re.escape(want)):
        list(src)


def test_dropped_events_are_counted_and_warned_about_where_the_stream_is_read(tmp_path):
    t = np.array([5, 6, 4, 7, 3, 8], np.int64)
    z = np.zeros(6, np.uint16)
    src = source(tmp_path, [Block(t, z, z, z.astype(np.uint8), 0, 30, 5)], 30, timestamps="drop")
    src.counters["words"] = 3
    src.details["evt"] = "3.0"
    with pytest.warns(EventWarning, match=rf"^{re.escape(src.path)}: 2 events dropped: their timestamps go back "
                                          r"\(timestamp policy 'drop'\)$") as caught:
        chunks = list(src)
    if "MUTANT_UNDER_TEST" not in os.environ:  # (under mutmut, its trampoline is one frame more)
        assert caught[0].filename == __file__  # stacklevel: the line that read the stream, not the library
    assert [c.t.tolist() for c in chunks] == [[5, 6, 7, 8]]
    info = src.info()
    src.counters["words"] = 4
    assert info == {"format": "blocks", "path": src.path, "bytes": 30, "width": 64, "height": 32,
                    "geometry_from": "test", "timestamps": "drop", "dropped": 2, "reordered": 0,
                    "counters": {"words": 3}, "evt": "3.0"}
    src = source(tmp_path, [Block(t, z, z, z.astype(np.uint8))], 30, timestamps="sort", geometry="64x32")
    list(src)
    info = src.info()
    assert (src.dropped, src.reordered, info["geometry_from"], info["timestamps"]) == (0, 5, "option", "sort")


def test_options_are_checked_and_defaulted(tmp_path):
    (tmp_path / "f").write_bytes(b"abc")
    src = FileSource(tmp_path / "f")
    assert (src.chunk_events, src.chunk_us, src.block_bytes, src.timestamps, src.geometry, src.geometry_source,
            src.file_size, src.fraction_read, src.first_row) == (50_000, None, 1 << 20, "error", None, None, 3, None, 0)
    src = FileSource(tmp_path / "f", chunk_events=1, chunk_us=1, block_bytes=1023, timestamps="drop", geometry=(3, 2))
    assert (src.chunk_events, src.chunk_us, src.block_bytes, src.timestamps) == (1, 1, 1024, "drop")
    assert (src.geometry, src.geometry_source) == (Geometry(3, 2), "option")
    assert FileSource(tmp_path / "f", block_bytes=5000).block_bytes == 5000
    assert (src.dropped, src.reordered) == (0, 0)
    for bad in ({"chunk_events": 0}, {"chunk_us": 0}, {"chunk_events": -1}):
        with pytest.raises(ValueError, match="^chunk_events and chunk_us must be positive$"):
            FileSource(tmp_path / "f", **bad)
    with pytest.raises(EventError, match=rf"^{re.escape(src.path)}: no sensor size known; give it: --geometry WxH"):
        list(FileSource(tmp_path / "f"))
    src.set_geometry(Geometry(9, 9), "header")  # the user's size wins
    assert (src.geometry, src.geometry_source) == (Geometry(3, 2), "option")
    src = FileSource(tmp_path / "f")
    src.set_geometry(None, "header")
    assert (src.geometry, src.geometry_source) == (None, None)
    src.set_geometry(Geometry(2048, 1), "header")
    assert (src.geometry, src.geometry_source) == (Geometry(2048, 1), "header")
    for g in (Geometry(2049, 1), Geometry(1, 2049)):
        with pytest.raises(EventError, match=rf"^{re.escape(src.path)}: the file claims a {g} sensor \(header\), "
                                             r"larger than any event camera \(2048 a side\); if it is real: --"):
            src.set_geometry(g, "header")
    assert src.error("why", 0).args[0] == f"{src.path} at byte 0: why"
    assert src.error("why").args[0] == f"{src.path}: why"


def test_geometry_helpers():
    assert as_geometry(None) is None and as_geometry("640X480") == Geometry(640, 480) == as_geometry((640.0, 480))
    with pytest.raises(ValueError, match=r"^geometry '64x': expected WIDTHxHEIGHT, e\.g\. 640x480$"):
        as_geometry("64x")
    assert fit_geometry(33, 33) == Geometry(34, 34) and fit_geometry(34, 0) == Geometry(128, 128)
    assert fit_geometry(1279, 719) == Geometry(1280, 720)
    assert fit_geometry(1280, 0) == Geometry(1281, 1) and fit_geometry(0, 720) == Geometry(1, 721)
    assert fit_geometry(5000, 9000) == Geometry(2048, 2048)
    assert fit_geometry(0, 0, []) == Geometry(1, 1) and fit_geometry(-5, -5, []) == Geometry(1, 1)
    assert fit_geometry(4, 2, [Geometry(4, 9), Geometry(5, 3), Geometry(8, 8)]) == Geometry(5, 3)


class Columns(FileSource):
    format = "columns"

    def __init__(self, path, cols, time_unit, rows=None, **options):
        super().__init__(path, geometry=G, **options)
        self.cols, self.time_unit, self.rows = cols, time_unit, rows

    def _blocks(self):
        return self._column_blocks(self.cols, len(self.cols["t"]), self.time_unit, self.rows)


@given(st.integers(0, 300), st.sampled_from([1024, 1500, 4000]), st.integers(0, 300), st.booleans())
def test_column_blocks_cover_the_rows_from_the_seek_with_their_bytes(tmp_path_factory, n, block_bytes, start, rows):
    path = tmp_path_factory.mktemp("c") / "c.npy"
    path.write_bytes(b"\0" * 10)
    t = np.arange(n, dtype=np.int64) * 2
    cols = {"t": t, "x": t % 64, "y": t % 32, "p": t % 3 == 0}
    src = Columns(path, cols, "ms", (128, 16) if rows else None, block_bytes=block_bytes)
    assert src.seek_rows(t, "us", start) == (n > 0)
    first = src.first_row
    assert first == min(n, (start + 1) // 2)
    step, seen = block_bytes // 16, []
    for a, b in zip(range(first, n, step), src._blocks()):
        end = min(a + step, n)
        assert b.t.tolist() == (t[a:end] * 1000).tolist() and b.x.tolist() == (t[a:end] % 64).tolist()
        assert b.p.tolist() == (t[a:end] % 3 == 0).tolist()
        assert (b.byte_start, b.byte_end, b.record_bytes) == ((128 + 16 * a, 128 + 16 * end, 16) if rows else (0, 0, 0))
        assert src.fraction_read == end / n
        seen.append(len(b))
    assert sum(seen) == n - first


def test_column_blocks_name_a_bad_value_by_its_row_byte(tmp_path):
    (tmp_path / "c.npy").write_bytes(b"")
    t = np.arange(100, dtype=np.int64)
    x = t % 64
    x[70] = -1
    src = Columns(tmp_path / "c.npy", {"t": t, "x": x, "y": t % 32, "p": t % 2}, "us", (128, 16), block_bytes=1024)
    with pytest.raises(EventError, match=rf"^{re.escape(src.path)} at byte 1152: event 6 of a block has x = "):
        list(src)  # (the second block of 64 rows begins at byte 128 + 64 * 16)


def reference_seek(t, scale, start_us):
    us = [round(v * scale) if scale != 1 or isinstance(v, float) else v for v in t.tolist()]
    return next((i for i, v in enumerate(us) if v >= start_us), len(us))


@given(st.lists(st.integers(0, 50), max_size=20), st.sampled_from(["us", "ms", "s", "float"]), st.integers(-5, 2000))
def test_seek_rows_finds_the_first_row_a_time_range_keeps(tmp_path_factory, steps, unit, start_us):
    path = tmp_path_factory.mktemp("s") / "c.npy"
    path.write_bytes(b"")
    t = np.cumsum(np.array(steps, np.int64))
    src = Columns(path, {}, "us")
    if unit == "float":
        t, unit = t + 0.6, "us"  # rounded to the nearest µs, as to_events does
        scale = 1
    else:
        t = t * {"us": 1, "ms": 1, "s": 1}[unit]
        scale = {"us": 1, "ms": 1000, "s": 10**6}[unit]
        start_us = start_us * {"us": 1, "ms": 30, "s": 30_000}[unit]
    src.first_row = 7
    assert src.seek_rows(t, unit, None) is False and src.first_row == 0
    want = reference_seek(t, scale, start_us)
    assert src.seek_rows(t, unit, start_us) is (len(t) > 0)
    assert src.first_row == (want if len(t) else 0)


def test_seek_rows_reads_from_the_start_when_an_earlier_row_is_in_range(tmp_path):
    """Under 'sort'/'drop' a row before the bisection point with a time in range would be lost: the
    seek gives up (False, first row 0); under 'error' it skips them (reading would refuse the file)."""
    (tmp_path / "c.npy").write_bytes(b"")
    t = np.array([0, 10, 25, 5, 20, 30, 40], np.int64)  # the bisection lands on row 4; 25 is skipped
    for policy, ok, first in (("error", True, 4), ("sort", False, 0), ("drop", False, 0)):
        src = Columns(tmp_path / "c.npy", {}, "us", timestamps=policy)
        assert (src.seek_rows(t, "us", 20), src.first_row) == (ok, first)
    assert (src.seek_rows(t, "us", 41), src.first_row) == (True, 7)  # all before the start: none left
    assert (src.seek_rows(t, "us", 40), src.first_row) == (True, 6)
    t = np.array([0, 10, 5, 20, 30], np.int64)
    assert (src.seek_rows(t, "us", 20), src.first_row) == (True, 3)  # every skipped row before the start
    assert (src.seek_rows(t, "us", 11), src.first_row) == (True, 3)
    assert (src.seek_rows(t, "us", 10), src.first_row) == (False, 0)  # the row at 10 is in range
    assert (src.seek_rows(t, "us", 0), src.first_row) == (True, 0)
    assert (src.seek_rows(np.array([0.4, 1.6]), "ms", 1600), src.first_row) == (True, 1)  # 1.6 ms = 1600 µs
    assert (src.seek_rows(np.array([0.0004, 0.0016]), "s", 1001), src.first_row) == (True, 1)
    assert (src.seek_rows(np.array([1.4, 2.6]), "us", 2), src.first_row) == (True, 1)  # 1.4 µs rounds to 1
    assert (src.seek_rows(np.array([1.4, 1.6], np.float32), "us", 2), src.first_row) == (True, 1)  # float32 too
    big = np.array([2**53, 2**53 + 1], np.int64)  # integer µs compared exactly, not through float64
    assert (src.seek_rows(big, "us", 2**53 + 1), src.first_row) == (True, 1)


@st.composite
def tables(draw):
    n = draw(st.integers(2, 12))
    seconds = draw(st.booleans())
    t = np.cumsum(draw(st.lists(st.integers(1, 1000), min_size=n, max_size=n))).astype(np.float64)
    t = t * 1e-6 + 0.5 if seconds else t
    x = np.array(draw(st.lists(st.integers(2, 639), min_size=n, max_size=n)), np.float64)
    x[-1] = x[0]  # not rising
    y = np.array(draw(st.lists(st.integers(-1, 479), min_size=n, max_size=n)), np.float64)
    y[0], y[-1] = 300, 2
    p = np.array(draw(st.lists(st.sampled_from(draw(st.sampled_from([(0, 1), (-1, 1), (-1, 0, 1)]))), min_size=n,
                               max_size=n)), np.float64)
    p[-1] = p[0]  # not rising either (a sorted polarity column would look like time)
    order = draw(st.permutations("txyp"))
    cols = {"t": t, "x": x, "y": y, "p": p}
    return np.stack([cols[c] for c in order], axis=1), "".join(order)


@given(tables())
def test_guess_columns_finds_the_order_of_an_event_table(table):
    a, order = table
    want = order if order.index("x") < order.index("y") else order.translate(str.maketrans("xy", "yx"))
    assert guess_columns(a) == want
    assert guess_columns(a.astype(np.int64 if a.dtype.kind == "i" else np.float64).tolist()) == want


def test_guess_columns_falls_back_when_the_table_does_not_say():
    t = [1.0, 2.0, 3.0]
    rows = lambda *cols: np.array(cols, np.float64).T  # noqa: E731
    assert guess_columns(np.zeros(4)) == "txyp"
    assert guess_columns(rows([5, 5], [1.5, 2.5], [4, 2], [1, 0])) == "xtyp"  # two rows are enough
    assert guess_columns(rows([5, 3, 5], [1, 1, 2], [4, 9, 4], [1, 0, 1])) == "xtyp"
    table = rows([5, 3, 6], [1, 2, 3], [4, 9, 4], [1, 0, 1]).astype(np.uint16)  # unsigned: 3 - 5 is no rise
    assert guess_columns(table) == "xtyp"
    assert guess_columns(rows(t, [5, 3, 5], [4, 9, 4], [0, 1, 0])) == "txyp"
    assert guess_columns(rows([5, 3, 5], [4, 9, 4], [0, 1, 0], t)) == "xypt"
    assert guess_columns(rows([5, 3, 5], t, [0, 1, 0], [4, 9, 4])) == "xtpy"
    for bad in (np.zeros(4), np.zeros((3, 3)), np.zeros((3, 5)), rows([1.0], [2], [3], [0])):
        assert guess_columns(bad, "tpxy") == "tpxy"
    assert guess_columns(rows(t, [1, 2, 3], [4, 9, 4], [0, 1, 0]), "pxyt") == "pxyt"  # two rising integer columns
    assert guess_columns(rows([1.5, 2, 3], [1, 2, 3], [4, 9, 4], [0, 1, 0]), "pxyt") == "txyp"  # one fractional
    assert guess_columns(rows([1.5, 2, 3], [1.5, 2, 3], [4, 9, 4], [0, 1, 0]), "pxyt") == "pxyt"  # both
    assert guess_columns(rows(t, t, [4, 9, 4], [0, 1, 0]), "pxyt") == "pxyt"
    assert guess_columns(rows(t, [5, 3, 5], [4, 9, 4], [7, 1, 0]), "pxyt") == "pxyt"  # no polarity column
    assert guess_columns(rows(t, [1, 0, 1], [4, 9, 4], [0, 1, 0])) == "txyp"  # the last -1/0/1 column is p
    assert guess_columns(rows(t, [1, 0, 1], [4, 9, 4], [0, 2, 0])) == "tpxy"
    assert guess_columns(rows(t, [5, 3, 5], [4, 9, 4], [0, 0, 0])) == "txyp"  # all one polarity
    assert guess_columns(rows([1, 1, 1], [5, 3, 5], [4, 9, 4], [0, 1, 0]), "pxyt") == "pxyt"  # a constant is not time
    assert guess_columns(rows([1, 2, 2], [5, 3, 5], [4, 9, 4], [0, 1, 0]), "pxyt") == "txyp"  # ties still rise


def test_read_header_lines():
    f = io.BytesIO(b"% a\r\n% b\n%end\n% c\nbody")
    assert read_header_lines(f, b"%") == (["% a", "% b", "%end", "% c"], 18) and f.tell() == 18
    assert read_header_lines(f, b"%", end_line="%end") == (["% a", "% b", "%end"], 14) and f.tell() == 14
    assert read_header_lines(f, b"% ", end_line="end") == (["% a", "% b"], 9) and f.tell() == 9
    f = io.BytesIO(b"% only\n% head\xe9r")
    assert read_header_lines(f, b"%") == (["% only", "% head\xe9r"], 15) and f.tell() == 15
    f = io.BytesIO(b"% bX\r\n% c \t\n% dX \r")  # only the line break goes, at the end of the file too
    assert read_header_lines(f, b"%") == (["% bX", "% c \t", "% dX "], 18)
    assert read_header_lines(io.BytesIO(b"% dX\r"), b"%") == (["% dX"], 5)
    f = io.BytesIO(b"#a\n#b\n#c\n")
    assert read_header_lines(f, b"#", max_bytes=4) == (["#a", "#b"], 6)  # stops once past max_bytes
    assert read_header_lines(f, b"#", max_bytes=3) == (["#a"], 3)
    assert read_header_lines(io.BytesIO(b"x% a\n"), b"%") == ([], 0)
    f = io.BytesIO(b"%" + b"a" * 30 + b"\n%b\n")
    assert read_header_lines(f, b"%", max_bytes=10) == (["%" + "a" * 10], 11)  # a line cut at max_bytes


def test_iter_records_yields_whole_records_and_warns_about_a_partial_one(tmp_path):
    path = tmp_path / "r.bin"
    body = bytes(range(256)) * 20  # 5120 bytes
    path.write_bytes(b"HEAD" + body + b"xy")
    src = FileSource(path, block_bytes=1024)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = list(iter_records(src, 4, 10))
    assert [(len(a), at) for a, at in got] == [(1020, 4 + 1020 * k) for k in range(5)] + [(10 * 2, 5104)]
    assert b"".join(a.tobytes() for a, _ in got) == (body + b"xy")[:5120]
    assert all(a.dtype == np.uint8 for a, _ in got)
    assert [str(w.message) for w in caught] == [
        f"{src.path}: truncated: 2 byte(s) at byte 5124 are a partial 10-byte event (ignored)"]
    assert caught[0].category is EventWarning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert sum(len(a) for a, _ in iter_records(src, 4, 10, warn=False)) == 5120
        assert [at for _, at in iter_records(src, 4, 2048, warn=False)] == [4, 2052]
        assert [(len(a), at) for a, at in iter_records(src, 6, 1024)] == [(1024, 6), (1024, 1030), (1024, 2054),
                                                                          (1024, 3078), (1024, 4102)]


def test_the_readers_counts_agree_with_their_nouns(tmp_path):
    """A count of one in a reader's message is singular ('1 events dropped', 'MAT header is 1 bytes' before;
    the commands' own counts were fixed in session 12), and the others plural."""
    from evstream.sources import matlab, npy_stream

    t, z = np.array([5, 4, 6], np.int64), np.zeros(3, np.uint16)
    src = source(tmp_path, [Block(t, z, z, z.astype(np.uint8), 0, 30, 5)], 30, timestamps="drop")
    with pytest.warns(EventWarning, match=rf"^{re.escape(src.path)}: 1 event dropped: their timestamps go back "):
        list(src)
    path = tmp_path / "one.bin"
    path.write_bytes(b"1")
    with pytest.raises(EventError, match=rf"^{re.escape(str(path))}: the file shrank from 2 to 1 byte while it was "):
        check_not_shrunk(str(path), 2)
    with pytest.raises(EventError, match=rf"^{re.escape(str(path))}: MAT header is 1 byte, 128 expected "):
        matlab.read_variables(str(path))
    with pytest.raises(ValueError, match=r"^cut short in its \.npy header \(1 byte from byte 10\)$"):
        npy_stream.parse_header(b"\x93NUMPY\x01\x00\x01\x00")
    with pytest.raises(ValueError, match=r"^cut short in its \.npy header \(2 bytes from byte 10\)$"):
        npy_stream.parse_header(b"\x93NUMPY\x01\x00\x02\x00")


def test_a_file_that_shrinks_or_goes_away_while_read_is_an_error(tmp_path):
    path = tmp_path / "r.bin"
    path.write_bytes(b"12345")
    check_not_shrunk(str(path), 5)
    check_not_shrunk(str(path), 4)  # it grew: a recording being written, nothing is missing
    with pytest.raises(EventError, match=rf"^{re.escape(str(path))}: the file shrank from 6 to 5 bytes while it was "
                                         r"read: the events after byte 5 are missing$"):
        check_not_shrunk(str(path), 6)
    path.unlink()
    with pytest.raises(EventError, match=rf"^{re.escape(str(path))}: the file went away while it was read: the "
                                         r"events after that are missing$"):
        check_not_shrunk(str(path), 0)


@pytest.mark.parametrize("t, x, y, ok", [
    (0, 15, 15, True), ((1 << 8) - 1, 0, 0, True), (-1, 0, 0, False), (1 << 8, 0, 0, False),
    (5, 16, 0, False), (5, 0, 16, False)])
def test_check_fits_at_each_limit(t, x, y, ok):
    """x and y below `side`, t from 0 to below 2^t_bits: the last value that fits, and the first that
    does not, of each; the message names the file, the event and the limits."""
    g = Geometry(40, 40)
    events = EventChunk.from_arrays([0, t], [1, x], [1, y], [1, 1], g)
    if ok:
        check_fits("f.bin", events, 16, 8, "a test file")
        return
    with pytest.raises(ValueError) as e:
        check_fits("f.bin", events, 16, 8, "a test file")
    assert str(e.value) == (f"f.bin: event 1 (t={t} µs, x={x}, y={y}) does not fit a test file (x, y below 16; "
                            "t from 0 to below 2^8 µs)")
