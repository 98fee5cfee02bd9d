"""MATLAB `.mat` (level 5) files holding events: our own small MAT v5 parser (numeric matrices,
zlib-compressed or not), so scipy is not needed.

Looked for: a numeric N×4 (or 4×N) matrix named `events` (else the only such matrix) with columns
guessed from the first rows (`x, y, p, t` in the ETH lifetime data; `columns=` overrides), or separate vectors named
t/ts, x, y, p/pol. p as ±1 or 0/1; t in µs (integers) or seconds (floats; `time_unit=` overrides).
The whole matrix is loaded (MAT stores it column by column), so memory grows with the file: these are
small dataset files. Sensor size from `width`/`height` scalars, else fitted to the events.
MAT v7.3 files are HDF5 and are read by the HDF5 reader.
"""

from __future__ import annotations

import builtins
import struct
import zlib
from collections.abc import Iterator

import numpy as np

from evstream.events import EventError, Geometry, counted

from ._base import Block, FileSource, find_fields, fit_geometry, guess_columns, guess_time_unit

NAME = "MATLAB .mat (level 5)"
FORMAT = "mat"

_MI = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 9: "f8", 12: "i8", 13: "u8"}
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_NUMERIC_CLASSES = set(range(6, 16))  # double, single, int8 ... uint64
_MAX_DECOMPRESSED = 8 << 30


def probe(head: bytes, path: str) -> bool:
    return head.startswith(b"MATLAB 5.0 MAT-file") and len(head) >= 128 and head[126:128] in (b"IM", b"MI")


class _Reader:
    """Walks MAT v5 data elements in a byte buffer."""

    def __init__(self, data: bytes, endian: str, base: int, path: str):
        self.data, self.e, self.base, self.path = data, endian, base, path

    def fail(self, pos: int, reason: str):
        return EventError(f"{self.path} at byte {self.base + pos}: {reason}")

    def tag(self, pos: int) -> tuple[int, int, int, int]:
        """(type, nbytes, data start, next element start)."""
        if pos + 8 > len(self.data):
            raise self.fail(pos, "truncated MAT data element tag")
        first, second = struct.unpack_from(self.e + "II", self.data, pos)
        if first >> 16:  # small data element: 4 bytes of data inside the tag
            return first & 0xFFFF, first >> 16, pos + 4, pos + 8
        end = pos + 8 + second
        if end > len(self.data):
            raise self.fail(pos, f"MAT element of {counted(second, 'byte')} runs past the end of its data (truncated?)")
        return first, second, pos + 8, pos + 8 + (second + 7) // 8 * 8

    def array(self, pos: int, what: str) -> np.ndarray:
        kind, nbytes, start, _ = self.tag(pos)
        if kind not in _MI:
            raise self.fail(pos, f"{what}: MAT data type {kind} is not numeric")
        dt = np.dtype(self.e + _MI[kind])
        if nbytes % dt.itemsize:
            raise self.fail(pos, f"{what}: {counted(nbytes, 'byte')} is not a whole number of {dt} values")
        return np.frombuffer(self.data, dt, nbytes // dt.itemsize, start)

    def matrix(self, pos: int, end: int):
        """(name, numeric array in MATLAB's shape) of a miMATRIX body, or None if not numeric."""
        flags = self.array(pos, "array flags")
        _, _, _, pos = self.tag(pos)
        cls = int(flags[0]) & 0xFF
        dims = self.array(pos, "dimensions")
        _, _, _, pos = self.tag(pos)
        name = self.array(pos, "name").tobytes().decode("latin-1")
        _, _, _, pos = self.tag(pos)
        if cls not in _NUMERIC_CLASSES or pos >= end:
            return name, None
        if (int(flags[0]) >> 11) & 1:  # complex
            return name, None
        values = self.array(pos, f"variable {name!r}")
        shape = tuple(int(d) for d in dims)
        if int(np.prod(shape)) != len(values):
            raise self.fail(pos, f"variable {name!r}: {counted(len(values), 'value')} for dimensions {shape}")
        return name, values.reshape(shape, order="F")


def read_variables(path: str) -> dict:
    """Numeric variables of a MAT v5 file, by name (others are skipped)."""
    with builtins.open(path, "rb") as f:
        data = f.read()
    if len(data) < 128:
        raise EventError(f"{path}: MAT header is {counted(len(data), 'byte')}, 128 expected (truncated)")
    endian = "<" if data[126:128] == b"IM" else ">"
    out = {}
    pos = 128
    while pos < len(data):
        r = _Reader(data, endian, 0, path)
        if len(data) - pos < 8:
            raise r.fail(pos, f"{len(data) - pos} stray bytes after the last MAT element (truncated?)")
        kind, nbytes, start, nxt = r.tag(pos)
        if kind == _MI_COMPRESSED:
            d = zlib.decompressobj()
            try:
                body = d.decompress(data[start : start + nbytes], _MAX_DECOMPRESSED)
            except zlib.error as e:
                raise r.fail(start, f"corrupt compressed MAT element: {e}") from None
            if not d.eof:
                raise r.fail(start, "compressed MAT element ends early (truncated file?)")
            inner = _Reader(body, endian, start, path)
            ikind, _, istart, iend = inner.tag(0)
            if ikind == _MI_MATRIX:
                _add(out, inner, istart, iend)
        elif kind == _MI_MATRIX:
            _add(out, r, start, start + nbytes)
        pos = nxt
    return out


def _add(out: dict, r: _Reader, start: int, end: int) -> None:
    try:
        name, arr = r.matrix(start, end)
    except (ValueError, IndexError, struct.error, OverflowError) as e:
        if isinstance(e, EventError):
            raise
        raise r.fail(start, f"malformed MAT matrix: {e}") from None
    if arr is not None:
        out[name] = arr


class MatSource(FileSource):
    """Replays events from a .mat file; timestamps must rise (policy 'error' by default)."""

    format = FORMAT

    def __init__(self, path, columns: str | None = None, time_unit: str | None = None, **options):
        super().__init__(path, **options)
        if columns is not None and sorted(columns) != sorted("txyp"):
            raise ValueError(f"columns {columns!r}: a permutation of 'txyp'")
        variables = read_variables(self.path)
        cols, self.variable = self._pick(variables, columns)
        self._cols = cols
        self.n_events = len(cols["t"])
        self.time_unit = time_unit or guess_time_unit(cols["t"])
        if "width" in variables and "height" in variables:
            self.set_geometry(Geometry(int(variables["width"].ravel()[0]), int(variables["height"].ravel()[0])),
                              "file (width/height)")
        elif self.geometry is None:
            mx = int(cols["x"].max()) if self.n_events else 0
            my = int(cols["y"].max()) if self.n_events else 0
            self.set_geometry(fit_geometry(mx, my), "fitted to the events (the file has no size)")
        self.details = {"variable": self.variable, "columns": getattr(self, "columns", None),
                        "time_unit": self.time_unit, "events": self.n_events}

    def _pick(self, v: dict, columns: str):
        vectors = {k: a.ravel() for k, a in v.items() if a.ndim <= 2 and min(a.shape or (1,)) == 1}
        fields = find_fields(vectors)
        if fields and len({len(vectors[n]) for n in fields.values()}) == 1:
            return {k: vectors[n] for k, n in fields.items()}, "+".join(fields.values())
        tables = {k: a for k, a in v.items() if a.ndim == 2 and 4 in a.shape and a.size >= 4}
        name = "events" if "events" in tables else (next(iter(tables)) if len(tables) == 1 else None)
        if name is None:
            raise self.error(f"no event matrix: expected an N×4 'events' matrix or t/x/y/p vectors; "
                             f"numeric variables: { {k: a.shape for k, a in v.items()} }")
        a = tables[name]
        rows = a if a.shape[1] == 4 else a.T
        columns = columns or guess_columns(rows[:1000], "xypt")
        self.columns = columns
        return {k: np.ascontiguousarray(rows[:, i]) for i, k in enumerate(columns)}, name

    def set_time_range(self, start_us: int | None, end_us: int | None) -> bool:
        """Start at `start_us` by bisection on the time column (held in memory)."""
        return self.seek_rows(self._cols["t"], self.time_unit, start_us)

    def _blocks(self) -> Iterator[Block]:
        return self._column_blocks(self._cols, self.n_events, self.time_unit)


def open(path, **options) -> MatSource:  # noqa: A001 - the format-module interface
    return MatSource(path, **options)
