"""HDF5 event files, read with h5py in slices (constant memory). Layouts found in the wild:

- `/events/{t,x,y,p}` datasets (and aliases: ts/xs/ys/ps, timestamp/polarity, ...), struct of arrays;
- the same datasets at the root;
- `/events` (or `/CD/events`, Prophesee's) as one compound dataset with t/x/y/p fields;
- `/events` as an N×4 array (column order guessed from the first rows; `columns=` overrides);
- a group or dataset called `events` deeper down (MVSEC's `/davis/left/events`, x y t p);
- a `t_offset` dataset or attribute (DSEC) is added to the timestamps.

Sensor size from `width`/`height` (or `sensor_size`, `sensor_resolution`) attributes on the file, the
group or the dataset, else fitted to the events (one pass). Integer timestamps are µs, floating ones
seconds (a `t_unit` attribute or `time_unit=` overrides). Prophesee's own HDF5 files compress with the
ECF filter: without that plugin installed, reading fails with a clear error.
"""

from __future__ import annotations

import builtins
import re
from collections.abc import Iterator

import numpy as np

from evstream.events import EventError, Geometry, counted

from ._base import Block, FileSource, find_fields, fit_geometry, guess_columns, guess_time_unit, to_events

NAME = "HDF5 (/events/{t,x,y,p} and variants)"
FORMAT = "hdf5"
MAGIC = b"\x89HDF\r\n\x1a\n"
_H5_ERRORS = (OSError, RuntimeError, KeyError, ValueError, TypeError, IndexError)


def probe(head: bytes, path: str) -> bool:
    return head.startswith(MAGIC)


def _h5py():
    try:
        import h5py
    except ImportError:  # pragma: no cover - h5py is a dependency
        raise ImportError("reading HDF5 needs h5py: pip install h5py") from None
    return h5py


class Hdf5Source(FileSource):
    """Replays an HDF5 event file; timestamps must rise (policy 'error' by default)."""

    format = FORMAT

    def __init__(self, path, columns: str | None = None, time_unit: str | None = None, **options):
        super().__init__(path, **options)
        h5py = _h5py()
        try:
            self._file = h5py.File(self.path, "r")
            self._layout, self._where, attrs_from = self._find(self._file, columns)
            t = self._col("t", 0, 1)
            unit_attr = next((str(o.attrs[k]) for o in attrs_from for k in ("t_unit", "time_unit")
                              if k in o.attrs), None)
        except EventError:
            raise
        except _H5_ERRORS as e:  # h5py reports corruption as any of these
            cut = re.search(r"truncated file: eof = (\d+), sblock->base_addr = \d+, stored_eof = (\d+)", str(e))
            if cut:  # the superblock records the file's length: say it as the other readers do
                raise self.error(f"truncated: the file ends at byte {cut[1]}, its superblock says it is "
                                 f"{counted(int(cut[2]), 'byte')} long") from None
            raise self.error(f"unreadable HDF5 file: {type(e).__name__}: {e}") from None
        self.time_unit = time_unit or (unit_attr.replace("µs", "us") if unit_attr else guess_time_unit(t))
        self.t_offset_us = self._t_offset(attrs_from)
        for obj in attrs_from:
            try:
                g = _attr_geometry(obj.attrs)
            except _H5_ERRORS:
                g = None
            if g is not None:
                self.set_geometry(g, f"attributes of {obj.name}")
                break
        if self.geometry is None:
            mx = my = 0
            for b in self._blocks():
                if len(b):
                    mx, my = max(mx, int(b.x.max())), max(my, int(b.y.max()))
            self.set_geometry(fit_geometry(mx, my), "fitted to the events (no size attributes)")
        self.details = {"layout": self._layout, "events": self.n_events, "time_unit": self.time_unit,
                        "t_offset_us": self.t_offset_us}

    def _find(self, f, columns):
        h5py = _h5py()
        deeper = []
        f.visit(lambda name: deeper.append(name) if name.lower().rsplit("/", 1)[-1] == "events"
                and len(deeper) < 16 else None)
        for name in ("events", "CD/events", "cd/events", *deeper):
            obj = f.get(name)
            if isinstance(obj, h5py.Group):
                fields = find_fields([k for k, v in obj.items() if isinstance(v, h5py.Dataset)])
                if fields:
                    self._set({k: obj[v] for k, v in fields.items()})
                    return f"/{name}/{{t,x,y,p}}", obj, [obj, obj.parent, f]
            elif isinstance(obj, h5py.Dataset):
                if obj.dtype.names:
                    fields = find_fields(obj.dtype.names)
                    if fields is None:
                        raise self.error(f"dataset /{name} has fields {list(obj.dtype.names)}, not t/x/y/p")
                    self._set({k: (obj, v) for k, v in fields.items()})
                    return f"/{name} (compound)", obj, [obj, obj.parent, f]
                if obj.ndim == 2 and 4 in obj.shape:
                    if obj.shape[1] != 4:
                        raise self.error(f"dataset /{name} is 4×N; only N×4 is read")
                    columns = columns or guess_columns(obj[:1000])
                    self._set({k: (obj, i) for i, k in enumerate(columns)})
                    return f"/{name} (N×4, {columns})", obj, [obj, obj.parent, f]
        fields = find_fields([k for k, v in f.items() if isinstance(v, h5py.Dataset)])
        if fields:
            self._set({k: f[v] for k, v in fields.items()})
            return "/{t,x,y,p}", f, [f]
        raise self.error(f"no event datasets found (looked for /events/{{t,x,y,p}}, /events, /CD/events, "
                         f"/{{t,x,y,p}}); the file has {list(f.keys())}")

    def _t_offset(self, attrs_from) -> int:
        """DSEC keeps event time relative to a `t_offset` (µs) dataset beside the events."""
        try:
            ds = self._file.get("t_offset")
            if ds is not None and ds.shape in ((), (1,)):
                return int(np.asarray(ds[()]).ravel()[0])
            for obj in attrs_from:
                if "t_offset" in obj.attrs:
                    return int(np.asarray(obj.attrs["t_offset"]).ravel()[0])
        except (*_H5_ERRORS, AttributeError):
            return 0
        return 0

    def _set(self, cols: dict) -> None:
        self._cols = cols
        lengths = {k: (c[0].shape[0] if isinstance(c, tuple) else c.shape[0]) for k, c in cols.items()}
        if len(set(lengths.values())) != 1:
            raise self.error(f"event datasets differ in length: {lengths}")
        self.n_events = lengths["t"]

    def _col(self, key: str, a: int, b: int) -> np.ndarray:
        c = self._cols[key]
        try:
            if isinstance(c, tuple):
                ds, field = c
                return ds[a:b, field] if isinstance(field, int) else ds.fields(field)[a:b]
            return c[a:b]
        except _H5_ERRORS as e:
            ds = c[0] if isinstance(c, tuple) else c
            missing = _missing_filters(ds)
            if missing:  # Prophesee's ECF codec, or another plugin this HDF5 library lacks
                raise self.error(f"cannot read events {a}..{b} of {ds.name}: it is compressed with "
                                 f"{', '.join(missing)}, which this HDF5 library lacks (Prophesee HDF5 needs "
                                 f"its ECF filter plugin: pip install hdf5plugin, or convert with Metavision)"
                                 ) from None
            where = _bad_chunk(ds, a, b)  # every filter is there: the stored data is damaged
            if where is None:
                raise self.error(f"cannot read events {a}..{b} of {ds.name}: {e}") from None
            (lo, hi), offset = where
            raise self.error(f"corrupt compressed data in {ds.name}: the chunk of events {lo}..{hi} does "
                             f"not decompress ({e})", offset=offset) from None

    def _blocks(self) -> Iterator[Block]:
        step = max(1, self.block_bytes // 16)
        for a in range(0, self.n_events, step):
            b = min(a + step, self.n_events)
            block = to_events(self, *(self._col(k, a, b) for k in "txyp"), self.time_unit)
            self.fraction_read = b / self.n_events
            if self.t_offset_us:
                block.t += self.t_offset_us
            yield block


def _attr_geometry(attrs) -> Geometry | None:
    try:
        if "width" in attrs and "height" in attrs:
            return Geometry(int(attrs["width"]), int(attrs["height"]))
        for key in ("sensor_size", "sensor_resolution", "resolution"):
            if key in attrs:
                s = np.asarray(attrs[key]).ravel()
                return Geometry(int(s[0]), int(s[1]))
    except (ValueError, IndexError, TypeError):
        return None
    return None


def open(path, **options) -> Hdf5Source:  # noqa: A001 - the format-module interface
    return Hdf5Source(path, **options)


CHUNK_ROWS = 1 << 16  # events per HDF5 chunk of a written column (512 KB of timestamps before gzip)


def save(path, events, compression: str | None = "gzip") -> None:
    """Write a chunk as `/events/{t,x,y,p}` with width/height attributes (a `Writer` given one chunk)."""
    with Writer(path, events.geometry, compression=compression) as writer:
        writer.append(events)


class Writer:
    """HDF5 events written as they come: `/events/{t,x,y,p}` (resizable, chunked, gzip) grow by each chunk
    appended, and `width`/`height`/`t_unit` attributes on the file; memory holds a few HDF5 chunks, not
    the recording. `with Writer(path, geometry) as w: w.append(chunk)`; an error inside the block drops
    the file (the caller's AtomicOutput keeps what was there before).

    The HDF5 library writes through `_KeptErrorFile`: when the library itself meets a write error (a full
    disk), h5py raises it from object finalizers and then dies by segfault (h5py 3.16, 5 of 5 runs); so
    no error reaches the library, and the first is raised here, in Python, as a plain OSError."""

    def __init__(self, path, geometry: Geometry | None = None, chunk_rows: int = CHUNK_ROWS,
                 compression: str | None = "gzip"):
        h5py = _h5py()
        self.path = path
        self.geometry = geometry
        self.events = 0
        self._raw = _KeptErrorFile(path)
        try:
            self._file = h5py.File(self._raw, "w")
            if geometry is not None:
                self._set_size(geometry)
            group = self._file.create_group("events")
            self._columns = {k: group.create_dataset(k, shape=(0,), maxshape=(None,), dtype=dtype,
                                                     chunks=(chunk_rows,), compression=compression)
                             for k, dtype in (("t", np.int64), ("x", np.uint16), ("y", np.uint16), ("p", np.uint8))}
        except BaseException:
            self.abort()
            raise
        self._check()

    def _set_size(self, geometry: Geometry) -> None:
        self._file.attrs["width"], self._file.attrs["height"] = geometry.width, geometry.height
        self._file.attrs["t_unit"] = "us"

    def append(self, chunk) -> None:
        """Add a chunk's events after those written so far."""
        if self.geometry is None:
            self.geometry = chunk.geometry
            self._set_size(chunk.geometry)
        n, end = self.events, self.events + len(chunk)
        if end > n:
            for k, column in self._columns.items():
                column.resize((end,))
                column[n:end] = getattr(chunk, k)
        self.events = end
        self._check()

    def close(self) -> None:
        """Finish the file (the library writes its last metadata); raises the first write error."""
        if self.geometry is None:
            self.abort()
            raise ValueError(f"{self.path}: no events and no geometry given")
        try:
            self._file.close()
        finally:
            self._raw.close()
        self._check()

    def abort(self) -> None:
        """Let go of the file without a word (an error already on its way): what is in it is not wanted."""
        try:
            if getattr(self, "_file", None) is not None:
                self._file.close()
        except Exception:  # the error on its way is the one to see
            pass
        self._raw.close()

    def _check(self) -> None:
        if self._raw.error is not None:
            raise self._raw.error

    def __enter__(self) -> Writer:
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if exc is None:
            self.close()
        else:
            self.abort()


class _KeptErrorFile:
    """The file h5py writes through (its Python-file driver calls seek, tell, read, write, truncate and
    flush), keeping every OS error from the HDF5 library: the first is kept in `error` for Python to raise;
    what is written after it is held in memory (the library only finishes its metadata then), so what the
    library reads back is what it wrote. Unbuffered: an error belongs to the write that made it."""

    def __init__(self, path):
        self._file = builtins.open(path, "w+b", buffering=0)
        self.error: OSError | None = None
        self._pos = self._end = 0
        self._held: list[tuple[int, bytes]] = []  # (offset, bytes) written after the error, in order

    def seek(self, offset: int, whence: int = 0) -> int:
        self._pos = offset if whence == 0 else self._pos + offset if whence == 1 else self._end + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def write(self, data) -> int:
        data = bytes(data)
        if self.error is None:
            try:
                self._file.seek(self._pos)
                view = memoryview(data)
                while view:
                    view = view[self._file.write(view):]
            except OSError as e:
                self.error = e
        if self.error is not None:
            self._held.append((self._pos, data))
        self._pos += len(data)
        self._end = max(self._end, self._pos)
        return len(data)

    def read(self, size: int = -1) -> bytes:
        size = self._end - self._pos if size < 0 else size
        data = bytearray()
        try:
            self._file.seek(self._pos)
            while len(data) < size:
                piece = self._file.read(size - len(data))
                if not piece:
                    break
                data += piece
        except OSError as e:
            self.error = self.error or e
        data += bytes(size - len(data))  # past what reached the disk: zeros, or what is held
        for at, piece in self._held:
            lo, hi = max(at, self._pos), min(at + len(piece), self._pos + size)
            if lo < hi:
                data[lo - self._pos:hi - self._pos] = piece[lo - at:hi - at]
        self._pos += size
        return bytes(data)

    def truncate(self, size: int | None = None) -> int:
        size = self._pos if size is None else size
        if self.error is None:
            try:
                self._file.truncate(size)
            except OSError as e:
                self.error = e
        self._end = size
        return size

    def flush(self) -> None:
        pass  # unbuffered

    def close(self) -> None:
        try:
            self._file.close()
        except OSError as e:
            self.error = self.error or e


def _missing_filters(ds) -> list[str]:
    """Names of the dataset's compression filters that this HDF5 library cannot run."""
    import h5py

    try:
        plist = ds.id.get_create_plist()
        filters = [plist.get_filter(i) for i in range(plist.get_nfilters())]
    except _H5_ERRORS:
        return []
    return [f"filter {code} ({name.decode(errors='replace') or 'unnamed'})" for code, _, _, name in filters
            if not h5py.h5z.filter_avail(code)]


def _bad_chunk(ds, a: int, b: int):
    """((first, end) event indices, byte offset) of the first chunk in rows a..b that does not read;
    None if the dataset is not chunked or every chunk reads (the error path only: reads chunk by chunk)."""
    rows = ds.chunks[0] if ds.chunks else 0
    if not rows:
        return None
    for lo in range(a - a % rows, b, rows):
        hi = min(lo + rows, ds.shape[0])
        try:
            ds[lo:hi]
        except _H5_ERRORS:
            try:
                offset = ds.id.get_chunk_info_by_coord((lo,) + (0,) * (ds.ndim - 1)).byte_offset
            except _H5_ERRORS:
                offset = None
            return (lo, hi), offset
    return None
