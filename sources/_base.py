"""What every file reader shares: options, re-chunking of decoded blocks, validation, watermarks,
warnings, byte offsets in errors, and a few small numba kernels (clock unwrapping).

A reader subclasses `FileSource` and implements `_blocks()`, a generator of `Block`s (decoded events
in file order with the byte range they came from). `FileSource.__iter__` turns those into validated
`EventChunk`s of `chunk_events` events (or `chunk_us` of event time) at constant memory.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from evstream.events import EventChunk, EventError, Geometry, TimestampPolicy, Validator, counted, shown
from evstream.jit import njit

DEFAULT_CHUNK_EVENTS = 50_000
DEFAULT_BLOCK_BYTES = 1 << 20  # larger blocks are no faster and hold more resident memory
MAX_CHUNK_EVENTS = 4_000_000  # a chunk_us chunk is cut here too, so memory stays bounded

# Sensors whose size a reader may assume when a file does not say (smallest that fits wins).
KNOWN_SENSORS = [
    Geometry(34, 34),  # N-MNIST (ATIS crop)
    Geometry(128, 128),  # DVS128
    Geometry(240, 180),  # DAVIS240
    Geometry(304, 240),  # ATIS
    Geometry(320, 240),  # DVXplorer Lite
    Geometry(346, 260),  # DAVIS346
    Geometry(640, 480),  # Prophesee Gen3, DVXplorer
    Geometry(1280, 720),  # Prophesee Gen4 / IMX636
]


class EventWarning(UserWarning):
    """A recoverable problem in a recording (a truncated tail, events dropped by the timestamp policy)."""


@dataclass
class Block:
    """Decoded events in file order and the byte range [byte_start, byte_end) they came from.

    `record_bytes` > 0 means fixed-size records starting at `byte_start` (exact offsets per event).
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    byte_start: int = 0
    byte_end: int = 0
    record_bytes: int = 0
    locate: object = None  # optional: event index in this block -> its byte offset in the file

    def __len__(self) -> int:
        return len(self.t)


def as_geometry(g) -> Geometry | None:
    """A Geometry from a Geometry, a (width, height) pair or 'WxH'; None stays None."""
    if g is None or isinstance(g, Geometry):
        return g
    if isinstance(g, str):
        try:
            w, h = (int(v) for v in g.lower().split("x"))
        except ValueError:
            raise ValueError(f"geometry {g!r}: expected WIDTHxHEIGHT, e.g. 640x480") from None
        return Geometry(w, h)
    w, h = g
    return Geometry(int(w), int(h))


# No event camera has more than 2048 columns or rows (EVT 2.0/3.0 carry 11-bit addresses). A size the
# data only claims — fitted to the events, or in an EventPacket from a file or the network — is held to
# it, so one corrupt event (x = 60000) or packet is an error naming it, not a 60001x60001 "sensor" whose
# per-pixel state (13 GiB a stage) exhausts memory. `--geometry` still sets any size.
MAX_SENSOR_SIDE = 2048
# how a user gives the sensor's size, on the command line and in Python: said where a file's is missing or wrong
GEOMETRY_FLAGS = "--geometry WxH, geometry=(W, H) in Python"


def fit_geometry(max_x: int, max_y: int, sensors: list[Geometry] | None = None) -> Geometry:
    """The smallest known sensor that holds (max_x, max_y), else the bounding box, at most
    `MAX_SENSOR_SIDE` a side (events beyond it are then outside the sensor: `--geometry` reads them)."""
    for g in KNOWN_SENSORS if sensors is None else sensors:
        if max_x < g.width and max_y < g.height:
            return g
    return Geometry(min(MAX_SENSOR_SIDE, max(1, int(max_x) + 1)), min(MAX_SENSOR_SIDE, max(1, int(max_y) + 1)))


@njit(cache=True, nogil=True)
def unwrap_kernel(t_raw, bits, state, out):
    """Unwrap a counter of `bits` bits that wraps: a drop of more than half the range is a wrap.

    `state` = [offset, last raw value (-1 at start), wraps]; writes int64 µs into `out`.
    """
    half = np.int64(1) << (bits - 1)
    period = np.int64(1) << bits
    offset = state[0]
    last = state[1]
    wraps = state[2]
    for i in range(len(t_raw)):
        v = np.int64(t_raw[i])
        if last >= 0 and last - v > half:
            offset += period
            wraps += 1
        last = v
        out[i] = v + offset
    state[0] = offset
    state[1] = last
    state[2] = wraps


class Unwrapper:
    """Streaming unwrap of a `bits`-bit timestamp counter (e.g. DAT and AEDAT2's 32-bit µs clocks)."""

    def __init__(self, bits: int):
        self.bits = bits
        self.state = np.array([0, -1, 0], np.int64)

    @property
    def wraps(self) -> int:
        return int(self.state[2])

    def __call__(self, t_raw: np.ndarray) -> np.ndarray:
        out = np.empty(len(t_raw), np.int64)
        # contiguous (DAT's times are every other word of its records): the layout the kernels ahead of time take
        unwrap_kernel(np.ascontiguousarray(t_raw), self.bits, self.state, out)
        return out


class FileSource:
    """Base of the file readers. Subclasses set `format`, `geometry` (before iterating) and implement
    `_blocks()`; they may add entries to `self.details` (shown by `info()`) and counters to
    `self.counters`.

    Options common to every reader: `chunk_events` (events per chunk), `chunk_us` (event time per
    chunk, instead), `geometry` (override the file's), `timestamps` (policy for timestamps that go
    back: 'error', 'sort' or 'drop'; the default is the reader's `default_timestamps`).
    """

    format = "?"
    default_timestamps = "error"
    has_labels = False

    def __init__(self, path, chunk_events: int = DEFAULT_CHUNK_EVENTS, chunk_us: int | None = None,
                 geometry=None, timestamps: str | None = None, block_bytes: int = DEFAULT_BLOCK_BYTES):
        self.path = os.fspath(path)
        self.chunk_events = int(chunk_events)
        self.chunk_us = None if chunk_us is None else int(chunk_us)
        if self.chunk_events <= 0 or (self.chunk_us is not None and self.chunk_us <= 0):
            raise ValueError("chunk_events and chunk_us must be positive")
        self.block_bytes = max(1024, int(block_bytes))
        self.timestamps = TimestampPolicy(timestamps or self.default_timestamps).value
        self.geometry_override = as_geometry(geometry)
        self.geometry: Geometry | None = self.geometry_override
        self.geometry_source = "option" if self.geometry_override else None
        self.file_size = os.path.getsize(self.path)
        self.fraction_read: float | None = None  # how far into the file decoding has got (0..1), if known
        self.details: dict = {}
        self.counters: dict = {}
        self.dropped = 0
        self.reordered = 0
        self.first_row = 0  # column readers: the row a time range starts at (`seek_rows`)

    # -- to implement ----------------------------------------------------------------------------
    def _blocks(self) -> Iterator[Block]:
        raise NotImplementedError

    # -- shared ----------------------------------------------------------------------------------
    def _column_blocks(self, cols: dict, n_events: int, time_unit: str,
                       rows: tuple[int, int] | None = None) -> Iterator[Block]:
        """Blocks of a recording already held as columns `t`, `x`, `y`, `p` (npy/npz, MATLAB), from the
        row `set_time_range` found on. `rows` = (byte of event 0, bytes per event) when the file holds
        one event per fixed-size row: each block then carries its bytes, so an error names its event's byte."""
        step = max(1, self.block_bytes // 16)
        for a in range(self.first_row, n_events, step):
            b = min(a + step, n_events)
            self.fraction_read = b / n_events
            where = (rows[0] + a * rows[1], rows[0] + b * rows[1], rows[1]) if rows else ()
            yield to_events(self, cols["t"][a:b], cols["x"][a:b], cols["y"][a:b], cols["p"][a:b], time_unit,
                            *where)

    def seek_rows(self, t: np.ndarray, time_unit: str, start_us: int | None) -> bool:
        """Column readers: start at the first row whose time is >= `start_us`, found by bisection on the
        time column `t` (in `time_unit`; element by element, so a memory-mapped .npy reads a few pages).

        The rows skipped are exactly those a time range drops when the file is in time order. Under the
        'sort' and 'drop' policies a file need not be, so the largest time before the row is checked
        too (one vectorised pass over the skipped times, no decoding), and the file is read from its
        start (False) if it is in the range. Under 'error' (the default) a row in the range before the
        bisection point means time goes back there, which reading from the start refuses: the seek
        skips that part unchecked."""
        self.first_row = 0
        if start_us is None or not len(t):
            return False
        scale = TIME_UNITS_US[time_unit]
        floating = np.issubdtype(t.dtype, np.floating) or time_unit != "us"

        def us(v) -> float:  # as `to_events` converts a time (monotone in v)
            return float(np.rint(np.float64(v) * scale)) if floating else int(v)

        lo, hi = 0, len(t)  # first row with us(t) >= start_us, if t rises
        while lo < hi:
            mid = (lo + hi) // 2
            if us(t[mid]) < start_us:
                lo = mid + 1
            else:
                hi = mid
        if lo and self.timestamps != "error" and not us(np.max(t[:lo])) < start_us:
            return False
        self.first_row = lo
        return True

    def set_geometry(self, g: Geometry | None, source: str) -> None:
        """Use `g` (from the header, or assumed) unless the user gave one; a claimed size beyond any event
        camera is refused (a corrupt header: its per-pixel state would exhaust memory)."""
        if self.geometry_override is None and g is not None:
            if max(g.width, g.height) > MAX_SENSOR_SIDE:
                raise self.error(f"the file claims a {g} sensor ({source}), larger than any event camera "
                                 f"({MAX_SENSOR_SIDE} a side); if it is real: {GEOMETRY_FLAGS}")
            self.geometry = g
            self.geometry_source = source

    def info(self) -> dict:
        return {
            "format": self.format, "path": self.path, "bytes": self.file_size,
            "width": self.geometry.width, "height": self.geometry.height,
            "geometry_from": self.geometry_source, "timestamps": self.timestamps,
            "dropped": self.dropped, "reordered": self.reordered, "counters": dict(self.counters),
            **self.details,
        }

    def error(self, reason: str, offset: int | None = None) -> EventError:
        at = f" at byte {offset}" if offset is not None else ""
        return EventError(f"{self.path}{at}: {reason}")

    def warn(self, message: str) -> None:
        warnings.warn(f"{self.path}: {message}", EventWarning, stacklevel=3)

    def __iter__(self) -> Iterator[EventChunk]:
        if self.geometry is None:
            raise self.error(f"no sensor size known; give it: {GEOMETRY_FLAGS}")
        check = Validator(self.geometry, self.path, self.timestamps)
        strict = check.policy is TimestampPolicy.ERROR
        queue = _Queue()
        offset = 0  # events emitted so far
        bin_start = None  # chunk_us: start of the current time bin
        for block in self._blocks():
            if not len(block):
                continue
            self._check_coords(block, offset + queue.n)
            queue.push(block)
            if block.byte_end:
                self.fraction_read = min(1.0, block.byte_end / max(1, self.file_size))
            while True:
                if self.chunk_us is None:
                    if queue.n <= self.chunk_events:
                        break
                    cut = self.chunk_events
                else:
                    if bin_start is None:
                        bin_start = queue.t_at(0)
                    cut = queue.time_cut(bin_start + self.chunk_us, MAX_CHUNK_EVENTS)
                    if cut < 0:
                        break
                    bin_start = _next_bin(bin_start, queue.t_at(cut), self.chunk_us)
                next_t = queue.t_at(cut) if strict else None
                head = queue.take(cut)
                offset += cut
                yield self._emit(check, head, next_t)
        # the rest, without a following event to bound it
        step = self.chunk_events if self.chunk_us is None else MAX_CHUNK_EVENTS
        while queue.n:
            k = min(step, queue.n)
            next_t = queue.t_at(k) if strict and k < queue.n else None
            yield self._emit(check, queue.take(k), next_t)
        check_not_shrunk(self.path, self.file_size)
        self.dropped, self.reordered = check.dropped, check.reordered
        if check.dropped:
            self.warn(f"{counted(check.dropped, 'event')} dropped: their timestamps go back "
                      f"(timestamp policy {self.timestamps!r})")

    def _emit(self, check: Validator, b: Block, next_t: int | None) -> EventChunk:
        base = check.offset
        try:
            chunk = check(EventChunk.from_arrays(b.t, b.x, b.y, b.p, self.geometry))
        except EventError as e:
            if b.byte_end <= b.byte_start:  # a reader that cannot tell bytes (AEDAT4's decoder) says nothing false
                raise
            i = getattr(e, "event_index", None)
            if b.record_bytes and i is not None:  # fixed-size records: the event's own byte
                at = b.byte_start + (i - base) * b.record_bytes
                raise EventError(f"{self.path} at byte {at}: {str(e).removeprefix(f'{self.path}: ')}") from None
            raise EventError(f"{e} [in bytes {b.byte_start}..{b.byte_end}]") from None
        if next_t is not None and len(chunk) and next_t >= chunk.t[-1]:
            chunk = chunk.replace(t_end=next_t)
        return chunk

    def _check_coords(self, b: Block, first_event: int) -> None:
        g = self.geometry
        bad = (b.x >= g.width) | (b.y >= g.height)
        if bad.any():
            i = int(np.argmax(bad))
            if b.record_bytes:
                where = f"at byte {b.byte_start + i * b.record_bytes}"
            elif b.locate is not None:
                where = f"at byte {b.locate(i)}"
            elif b.byte_end > b.byte_start:
                where = f"in bytes {b.byte_start}..{b.byte_end}"
            else:  # the reader does not know where its events lie in the file (AEDAT4): no "bytes 0..0"
                where = ""
            hint = "" if self.geometry_override else f" (if the file's is wrong: {GEOMETRY_FLAGS})"
            raise EventError(
                f"{self.path}{' ' + where if where else ''}: event {first_event + i}: ({b.x[i]}, {b.y[i]}) outside the "
                f"{g} sensor (size from {self.geometry_source}){hint}"
            )


def check_fits(path, events: EventChunk, side: int, t_bits: int, what: str) -> None:
    """For a writer of fixed-width columns (`dat.save`, `nmnist.save`): a ValueError naming the first event
    whose x or y is not below `side` or whose t is not in 0 .. 2^t_bits - 1 µs; written, its columns would
    wrap silently into a file of other events."""
    bad = np.flatnonzero((events.x >= side) | (events.y >= side) | (events.t < 0) | (events.t >= 1 << t_bits))
    if len(bad):
        i = int(bad[0])
        raise ValueError(f"{path}: event {i} (t={events.t[i]} µs, x={events.x[i]}, y={events.y[i]}) does not fit "
                         f"{what} (x, y below {side}; t from 0 to below 2^{t_bits} µs)")


def check_not_shrunk(path: str, size_at_open: int) -> None:
    """An input cut shorter while it was read (`truncate` during a paced replay) ends the stream early
    without a sign in the data: an EventError says so, so the run does not end as if whole."""
    try:
        now = os.path.getsize(path)
    except OSError:
        raise EventError(f"{path}: the file went away while it was read: the events after that are missing") from None
    if now < size_at_open:
        raise EventError(f"{path}: the file shrank from {size_at_open} to {counted(now, 'byte')} while it was read: "
                         f"the events after byte {now} are missing")


def _merge(blocks: list[Block]) -> Block:
    if len(blocks) == 1:
        return blocks[0]
    rb = blocks[0].record_bytes  # records back to back stay records: errors keep their exact byte
    contiguous = rb and all(b.record_bytes == rb and a.byte_end == b.byte_start for a, b in zip(blocks, blocks[1:]))
    return Block(*(np.concatenate([getattr(b, k) for b in blocks]) for k in "txyp"),
                 byte_start=blocks[0].byte_start, byte_end=blocks[-1].byte_end, record_bytes=rb if contiguous else 0)


def _slice(b: Block, i: int, j: int) -> Block:
    if b.record_bytes:
        return Block(b.t[i:j], b.x[i:j], b.y[i:j], b.p[i:j], b.byte_start + i * b.record_bytes,
                     b.byte_start + j * b.record_bytes, b.record_bytes)
    return Block(b.t[i:j], b.x[i:j], b.y[i:j], b.p[i:j], b.byte_start, b.byte_end)


class _Queue:
    """Decoded blocks waiting to become chunks. Chunks inside one block are views; only a chunk that
    straddles blocks is copied together."""

    def __init__(self):
        self.blocks: list[Block] = []
        self.n = 0

    def push(self, b: Block) -> None:
        self.blocks.append(b)
        self.n += len(b)

    def t_at(self, i: int) -> int:
        for b in self.blocks:
            if i < len(b):
                return int(b.t[i])
            i -= len(b)
        raise IndexError(i)

    def take(self, k: int) -> Block:
        parts = []
        while k:
            b = self.blocks[0]
            if len(b) <= k:
                parts.append(self.blocks.pop(0))
                k -= len(b)
                self.n -= len(b)
            else:
                parts.append(_slice(b, 0, k))
                self.blocks[0] = _slice(b, k, len(b))
                self.n -= k
                k = 0
        return _merge(parts)

    def time_cut(self, boundary: int, max_events: int) -> int:
        """First index ≥ 1 with t ≥ boundary (the chunk ends before it), else max_events if that
        many are waiting, else -1."""
        base = 0
        for j, b in enumerate(self.blocks):
            i = _first_at_or_after(b.t, boundary, 1 if j == 0 else 0)
            if i >= 0:
                return min(base + i, max_events)
            base += len(b)
            if base > max_events:
                return max_events
        return -1


@njit(cache=True, nogil=True)
def _first_at_or_after(t, boundary, start):
    """First index i ≥ start with t[i] ≥ boundary, else -1."""
    for i in range(start, len(t)):
        if t[i] >= boundary:
            return i
    return -1


def _next_bin(bin_start: int, t_next: int, chunk_us: int) -> int:
    """The start of the time bin holding t_next (bins are anchored at the first event)."""
    if t_next < bin_start + chunk_us:
        return bin_start if t_next >= bin_start else t_next
    return bin_start + (t_next - bin_start) // chunk_us * chunk_us


def read_header_lines(f, prefix: bytes, max_bytes: int = 1 << 20,
                      end_line: str | None = None) -> tuple[list[str], int]:
    """Read the leading lines that start with `prefix` (e.g. b'%'), up to and including `end_line`
    if given; returns (lines, body offset)."""
    lines = []
    pos = 0
    f.seek(0)
    while pos < max_bytes:
        first = f.read(len(prefix))
        if first != prefix:
            break
        rest = f.readline(max_bytes)
        line = first + rest
        if not line.endswith(b"\n"):
            # a header line running into the end of the file: the header is all there is
            pos += len(line)
            lines.append(line.decode("latin-1").rstrip("\r\n"))
            break
        pos += len(line)
        lines.append(line.decode("latin-1").rstrip("\r\n"))
        if end_line is not None and lines[-1].strip() == end_line:
            break
    f.seek(pos)
    return lines, pos


def iter_records(source: FileSource, offset: int, record_bytes: int,
                 warn: bool = True) -> Iterator[tuple[np.ndarray, int]]:
    """Whole fixed-size records of `source.path` from byte `offset`, as (uint8 array, byte start)
    blocks of about `source.block_bytes`; warns about a partial record at the end."""
    per_block = max(1, source.block_bytes // record_bytes) * record_bytes
    pos = offset
    with open(source.path, "rb") as f:
        f.seek(offset)
        while True:
            data = f.read(per_block)
            whole = len(data) - len(data) % record_bytes
            if whole:
                yield np.frombuffer(data, np.uint8, whole), pos
            if whole < len(data) and warn:
                source.warn(f"truncated: {len(data) - whole} byte(s) at byte {pos + whole} are a partial "
                            f"{record_bytes}-byte event (ignored)")
            pos += len(data)
            if len(data) < per_block:
                break


TIME_UNITS_US = {"s": 1e6, "ms": 1e3, "us": 1.0, "ns": 1e-3}
FIELD_ALIASES = {
    "t": ("t", "ts", "timestamp", "timestamps", "time", "times", "t_us"),
    "x": ("x", "xs", "x_pos"),
    "y": ("y", "ys", "y_pos"),
    "p": ("p", "ps", "pol", "polarity", "polarities", "on"),
}


def find_fields(names) -> dict | None:
    """Map t/x/y/p to the given field names (case-insensitive aliases); None if one is missing."""
    lower = {str(n).lower(): n for n in names}
    out = {}
    for key, aliases in FIELD_ALIASES.items():
        hit = next((lower[a] for a in aliases if a in lower), None)
        if hit is None:
            return None
        out[key] = hit
    return out


def guess_time_unit(t: np.ndarray) -> str:
    """Floating timestamps are seconds, integers µs (the conventions of the formats we read)."""
    return "s" if np.issubdtype(t.dtype, np.floating) else "us"


def to_events(source: FileSource, t, x, y, p, time_unit: str, byte_start: int = 0, byte_end: int = 0,
              record_bytes: int = 0) -> Block:
    """Normalise columns from any numeric dtype: t to int64 µs, p to 1 = ON (any value > 0, True, +1)."""
    if time_unit not in TIME_UNITS_US:
        raise ValueError(f"time_unit {time_unit!r}: choose from {', '.join(TIME_UNITS_US)}")
    t = np.asarray(t)
    if np.issubdtype(t.dtype, np.floating) or time_unit != "us":
        tf = t.astype(np.float64) * TIME_UNITS_US[time_unit]
        if not np.isfinite(tf).all():
            i = int(np.argmax(~np.isfinite(tf)))
            raise source.error(f"event {i} of a block has timestamp {t[i]!r}", byte_start or None)
        t64 = np.rint(tf).astype(np.int64)
    else:
        t64 = t.astype(np.int64, copy=False)
    cols = []
    for name, a in (("x", x), ("y", y)):
        a = np.asarray(a)
        if a.dtype != np.uint16:
            if len(a) and (a.min() < 0 or a.max() > 65535 or (np.issubdtype(a.dtype, np.floating)
                                                               and not np.all(a == np.floor(a)))):
                bad = (a < 0) | (a > 65535) | (a != np.floor(a))
                i = int(np.argmax(bad))
                raise source.error(f"event {i} of a block has {name} = {shown(a[i])}: not a pixel index",
                                   byte_start or None)
            a = a.astype(np.uint16)
        cols.append(a)
    p = np.asarray(p)
    p8 = p.astype(np.uint8) if p.dtype == np.bool_ else (p > 0).astype(np.uint8)
    return Block(t64, cols[0], cols[1], p8, byte_start, byte_end, record_bytes)


def guess_columns(sample: np.ndarray, default: str = "txyp") -> str:
    """Column order of an N×4 event table from its first rows: t is the one non-decreasing column
    (the non-integer one if several are), p the one with values in {-1, 0, 1}, x and y the other two
    in file order. Falls back to `default` when that does not single them out."""
    a = np.asarray(sample, np.float64)
    if a.ndim != 2 or a.shape[1] != 4 or len(a) < 2:
        return default
    rising = [j for j in range(4) if np.all(np.diff(a[:, j]) >= 0) and a[-1, j] > a[0, j]]
    if len(rising) > 1:
        fractional = [j for j in rising if np.any(a[:, j] != np.floor(a[:, j]))]
        rising = fractional if len(fractional) == 1 else []
    if len(rising) != 1:
        return default
    jt = rising[0]
    binary = [j for j in range(4) if j != jt and np.isin(a[:, j], (-1, 0, 1)).all()]
    if not binary:
        return default
    jp = binary[-1]
    rest = [j for j in range(4) if j not in (jt, jp)]
    cols = [""] * 4
    cols[jt], cols[jp], cols[rest[0]], cols[rest[1]] = "t", "p", "x", "y"
    return "".join(cols)
