"""evstream's native format: an `.npz` of struct-of-arrays events plus geometry, labels and metadata.

Arrays: `t` int64 µs, `x`, `y` uint16, `p` uint8 (1 = ON), optional `label` and `cls` uint8;
scalars `width`, `height`; `meta` a JSON string (scene, seed, noise, provenance). No pickle: arrays
of Python objects are refused.

Members stream straight from the zip (`npy_stream`): a stored one from its bytes, a deflated one through
zlib-ng's incremental inflater, each checked against its CRC by zlib-ng's SIMD CRC32, in blocks of
`BLOCK_EVENTS` events, so memory does not grow with the recording, and a member may not claim more
than its bytes can hold.

Seeking (`set_time_range`, for --start-us): `save` flushes each event column's deflate stream every
`SEEK_BLOCK_EVENTS` events (`npz_writer`: a raw inflater can start there) and adds a small index
member, `seek`: per block its first row, first and last time, and per column where the block starts
in the compressed bytes and its CRC-32. A reader bisects the index's last times and inflates every
column from the block holding the first event at or after the start; the blocks it reads are checked
against their CRCs, the ones before are not read. Files without the index (written before it, or by
other tools, or stored uncompressed) are read from the start.
"""

from __future__ import annotations

import builtins
import json
import os
import struct
import zipfile
import zlib
from collections.abc import Iterable, Iterator

import numpy as np
from zlib_ng import zlib_ng

from evstream.events import EventChunk, EventError, Geometry, Validator, concat, counted

from . import npy_stream, npz_writer
from ._base import GEOMETRY_FLAGS, MAX_SENSOR_SIDE, check_not_shrunk

NAME = "native (.npz)"
FORMAT = "native"
DEFAULT_CHUNK_EVENTS = 50_000
BLOCK_EVENTS = 1 << 16  # events inflated at a time per column
SEEK_BLOCK_EVENTS = BLOCK_EVENTS  # events between the flush points a seek can start at (written files)
COLUMNS = ("t", "x", "y", "p", "label", "cls")  # the per-event members, in the order written
# What reading a damaged file raises (a bad CRC, a broken deflate stream, a cut member).
ZIP_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error, zlib_ng.error)


def probe(head: bytes, path: str) -> bool:
    if not head.startswith(b"PK\x03\x04"):
        return False
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
    except zipfile.BadZipFile:
        return False
    return {"t.npy", "x.npy", "y.npy", "p.npy", "width.npy", "height.npy"} <= names


def read_member(f, info: zipfile.ZipInfo) -> np.ndarray:
    """The `.npy` member `info` of the open zip file `f` as a writable array, its CRC checked (bounded by
    what the member's bytes can hold). A damaged member raises ValueError saying where and what."""
    size = os.fstat(f.fileno()).st_size
    return npy_stream.Member(f.name, info, size).read(limit=max(info.file_size, 0))


def save(path: str | os.PathLike, events: EventChunk | Iterable[EventChunk], meta: dict | None = None,
         compress: bool = True) -> EventChunk:
    """Write events (a chunk or an iterable of chunks) to `path`; returns what was written."""
    chunk = events if isinstance(events, EventChunk) else concat(list(events))
    arrays = {"t": chunk.t, "x": chunk.x, "y": chunk.y, "p": chunk.p,
              "width": np.int64(chunk.geometry.width), "height": np.int64(chunk.geometry.height),
              "meta": np.array(json.dumps(meta or {}, sort_keys=True))}
    for name in ("label", "cls"):
        if getattr(chunk, name) is not None:
            arrays[name] = getattr(chunk, name)
    with builtins.open(path, "wb") as f:
        if not compress:
            np.savez(f, **arrays)
            return chunk
        w = npz_writer.NpzWriter(f)
        blocks = {name: w.add(name, arrays[name], SEEK_BLOCK_EVENTS) for name in COLUMNS if name in arrays}
        for name in ("width", "height", "meta"):
            w.add(name, arrays[name])
        t = chunk.t
        if len(t) and bool(np.all(t[1:] >= t[:-1])):  # a seek by time needs time order
            w.add("seek", seek_index(t, blocks))
        w.close()
    return chunk


def seek_index(t: np.ndarray, blocks: dict[str, tuple[list[int], list[int]]]) -> np.ndarray:
    """The `seek` member: per block of SEEK_BLOCK_EVENTS events its first row, its first and last time
    (`t` in time order), and per column (`blocks`: name -> each block's compressed start and CRC-32)."""
    n, b = len(t), SEEK_BLOCK_EVENTS
    rows = np.arange(0, n, b, dtype=np.int64)
    dtype = [("row", "<i8"), ("t_min", "<i8"), ("t_max", "<i8")]
    for name in blocks:
        dtype += [(f"{name}_at", "<i8"), (f"{name}_crc", "<u4")]
    index = np.zeros(len(rows), dtype)
    index["row"], index["t_min"], index["t_max"] = rows, t[rows], t[np.minimum(rows + b, n) - 1]
    for name, (starts, crcs) in blocks.items():
        index[f"{name}_at"], index[f"{name}_crc"] = starts, crcs
    return index


class NativeSource:
    """Replays a native `.npz` in chunks of `chunk_events` events (or `chunk_us` of event time), its members
    streamed (`npy_stream`): memory does not grow with the recording."""

    format = FORMAT

    def __init__(self, path, chunk_events: int = DEFAULT_CHUNK_EVENTS, chunk_us: int | None = None,
                 geometry: Geometry | None = None, timestamps: str = "error"):
        self.path = os.fspath(path)
        self.chunk_events = int(chunk_events)
        self.chunk_us = chunk_us
        self.timestamps = timestamps
        if self.chunk_events <= 0 or (chunk_us is not None and chunk_us <= 0):
            raise ValueError("chunk_events and chunk_us must be positive")
        try:
            with zipfile.ZipFile(self.path) as z:
                self._infos = {i.filename[:-4]: i for i in z.infolist() if i.filename.endswith(".npy")}
            files = set(self._infos)
            missing = {"t", "x", "y", "p", "width", "height"} - files
            if missing:
                raise EventError(f"{self.path}: native file lacks arrays {sorted(missing)}")
            self.geometry = geometry or Geometry(self._scalar("width"), self._scalar("height"))
            if geometry is None and max(self.geometry.width, self.geometry.height) > MAX_SENSOR_SIDE:
                raise EventError(f"{self.path}: the file claims a {self.geometry} sensor, larger than any event "
                                 f"camera ({MAX_SENSOR_SIDE} a side); if it is real: {GEOMETRY_FLAGS}")
            self.meta = self._meta() if "meta" in files else {}
            self.has_labels = "label" in files
            columns = self._columns()  # every column's header checked here
            self.n_events = columns["t"].rows
            for m in columns.values():
                m.close()
            self.file_size = os.path.getsize(self.path)
        except ZIP_ERRORS as e:
            if isinstance(e, EventError):
                raise
            raise EventError(f"{self.path}: unreadable native file: {e}") from None
        self.fraction_read: float | None = None  # share of the events read so far
        self._seek: tuple[int, np.ndarray] | None = None  # (block, index) reading starts at (set_time_range)
        self._first_row = 0  # the row it starts at

    def info(self) -> dict:
        return {"format": self.format, "path": self.path, "meta": self.meta}

    def _member(self, name: str) -> npy_stream.Member:
        return npy_stream.Member(self.path, self._infos[name], os.path.getsize(self.path))

    def _scalar(self, name: str) -> int:
        a = self._member(name).read(limit=64)
        if a.size != 1 or a.dtype.kind not in "iu":
            raise ValueError(f"array {name!r}: {a.dtype} of shape {a.shape}, not one integer")
        return int(a.ravel()[0])

    def _meta(self) -> dict:
        a = self._member("meta").read(limit=1 << 20)
        try:
            meta = json.loads(str(a)) if a.dtype.kind == "U" and a.ndim == 0 else None
        except ValueError:
            meta = None
        if not isinstance(meta, dict):
            raise ValueError(f"array 'meta': not a JSON object ({a.dtype} of shape {a.shape})")
        return meta

    def _columns(self) -> dict[str, npy_stream.Member]:
        cols = {k: self._member(k) for k in self._column_names()}
        for k, m in cols.items():
            if len(m.shape) != 1 or m.dtype.kind not in "iub":
                raise ValueError(f"array {k!r}: {m.dtype} of shape {m.shape}, not one integer per event")
        n = cols["t"].rows
        for k, m in cols.items():
            if m.rows != n:
                raise EventError(f"{self.path}: array {k!r} has {m.rows} entries, 't' has {n}")
        return cols

    def set_time_range(self, start_us: int | None, end_us: int | None) -> bool:
        """Start at the block holding the first event at or after `start_us`, found by bisection on the
        `seek` index's last times; False (read from the start) without an index or when that is block 0."""
        self._seek, self._first_row = None, 0
        if start_us is None or "seek" not in self._infos:
            return False
        try:
            index = self._member("seek").read(limit=self._infos["seek"].file_size)
            self._check_index(index)
        except ZIP_ERRORS as e:
            if isinstance(e, EventError):
                raise
            raise EventError(f"{self.path}: unreadable native file: {e}") from None
        k = int(np.searchsorted(index["t_max"], start_us, side="left"))  # every event before it is earlier
        if k == 0 or (k < len(index) and not self._flush_points_at(index, k)):
            return False
        self._seek = (k, index)
        self._first_row = int(index["row"][k]) if k < len(index) else self.n_events
        return True

    def _check_index(self, index: np.ndarray) -> None:
        """What the seek relies on: a block per SEEK-sized run of rows, times in order, flush points inside
        each column's bytes and rising (ValueError naming what is wrong)."""
        names = index.dtype.names or ()
        need = ["row", "t_min", "t_max"] + [f"{c}_{f}" for c in self._column_names() for f in ("at", "crc")]
        missing = [k for k in need if k not in names]
        if index.ndim != 1 or missing or not len(index):
            raise ValueError(f"array 'seek': {index.dtype} of shape {index.shape} is not a seek index"
                             + (f" (no {missing[0]})" if missing else ""))
        n = self.n_events
        row = index["row"]
        step = int(row[1]) if len(row) > 1 else max(n, 1)
        if step <= 0 or not np.array_equal(row, np.arange(len(row), dtype=np.int64) * step) or not (
                (len(row) - 1) * step < max(n, 1) <= len(row) * step):
            raise ValueError(f"array 'seek': its {counted(len(row), 'block')} do not cover the "
                             f"{counted(n, 'event')} in equal runs")
        t_min, t_max = index["t_min"], index["t_max"]
        if np.any(t_min > t_max) or np.any(t_max[:-1] > t_min[1:]):
            raise ValueError("array 'seek': its blocks' times are not in order")
        for c in self._column_names():
            at, size = index[f"{c}_at"], self._infos[c].compress_size
            if at[0] != 0 or np.any(at[1:] <= at[:-1]) or at[-1] >= size:
                raise ValueError(f"array 'seek': the blocks of {c!r} do not start inside its "
                                 f"{counted(size, 'byte')}, rising")

    def _flush_points_at(self, index: np.ndarray, k: int) -> bool:
        """Whether block k of every column starts at a flush point of its deflate stream: the 4 bytes
        before it are the empty stored block a full flush ends with (00 00 FF FF). A file whose members
        were compressed again (re-zipped, the index carried along) has none there: read from the start."""
        with builtins.open(self.path, "rb") as f:
            for c in self._column_names():
                info = self._infos[c]
                if info.compress_type != zipfile.ZIP_DEFLATED:
                    return False
                f.seek(info.header_offset + 26)
                local = f.read(4)
                if len(local) < 4:
                    return False
                f.seek(info.header_offset + 30 + sum(struct.unpack("<HH", local)) + int(index[f"{c}_at"][k]) - 4)
                if f.read(4) != b"\x00\x00\xff\xff":
                    return False
        return True

    def _column_names(self) -> tuple[str, ...]:
        return ("t", "x", "y", "p", *(["label"] if self.has_labels else []))

    def _blocks(self) -> Iterator[dict]:
        """Aligned pieces of every column, in order (members read once, in step), from the block a time
        range starts at."""
        try:  # members are read here, as the stream goes: a corrupt one shows only now
            cols = self._columns()
            if self._seek is not None:
                k, index = self._seek
                if k == len(index):  # the range starts after the last event
                    for m in cols.values():
                        m.close()
                    return
                row, step = int(index["row"][k]), int(index["row"][1])
                for name, m in cols.items():
                    m.skip_to_block(row, int(index[f"{name}_at"][k]), index[f"{name}_crc"][k:], step)
            yield from npy_stream.lockstep(cols, BLOCK_EVENTS)
        except ZIP_ERRORS as e:
            if isinstance(e, EventError):
                raise
            raise EventError(f"{self.path}: unreadable native file: {e}") from None

    def __iter__(self) -> Iterator[EventChunk]:
        blocks = self._blocks()
        try:
            yield from self._chunks(blocks)
        except EventError as e:
            if "unreadable native file" in str(e):
                raise
            # bad events from a member whose CRC fails at its end: the damage is the news, not the events
            try:
                for _ in blocks:
                    pass
            except EventError as damaged:
                raise damaged from None
            raise

    def _chunks(self, blocks) -> Iterator[EventChunk]:
        check = Validator(self.geometry, self.path, self.timestamps)
        n = self.n_events
        done = self._first_row  # events handed out (or skipped by a seek)
        buf: dict[str, np.ndarray] | None = None  # events read, not yet handed out
        bin_end = None  # chunk_us: end of the current time bin (bins anchored at the first event)

        def emit(k: int, t_end: int) -> EventChunk:
            nonlocal buf, done
            chunk = EventChunk.from_arrays(buf["t"][:k], buf["x"][:k], buf["y"][:k], buf["p"][:k], self.geometry,
                                           label=buf["label"][:k] if self.has_labels else None, t_end=t_end)
            buf = {key: a[k:] for key, a in buf.items()}
            done += k
            self.fraction_read = done / n if n else 1.0
            return check(chunk)

        for block in blocks:
            buf = block if buf is None else {k: np.concatenate([buf[k], a]) for k, a in block.items()}
            t = buf["t"]
            if self.chunk_us is None:
                while len(buf["t"]) > self.chunk_events:  # the next event bounds the chunk's watermark
                    yield emit(self.chunk_events, int(buf["t"][self.chunk_events]))
                continue
            if bin_end is None and len(t):
                bin_end = int(t[0]) + self.chunk_us
            while len(buf["t"]):
                k = int(np.searchsorted(buf["t"], bin_end, side="left"))
                if k == len(buf["t"]):
                    break  # the bin may go on in the next block
                if k == 0:  # empty bins (a gap in time): on to the bin of the next event, no chunk per bin
                    bin_end += (int(buf["t"][0]) - bin_end) // self.chunk_us * self.chunk_us
                    k = int(np.searchsorted(buf["t"], bin_end, side="left"))
                    if k == 0:
                        bin_end += self.chunk_us
                        continue
                yield emit(k, int(buf["t"][k]))
                bin_end += self.chunk_us
        if buf is None:
            return
        while len(buf["t"]) or done == 0:
            k = len(buf["t"]) if self.chunk_us is not None else min(self.chunk_events, len(buf["t"]))
            last = len(buf["t"]) == k
            t_end = (int(buf["t"][-1]) if len(buf["t"]) else 0) if last else int(buf["t"][k])
            yield emit(k, t_end)
            if last:
                check_not_shrunk(self.path, self.file_size)
                return


def open(path, **options) -> NativeSource:  # noqa: A001 - the format-module interface
    return NativeSource(path, **options)
