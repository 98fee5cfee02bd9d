"""NumPy files that are not evstream's native `.npz`: a `.npy` structured array (fields t/x/y/p or
their common aliases), a `.npy` N×4 array (column order guessed from the first rows, see
`guess_columns`; `columns=` overrides), or an `.npz` holding t, x, y, p arrays (a struct of arrays)
or one structured array. `.npy` files are memory-mapped, so replay runs at constant memory; `.npz`
members are loaded one at a time. Never unpickled (`allow_pickle=False`).

Integer timestamps are µs, floating ones seconds (`time_unit=` overrides). Sensor size from
`width`/`height` (or `sensor_size`) members, else fitted to the events (one pass).
"""

from __future__ import annotations

import builtins
import math
import os
import zipfile
from collections.abc import Iterator

import numpy as np

from evstream.events import EventError, Geometry, counted

from . import npy_stream
from ._base import Block, FileSource, find_fields, fit_geometry, guess_columns, guess_time_unit, to_events

NAME = "NumPy .npy / .npz (structured or struct of arrays)"
FORMAT = "npy"


def probe(head: bytes, path: str) -> bool:
    if head.startswith(b"\x93NUMPY"):
        return True
    if head.startswith(b"PK\x03\x04"):
        try:
            with zipfile.ZipFile(path) as z:
                return any(n.endswith(".npy") for n in z.namelist())
        except zipfile.BadZipFile:
            return False
    return False


class NumpySource(FileSource):
    """Replays a .npy/.npz event file; timestamps must rise (policy 'error' by default)."""

    def __init__(self, path, columns: str | None = None, time_unit: str | None = None, **options):
        super().__init__(path, **options)
        self._npz = None
        self._fields: dict | None = None  # .npz of t/x/y/p members: their names, read as streams
        self._rows = None  # .npy with one event per row: (byte of row 0, bytes per row), for error offsets
        try:
            with builtins.open(self.path, "rb") as f:
                magic = f.read(6)
            if magic == b"\x93NUMPY":
                self.format = "npy"
                array = self._load_npy()
                self._cols = self._from_array(array, columns)
                if isinstance(array, np.memmap) and array.flags.c_contiguous and (
                        array.dtype.names or array.shape[1:] == (4,)):  # one event per row, in file order
                    self._rows = (int(array.offset), array.strides[0])
            else:
                self.format = "npz"
                self._npz = _Npz(self.path)
                self._cols = self._from_npz(self._npz, columns)
        except EventError:
            raise
        except Exception as e:  # numpy reports a corrupt header as anything from EOFError to SyntaxError
            raise self.error(f"unreadable NumPy file: {type(e).__name__}: {e}") from None
        if self._cols is None:  # an .npz of t, x, y, p members: streamed, never held whole
            try:
                members = self._members()
            except ValueError as e:
                raise self.error(f"unreadable NumPy file: {e}") from None
            lengths = {k: m.rows for k, m in members.items()}
            t_sample = np.empty(0, members["t"].dtype)
        else:
            lengths = {k: len(a) for k, a in self._cols.items()}
            t_sample = self._cols["t"]
        n = lengths["t"]
        if any(v != n for v in lengths.values()):
            raise self.error(f"arrays differ in length: {lengths}")
        self.n_events = n
        self.time_unit = time_unit or guess_time_unit(t_sample)
        if self.geometry is None:
            mx = my = 0
            for x, y in self._xy_pieces():
                if len(x):
                    mx, my = max(mx, int(np.max(x))), max(my, int(np.max(y)))
            self.set_geometry(fit_geometry(mx, my), "fitted to the events (the file has no size)")
        self.details = {"events": n, "time_unit": self.time_unit}

    def set_time_range(self, start_us: int | None, end_us: int | None) -> bool:
        """Start at `start_us` by bisection on the time column (a .npy, or an .npz of one array); an .npz
        of t/x/y/p members is streamed through zlib and cannot skip ahead: False, read from the start."""
        if self._cols is None:
            return False
        return self.seek_rows(self._cols["t"], self.time_unit, start_us)

    def _load_npy(self) -> np.ndarray:
        """The .npy memory-mapped; a file shorter than its header promises (np.load said only "mmap
        length is greater than file size") keeps its whole rows, with a warning naming the byte."""
        with builtins.open(self.path, "rb") as f:  # our header parser: one-line errors, long headers too
            head = f.read(12)
            if head[6:7] in (b"\x02", b"\x03") and len(head) == 12:
                head += f.read(min(int.from_bytes(head[8:12], "little"), npy_stream.MAX_HEADER_BYTES + 1))
            else:
                head += f.read(1 << 16)
        try:
            shape, fortran, dtype, start = npy_stream.parse_header(head)
        except ValueError as e:
            raise self.error(str(e)) from None
        row_bytes = dtype.itemsize * int(np.prod(shape[1:], dtype=np.int64))
        want = start + row_bytes * (shape[0] if shape else 1)
        if self.file_size >= want or not shape or fortran or row_bytes == 0:
            if not shape or row_bytes == 0 or math.prod(shape) == 0:
                return np.zeros(shape, dtype)
            return np.memmap(self.path, dtype, "r", start, shape, order="F" if fortran else "C")
        rows = (self.file_size - start) // row_bytes
        self.warn(f"truncated: the header promises {counted(shape[0], 'row')} ({want} bytes) but the file "
                  f"ends at byte {self.file_size}; kept: the {counted(rows, 'whole row')} before byte "
                  f"{start + rows * row_bytes}")
        if rows == 0:
            return np.zeros((0, *shape[1:]), dtype)
        return np.memmap(self.path, dtype, "r", start, (rows, *shape[1:]))

    def _from_array(self, a: np.ndarray, columns: str) -> dict:
        if a.dtype.names:
            f = find_fields(a.dtype.names)
            if f is None:
                raise self.error(f"structured array lacks t/x/y/p fields; has {list(a.dtype.names)}")
            if a.ndim != 1:
                raise self.error(f"structured array of shape {a.shape}: expected one dimension (an event per entry)")
            return {k: a[v] for k, v in f.items()}
        if a.ndim == 2 and 4 in a.shape:
            rows = a if a.shape[1] == 4 else a.T
            if columns is None:
                columns = guess_columns(rows[:1000])
            if sorted(columns) != sorted("txyp"):
                raise ValueError(f"columns {columns!r}: a permutation of 'txyp'")
            return {k: rows[:, i] for i, k in enumerate(columns)}
        raise self.error(f"array of shape {a.shape} and dtype {a.dtype} is not an event list "
                         "(expected a structured array with t, x, y, p or an N×4 array)")

    def _from_npz(self, z, columns: str) -> dict:
        f = find_fields(z.files)
        if f is not None:
            try:
                if "width" in z.files and "height" in z.files:
                    w, h = (z.get(k, limit=64).ravel() for k in ("width", "height"))
                    self.set_geometry(Geometry(int(w[0]), int(h[0])), "file (width/height)")
                elif "sensor_size" in z.files:
                    s = z.get("sensor_size", limit=64).ravel()
                    self.set_geometry(Geometry(int(s[0]), int(s[1])), "file (sensor_size)")
            except (IndexError, TypeError, ValueError, OverflowError) as e:
                if isinstance(e, EventError):
                    raise
                raise self.error(f"sensor size members are not two integers: {e}") from None
            self._fields = f
            return None
        if len(z.files) == 1:
            return self._from_array(z[z.files[0]], columns)
        raise self.error(f"no t/x/y/p arrays among {z.files}")

    def _members(self, keys: str = "txyp") -> dict:
        """Fresh streams of the .npz members holding `keys` (each is read once), their shapes checked."""
        members = {k: self._npz.member(self._fields[k]) for k in keys}
        for k, m in members.items():
            if len(m.shape) != 1 or m.dtype.kind not in "iufb":
                raise ValueError(f"array {self._fields[k]!r}: {m.dtype} of shape {m.shape}, not one number per event")
        return members

    def _xy_pieces(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        if self._cols is not None:
            step = 1 << 22
            for a in range(0, self.n_events, step):
                yield self._cols["x"][a : a + step], self._cols["y"][a : a + step]
            return
        try:
            for block in npy_stream.lockstep(self._members("xy"), 1 << 16):
                yield block["x"], block["y"]
        except ValueError as e:
            raise self.error(f"unreadable NumPy file: {e}") from None

    def _blocks(self) -> Iterator[Block]:
        if self._cols is not None:
            yield from self._column_blocks(self._cols, self.n_events, self.time_unit, self._rows)
            return
        done = 0
        step = max(1, self.block_bytes // 16)
        try:
            for block in npy_stream.lockstep(self._members(), step):
                done += len(block["t"])
                self.fraction_read = done / max(1, self.n_events)
                yield to_events(self, block["t"], block["x"], block["y"], block["p"], self.time_unit)
        except ValueError as e:
            if isinstance(e, EventError):
                raise
            raise self.error(f"unreadable NumPy file: {e}") from None


class _Npz:
    """The `.npy` members of an `.npz`, each read bounded by what its bytes can hold (`npy_stream`)."""

    def __init__(self, path: str):
        self.path = path
        with zipfile.ZipFile(path) as z:
            self._infos = {i.filename[:-4]: i for i in z.infolist() if i.filename.endswith(".npy")}
        self.files = list(self._infos)

    def member(self, name: str) -> npy_stream.Member:
        return npy_stream.Member(self.path, self._infos[name], os.path.getsize(self.path))

    def get(self, name: str, limit: int | None = None) -> np.ndarray:
        return self.member(name).read(limit=self._infos[name].file_size if limit is None else limit)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.get(name)


def open(path, **options) -> NumpySource:  # noqa: A001 - the format-module interface
    return NumpySource(path, **options)
