"""Prophesee/Chronocam DAT files ("Event2d" CD events): `% ` header lines, a type and a size byte,
then 8-byte events: uint32 t (µs, wraps at 2^32: unwrapped), uint32 packing x, y, p.

Version 2: x bits 0..13, y bits 14..27, p bits 28..31. Version 1: x bits 0..8, y bits 9..16, p bit 17.
faery refuses the N-CARS sample and evlib mis-detects it (SOURCES.md), so this reader is ours.
Sensor size from `% Width`/`% Height` or `% geometry` lines, else ATIS 304x240 (the DAT era's sensor).
"""

from __future__ import annotations

import builtins
from collections.abc import Iterator

import numpy as np

from evstream.events import Geometry, counted

from ._base import Block, FileSource, Unwrapper, as_geometry, check_fits, fit_geometry, iter_records, read_header_lines

NAME = "Prophesee DAT (Event2d)"
FORMAT = "dat"
_ATIS = Geometry(304, 240)


def probe(head: bytes, path: str) -> bool:
    if not head.startswith(b"% "):
        return False
    text = head[:2048].lower()
    return b"data file containing" in text or b"event2d" in text or (
        path.lower().endswith(".dat") and b"% version" in text)


class DatSource(FileSource):
    """Replays a DAT file; timestamp policy defaults to 'sort' (recorded camera clocks)."""

    format = FORMAT
    default_timestamps = "sort"

    def __init__(self, path, **options):
        super().__init__(path, **options)
        with builtins.open(self.path, "rb") as f:
            lines, off = read_header_lines(f, b"%")
            f.seek(off)
            ts = f.read(2)
        h = {}
        for line in lines:
            key, _, value = line[1:].strip().partition(" ")
            h[key.lower()] = value.strip()
        if len(ts) < 2:
            raise self.error("DAT header has no event type and size bytes (file ends in the header)", off)
        self.event_type, self.record_bytes = ts[0], ts[1]
        self.body_offset = off + 2
        if self.record_bytes != 8:
            raise self.error(f"DAT event size {counted(self.record_bytes, 'byte')} is not supported (8 is)", off + 1)
        try:  # "% Version " with no number is as wrong as "% Version two"
            self.version = int((h.get("version", "2").split() or [""])[0])
        except ValueError:
            raise self.error(f"DAT header version {h['version']!r} is not a number") from None
        if self.version not in (1, 2):
            raise self.error(f"DAT version {self.version} is not supported (1 and 2 are)")
        g, src = None, ""
        try:
            if "width" in h and "height" in h:
                g, src = Geometry(int(h["width"]), int(h["height"])), "header (width/height)"
            elif "geometry" in h:
                g, src = as_geometry(h["geometry"].split()[0]), "header (geometry)"
        except ValueError:
            g = None
        if g is None:
            g, src = _ATIS, "assumed (ATIS; no geometry in the header)"
            if self.file_size - self.body_offset <= 64 << 20:  # small file: make sure it fits
                mx, my = self._max_xy()
                if mx >= g.width or my >= g.height:
                    g, src = fit_geometry(mx, my), "fitted to the events (no geometry in the header)"
        self.set_geometry(g, src)
        self.details = {"version": self.version, "event_type": self.event_type,
                        "header": h, "body_offset": self.body_offset}

    def _unpack(self, raw: np.ndarray):
        w = raw.view("<u4").reshape(-1, 2)
        d = w[:, 1]
        if self.version == 2:
            return w[:, 0], d & 0x3FFF, (d >> 14) & 0x3FFF, d >> 28
        return w[:, 0], d & 0x1FF, (d >> 9) & 0xFF, (d >> 17) & 1

    def _max_xy(self) -> tuple[int, int]:
        mx = my = 0
        for raw, _ in iter_records(self, self.body_offset, 8, warn=False):
            _, x, y, _ = self._unpack(raw)
            mx, my = max(mx, int(x.max())), max(my, int(y.max()))
        return mx, my

    def _blocks(self) -> Iterator[Block]:
        unwrap = Unwrapper(32)
        for raw, pos in iter_records(self, self.body_offset, 8):
            t, x, y, p = self._unpack(raw)
            if p.max() > 1:
                i = int(np.argmax(p > 1))
                raise self.error(f"event {i} has polarity {p[i]}: not a CD event (corrupt file?)", pos + 8 * i)
            yield Block(unwrap(t), x.astype(np.uint16), y.astype(np.uint16), p.astype(np.uint8), pos,
                        pos + len(raw), 8)
        self.counters = {"clock_wraps": unwrap.wraps}


def save(path, events) -> None:
    """Write events as a version 2 DAT file (times below 2^32 µs; x, y below 16384), its sensor size in
    `% Width`/`% Height` lines: for tests and tools (evstream.aot)."""
    check_fits(path, events, 1 << 14, 32, "a DAT file")
    rec = np.empty((len(events), 2), "<u4")
    rec[:, 0] = events.t & 0xFFFFFFFF
    rec[:, 1] = events.x.astype(np.uint32) | (events.y.astype(np.uint32) << 14) | (events.p.astype(np.uint32) << 28)
    size = f"% Width {events.geometry.width}\n% Height {events.geometry.height}\n".encode()
    with builtins.open(path, "wb") as f:
        f.write(b"% Data file containing Event2d events.\n% Version 2\n" + size + bytes([0, 8]) + rec.tobytes())


def open(path, **options) -> DatSource:  # noqa: A001 - the format-module interface
    return DatSource(path, **options)
