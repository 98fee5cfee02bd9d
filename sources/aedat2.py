"""jAER AEDAT 2.0 files from a DVS128: `#` header lines (the first `#!AER-DAT2.0`), then big-endian
8-byte events: uint32 address, uint32 timestamp (µs, wraps at 2^32: unwrapped).

jAER's DVS128 address: polarity bit 0 (0 = ON), x bits 1..7 mirrored (x = 127 - field), y bits 8..14,
as SOURCES.md's checked snippet decodes it. Other AEDAT2 cameras (DAVIS) pack addresses differently:
`open(path, sensor=...)` names the only layout supported today, 'dvs128'.
"""

from __future__ import annotations

import builtins
from collections.abc import Iterator

import numpy as np

from evstream.events import Geometry

from ._base import Block, FileSource, Unwrapper, iter_records, read_header_lines

NAME = "AEDAT 2.0 (jAER DVS128)"
FORMAT = "aedat2"


def probe(head: bytes, path: str) -> bool:
    return head.startswith(b"#!AER-DAT2")


class Aedat2Source(FileSource):
    format = FORMAT
    default_timestamps = "sort"

    def __init__(self, path, sensor: str = "dvs128", **options):
        super().__init__(path, **options)
        if sensor != "dvs128":
            raise ValueError(f"sensor {sensor!r}: only 'dvs128' AEDAT2 addresses are supported")
        with builtins.open(self.path, "rb") as f:
            lines, self.body_offset = read_header_lines(f, b"#")
        if not lines or not lines[0].startswith("#!AER-DAT2"):
            raise self.error("not an AEDAT 2.0 file (first line is not '#!AER-DAT2.0')", 0)
        self.set_geometry(Geometry(128, 128), "sensor (DVS128)")
        self.details = {"header": lines[:20], "body_offset": self.body_offset}

    def _blocks(self) -> Iterator[Block]:
        unwrap = Unwrapper(32)
        for raw, pos in iter_records(self, self.body_offset, 8):
            w = raw.view(">u4").reshape(-1, 2).astype(np.uint32)  # native byte order for numba
            addr = w[:, 0]
            x = (127 - ((addr >> 1) & 127)).astype(np.uint16)
            y = ((addr >> 8) & 127).astype(np.uint16)
            p = (1 - (addr & 1)).astype(np.uint8)
            yield Block(unwrap(w[:, 1]), x, y, p, pos, pos + len(raw), 8)
        self.counters = {"clock_wraps": unwrap.wraps}


def open(path, **options) -> Aedat2Source:  # noqa: A001 - the format-module interface
    return Aedat2Source(path, **options)


def save(path, t_us: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> None:
    """Write DVS128 events as AEDAT 2.0 (jAER layout); for tests and interchange."""
    addr = ((127 - np.asarray(x, np.uint32)) << 1) | (np.asarray(y, np.uint32) << 8) | (
        1 - np.asarray(p, np.uint32))
    body = np.empty((len(addr), 2), ">u4")
    body[:, 0] = addr
    body[:, 1] = np.asarray(t_us, np.int64) & 0xFFFFFFFF
    with builtins.open(path, "wb") as f:
        f.write(b"#!AER-DAT2.0\r\n# This is a raw AE data file written by evstream\r\n")
        f.write(body.tobytes())
