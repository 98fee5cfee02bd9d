"""Text files: one event per line, numbers separated by spaces, tabs or commas (the Event Camera
Dataset's `t x y p`, t in seconds; CSV; other column orders are recognised). Read in blocks at
constant memory.

Detected: `#`/`%` comment lines; an optional first line of two integers (`width height`) or of the
four column names (`t,x,y,p`, `timestamp x y polarity`, ...: they give the column order); the time
unit (a decimal point in the time column means seconds, else µs; `time_unit=` overrides); polarity
as 0/1 or -1/+1; the column order from the first lines (the rising column is t, the one of ±1/0 is
p, x and y in that order; `columns=`, e.g. 'xytp', overrides). Without a size line, files up
to 256 MB are scanned for the sensor size (smallest known sensor that holds the events).
"""

from __future__ import annotations

import builtins
import re
from collections.abc import Iterator

import numpy as np

from evstream.events import Geometry
from evstream.jit import njit

from ._base import Block, FileSource, find_fields, fit_geometry, guess_columns, to_events

NAME = "text (t x y p per line)"
FORMAT = "text"
_NUM = rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_SCAN_LIMIT_BYTES = 256 << 20


_POW10 = np.array([10.0**k for k in range(-40, 41)])


@njit(cache=True, nogil=True)
def _number(buf, i, n):
    """Parse a decimal number at buf[i:] (sign, digits, '.', digits, exponent); (value, end, ok)."""
    neg = False
    if i < n and (buf[i] == 45 or buf[i] == 43):  # '-' '+'
        neg = buf[i] == 45
        i += 1
    mant = np.int64(0)
    digits = 0  # significant digits kept in `mant` (18 fit an int64); leading zeros do not use them up
    seen = False
    scale = 0
    while i < n and 48 <= buf[i] <= 57:
        seen = True
        if digits < 18:
            mant = mant * 10 + (buf[i] - 48)
            digits += mant > 0
        else:
            scale += 1
        i += 1
    if i < n and buf[i] == 46:  # '.'
        i += 1
        while i < n and 48 <= buf[i] <= 57:
            seen = True
            if digits < 18:
                mant = mant * 10 + (buf[i] - 48)
                digits += mant > 0
                scale -= 1
            i += 1
    if not seen:
        return 0.0, i, False
    if i < n and (buf[i] == 101 or buf[i] == 69):  # 'e' 'E'
        i += 1
        eneg = False
        if i < n and (buf[i] == 45 or buf[i] == 43):
            eneg = buf[i] == 45
            i += 1
        e = 0
        ed = 0
        while i < n and 48 <= buf[i] <= 57:
            e = min(e * 10 + (buf[i] - 48), 1000)
            ed += 1
            i += 1
        if ed == 0:
            return 0.0, i, False
        scale += -e if eneg else e
    if scale < -40 or scale > 40:  # rare: tiny or huge values, one rounding more
        v = mant * 10.0**scale
    else:
        v = mant / _POW10[40 - scale] if scale < 0 else mant * _POW10[40 + scale]
    return (-v if neg else v), i, True


@njit(cache=True, nogil=True)
def _parse_kernel(buf, out):
    """Lines of 4 numbers (space, tab or comma separated) into `out` rows; blank and #, %, // comment
    lines skipped. Returns (rows, byte offset of the first bad line or -1)."""
    n = len(buf)
    i = 0
    rows = 0
    while i < n:
        start = i
        while i < n and (buf[i] == 32 or buf[i] == 9):
            i += 1
        if i >= n:
            break
        c = buf[i]
        if c == 10 or c == 13 or c == 35 or c == 37 or (c == 47 and i + 1 < n and buf[i + 1] == 47):
            while i < n and buf[i] != 10:  # blank or comment line
                i += 1
            i += 1
            continue
        for col in range(4):
            sep = i
            while i < n and (buf[i] == 32 or buf[i] == 9 or (col > 0 and buf[i] == 44)):
                i += 1
            if col > 0 and i == sep:  # numbers need a separator between them
                return rows, start
            v, i, ok = _number(buf, i, n)
            if not ok:
                return rows, start
            out[rows, col] = v
        while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 13):
            i += 1
        if i < n and buf[i] != 10:
            return rows, start
        i += 1
        rows += 1
    return rows, -1


def _data_lines(head: bytes) -> list[bytes]:
    lines = [ln.strip() for ln in head.split(b"\n")[:-1]]  # the last may be cut
    return [ln for ln in lines if ln and not ln.startswith((b"#", b"%", b"//"))]


def _fields(line: bytes) -> list[bytes]:
    """A line's fields, separated as the parser separates them: spaces, tabs or commas (CSV)."""
    return [f for f in re.split(rb"[ \t,]+", line.strip()) if f]


def _column_names(line: bytes) -> str | None:
    """The column order a header line of four names gives ('t,x,y,p', 'x y polarity timestamp'), or None."""
    names = [f.decode("ascii", "replace") for f in _fields(line)]
    if len(names) != 4 or not all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", n) for n in names):
        return None
    f = find_fields(names)
    if f is None or len(set(f.values())) != 4:
        return None
    return "".join(next(k for k, v in f.items() if v == n) for n in names)


def probe(head: bytes, path: str) -> bool:
    if b"\x00" in head:
        return False
    lines = _data_lines(head)[:20]
    if not lines:
        return False
    if re.fullmatch(rb"\d+\s+\d+", lines[0]) or _column_names(lines[0]):
        lines = lines[1:]
    ok = [len(_fields(ln)) == 4 and all(re.fullmatch(_NUM, f) for f in _fields(ln)) for ln in lines]
    # a text file of events: the first line and most of the rest are 4 numbers (a bad line further
    # on is the reader's to report, by byte offset)
    return bool(lines) and ok[0] and sum(ok) >= len(ok) - max(1, len(ok) // 5)


class TextSource(FileSource):
    """Replays a text file; timestamps must rise (policy 'error' by default)."""

    format = FORMAT

    def __init__(self, path, columns: str | None = None, time_unit: str | None = None, **options):
        super().__init__(path, **options)
        if columns is not None and sorted(columns) != sorted("txyp"):
            raise ValueError(f"columns {columns!r}: a permutation of 'txyp'")
        with builtins.open(self.path, "rb") as f:
            head = f.read(1 << 16)
        lines = _data_lines(head + (b"\n" if len(head) < 1 << 16 else b""))
        if not lines:
            raise self.error("no event lines in the first 64 KiB")
        self.body_offset = 0
        m = re.fullmatch(rb"(\d+)\s+(\d+)", lines[0])
        named = _column_names(lines[0])
        self._skip_first_data_line = None  # the pattern of a header line before the first event
        if m:
            self.set_geometry(Geometry(int(m[1]), int(m[2])), "header line (width height)")
            self._skip_first_data_line = _SIZE_LINE
            lines = lines[1:]
        elif named:
            columns = columns or named  # the names say the order: no guessing from the values
            self._skip_first_data_line = _NAMES_LINE
            lines = lines[1:]
            if not lines:
                raise self.error("no event lines in the first 64 KiB")
        if columns is None:  # from the first lines: the rising column is t, the ±1/0 one p
            sample = np.empty((len(lines), 4))
            rows, _ = _parse_kernel(np.frombuffer(b"\n".join(lines[:1000]) + b"\n", np.uint8), sample)
            columns = guess_columns(sample[:rows], "txyp")
        self.columns = columns
        tcol = columns.index("t")
        if time_unit is None:
            time_unit = "s" if lines and b"." in _fields(lines[0])[tcol] else "us"
        self.time_unit = time_unit
        if self.geometry is None:
            if self.file_size <= _SCAN_LIMIT_BYTES:
                mx = my = 0
                for b in self._blocks():
                    if len(b):
                        mx, my = max(mx, int(b.x.max())), max(my, int(b.y.max()))
                self.set_geometry(fit_geometry(mx, my), "fitted to the events (no size line)")
            else:
                b = next(iter(self._blocks()))
                self.set_geometry(fit_geometry(int(b.x.max()), int(b.y.max())),
                                  "fitted to the first block (no size line; pass geometry=)")
        self.details = {"time_unit": self.time_unit, "columns": self.columns}

    def _parse(self, block: bytes, pos: int) -> Block:
        buf = np.frombuffer(block, np.uint8)
        out = np.empty((block.count(b"\n") + 1, 4), np.float64)
        rows, bad = _parse_kernel(buf, out)
        if bad >= 0:
            end = block.find(b"\n", bad)
            line = block[bad : end if end >= 0 else len(block)].rstrip(b"\r")
            raise self.error(f"line {line[:60]!r} is not 4 numbers", pos + bad)
        cols = out[:rows].T
        c = {k: cols[i] for i, k in enumerate(self.columns)}
        return to_events(self, c["t"], c["x"], c["y"], c["p"], self.time_unit, pos, pos + len(block))

    def _blocks(self) -> Iterator[Block]:
        pos = 0
        rest = b""
        skip = self._skip_first_data_line
        with builtins.open(self.path, "rb") as f:
            while True:
                data = f.read(self.block_bytes)
                buf = rest + data
                if not data:
                    if buf.strip():
                        yield self._parse(buf + b"\n", pos)
                    break
                cut = buf.rfind(b"\n") + 1
                block, rest = buf[:cut], buf[cut:]
                if skip:
                    # drop comment lines and the `width height` or column-names line before the first event
                    m = skip.match(block)
                    if m:
                        pos += m.end()
                        block = block[m.end():]
                        skip = None
                if block:
                    yield self._parse(block, pos)
                pos += len(block)


_LEAD = rb"(?:\s*(?:#|%|//)[^\n]*\n|\s*\n)*\s*"  # comment and blank lines
_SIZE_LINE = re.compile(_LEAD + rb"\d+[ \t]+\d+[ \t]*\r?\n")
_NAMES_LINE = re.compile(_LEAD + rb"[A-Za-z_][A-Za-z0-9_]*(?:[ \t,]+[A-Za-z_][A-Za-z0-9_]*){3}[ \t,]*\r?\n")


def open(path, **options) -> TextSource:  # noqa: A001 - the format-module interface
    return TextSource(path, **options)


def save(path, events, time_unit: str = "s") -> None:
    """Write a chunk as `t x y p` lines (t in seconds with 6 decimals, or integer µs)."""
    with builtins.open(path, "w") as f:
        if time_unit == "s":
            for t, x, y, p in zip(events.t / 1e6, events.x, events.y, events.p):
                f.write(f"{t:.6f} {x} {y} {p}\n")
        else:
            for t, x, y, p in zip(events.t, events.x, events.y, events.p):
                f.write(f"{t} {x} {y} {p}\n")
