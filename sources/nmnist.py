"""N-MNIST / N-Caltech101 / SLAYER `.bs2` binaries: no header, 5 bytes (40 bits) per event:
x (8 bits), y (8 bits), polarity (bit 7 of byte 2, 1 = ON), a 23-bit µs timestamp (unwrapped
where it wraps, every 8.4 s).

With no magic, the probe needs the extension (.bin, .bs2) and a plausible body (a whole number of
events, timestamps mostly rising). The files carry no sensor size: small files are scanned and get the
smallest known sensor that holds them (N-MNIST 34x34, DVS128, ATIS 304x240); pass `geometry=` to set it.
"""

from __future__ import annotations

from builtins import open as open_file
from collections.abc import Iterator

import numpy as np

from evstream.events import Geometry

from ._base import Block, FileSource, Unwrapper, check_fits, fit_geometry, iter_records

NAME = "N-MNIST binary (40-bit events)"
FORMAT = "nmnist"
_EXTENSIONS = (".bin", ".bs2")
_SCAN_LIMIT_BYTES = 256 << 20
# the sensors these datasets were recorded with: ATIS (N-MNIST's 34x34 crop, N-Caltech101), DVS128
_SENSORS = [Geometry(34, 34), Geometry(128, 128), Geometry(304, 240)]


def _unpack(raw: np.ndarray):
    r = raw.reshape(-1, 5)
    t = ((r[:, 2].astype(np.uint32) & 0x7F) << 16) | (r[:, 3].astype(np.uint32) << 8) | r[:, 4]
    return t, r[:, 0].astype(np.uint16), r[:, 1].astype(np.uint16), (r[:, 2] >> 7).astype(np.uint8)


def probe(head: bytes, path: str) -> bool:
    import os

    if not path.lower().endswith(_EXTENSIONS):
        return False
    if os.path.getsize(path) < 5:
        return False
    n = min(len(head) // 5, 400)
    if n < 2:
        return True
    t = _unpack(np.frombuffer(head[: 5 * n], np.uint8))[0].astype(np.int64)
    return np.count_nonzero(np.diff(t) < 0) <= max(1, n // 50)


class NmnistSource(FileSource):
    """Replays an N-MNIST-style binary; timestamps must rise (policy 'error' by default)."""

    format = FORMAT

    def __init__(self, path, **options):
        super().__init__(path, **options)
        if self.geometry is None:
            if self.file_size <= _SCAN_LIMIT_BYTES:
                mx = my = 0
                for raw, _ in iter_records(self, 0, 5, warn=False):
                    _, x, y, _ = _unpack(raw)
                    mx, my = max(mx, int(x.max())), max(my, int(y.max()))
                self.set_geometry(fit_geometry(mx, my, _SENSORS), "fitted to the events (the format has none)")
            else:
                self.set_geometry(fit_geometry(255, 255), "assumed (the format has none)")

    def _blocks(self) -> Iterator[Block]:
        unwrap = Unwrapper(23)
        for raw, pos in iter_records(self, 0, 5):
            t, x, y, p = _unpack(raw)
            yield Block(unwrap(t), x, y, p, pos, pos + len(raw), 5)
        self.counters = {"clock_wraps": unwrap.wraps}


def save(path, events) -> None:
    """Write events as an N-MNIST binary (x, y below 256; times below 2^23 µs): for tests and tools
    (evstream.aot)."""
    check_fits(path, events, 256, 23, "an N-MNIST binary")
    r = np.zeros((len(events), 5), np.uint8)
    t = events.t.astype(np.uint32)
    r[:, 0], r[:, 1] = events.x, events.y
    r[:, 2] = (events.p.astype(np.uint8) << 7) | ((t >> 16) & 0x7F)
    r[:, 3], r[:, 4] = (t >> 8) & 0xFF, t & 0xFF
    with open_file(path, "wb") as f:
        f.write(r.tobytes())


def open(path, **options) -> NmnistSource:  # noqa: A001 - the format-module interface
    return NmnistSource(path, **options)
