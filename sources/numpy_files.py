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
import zipfile
from collections.abc import Iterator

import numpy as np

from evstream.events import EventError, Geometry

from ._base import Block, FileSource, find_fields, fit_geometry, guess_columns, guess_time_unit

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
                self._npz = np.load(self.path, allow_pickle=False)
                self._cols = self._from_npz(self._npz, columns)
        except EventError:
            raise
        except Exception as e:  # numpy reports a corrupt header as anything from EOFError to SyntaxError
            raise self.error(f"unreadable NumPy file: {type(e).__name__}: {e}") from None
        n = len(self._cols["t"])
        if any(len(a) != n for a in self._cols.values()):
            raise self.error(f"arrays differ in length: { {k: len(a) for k, a in self._cols.items()} }")
        self.n_events = n
        self.time_unit = time_unit or guess_time_unit(self._cols["t"])
        if self.geometry is None:
            mx = my = 0
            step = 1 << 22
            for a in range(0, n, step):
                mx = max(mx, int(np.max(self._cols["x"][a : a + step])))
                my = max(my, int(np.max(self._cols["y"][a : a + step])))
            self.set_geometry(fit_geometry(mx, my), "fitted to the events (the file has no size)")
        self.details = {"events": n, "time_unit": self.time_unit}

    def _load_npy(self) -> np.ndarray:
        """The .npy memory-mapped; a file shorter than its header promises (np.load said only "mmap
        length is greater than file size") keeps its whole rows, with a warning naming the byte."""
        with builtins.open(self.path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version not in ((1, 0), (2, 0)):  # 3.0 (UTF-8 field names): np.load's own checks
                return np.load(self.path, mmap_mode="r", allow_pickle=False)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read(f)
            start = f.tell()
        row_bytes = dtype.itemsize * int(np.prod(shape[1:], dtype=np.int64))
        want = start + row_bytes * (shape[0] if shape else 1)
        if self.file_size >= want or not shape or fortran or row_bytes == 0:
            return np.load(self.path, mmap_mode="r", allow_pickle=False)
        rows = (self.file_size - start) // row_bytes
        self.warn(f"truncated: the header promises {shape[0]} rows ({want} bytes) but the file ends at byte "
                  f"{self.file_size}; the {rows} whole rows before byte {start + rows * row_bytes} are kept")
        if rows == 0:
            return np.zeros((0, *shape[1:]), dtype)
        return np.memmap(self.path, dtype, "r", start, (rows, *shape[1:]))

    def _from_array(self, a: np.ndarray, columns: str) -> dict:
        if a.dtype.names:
            f = find_fields(a.dtype.names)
            if f is None:
                raise self.error(f"structured array lacks t/x/y/p fields; has {list(a.dtype.names)}")
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
            if "width" in z.files and "height" in z.files:
                self.set_geometry(Geometry(int(z["width"]), int(z["height"])), "file (width/height)")
            elif "sensor_size" in z.files:
                s = np.asarray(z["sensor_size"]).ravel()
                self.set_geometry(Geometry(int(s[0]), int(s[1])), "file (sensor_size)")
            return {k: z[v] for k, v in f.items()}
        if len(z.files) == 1:
            return self._from_array(z[z.files[0]], columns)
        raise self.error(f"no t/x/y/p arrays among {z.files}")

    def _blocks(self) -> Iterator[Block]:
        return self._column_blocks(self._cols, self.n_events, self.time_unit, self._rows)


def open(path, **options) -> NumpySource:  # noqa: A001 - the format-module interface
    return NumpySource(path, **options)
