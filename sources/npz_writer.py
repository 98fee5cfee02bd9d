"""Writing an `.npz` whose deflated members can be entered at block boundaries, for seeking; still an
ordinary `.npz` for numpy and every zip reader.

A member written with `block_rows` has its deflate stream fully flushed (Z_FULL_FLUSH) every
`block_rows` rows: the compressed stream is byte-aligned there and nothing after it refers back before
it, so a raw inflater can start at that byte. `add` returns, per block, the compressed byte where it
starts (within the member's data) and the CRC-32 of its uncompressed bytes (block 0's include the .npy
header), for the caller's index. A flush every 65,536 rows costs under 0.5 % of the compressed size.

The zip (local headers, central directory, ZIP64 records where a size or an offset needs them) is
written here: the standard library's zip writer compresses on its own and offers no flush point.
Compression is zlib-ng's deflate (level 6, ~4x faster than zlib's at the same size). Every member has
the same fixed date (1980-01-01), so the bytes depend on the arrays only.
"""

from __future__ import annotations

import io
import struct

import numpy as np
from zlib_ng import zlib_ng

ZIP64_LIMIT = 0xFFFFFFFF  # a size or offset from here on needs ZIP64 (a module value: tests lower it)
ZIP64_COUNT = 0xFFFF
LEVEL = 6
PIECE_BYTES = 1 << 22  # uncompressed bytes handed to the compressor at a time within a block
_DOS_DATE = (0 << 9) | (1 << 5) | 1  # 1980-01-01, the zip epoch
_DOS_TIME = 0


def npy_header(a: np.ndarray) -> bytes:
    """The .npy header numpy writes for `a` (version 1.0, or 2.0 when it needs more than 64 KiB)."""
    buf = io.BytesIO()
    d = np.lib.format.header_data_from_array_1_0(a)
    try:
        np.lib.format.write_array_header_1_0(buf, d)
    except ValueError:  # a header over 65,535 bytes
        buf = io.BytesIO()
        np.lib.format.write_array_header_2_0(buf, d)
    return buf.getvalue()


class NpzWriter:
    """Members added one by one to the open binary file `f` (seekable: each local header's CRC and sizes
    are filled in once its member is written); `close()` writes the central directory."""

    def __init__(self, f):
        self.f = f
        self.entries: list[tuple[bytes, int, int, int, int]] = []  # name, crc, csize, usize, header offset

    def add(self, name: str, a: np.ndarray, block_rows: int | None = None) -> tuple[list[int], list[int]]:
        """Write `a` as the deflated member `name`.npy; with `block_rows` (a 1-D array), a flush point
        every `block_rows` rows. Returns each block's (compressed start, CRC-32); one block without."""
        a = np.asarray(a)
        if not a.flags.c_contiguous:
            a = a.copy()  # C order (ascontiguousarray would turn a 0-d array into 1-d)
        if block_rows is not None and (a.ndim != 1 or block_rows <= 0):
            raise ValueError(f"{name}: blocks are rows of a 1-D array (shape {a.shape}, block_rows {block_rows})")
        fname = f"{name}.npy".encode()
        head = npy_header(a)
        data = memoryview(a.reshape(-1).view(np.uint8)) if a.size else memoryview(b"")
        step = len(data) if block_rows is None else block_rows * a.dtype.itemsize
        cuts = list(range(0, len(data), step)) if step else [0]
        if not cuts:
            cuts = [0]
        at = self.f.tell()
        local = self._local_header(fname, 0, 0, 0)
        self.f.write(local)
        comp = zlib_ng.compressobj(LEVEL, zlib_ng.DEFLATED, -15)
        csize = usize = crc = 0
        starts, crcs = [], []
        for k, cut in enumerate(cuts):
            block = [head] if k == 0 else []
            end = cut + step if k + 1 < len(cuts) else len(data)
            block += [data[i:min(i + PIECE_BYTES, end)] for i in range(cut, end, PIECE_BYTES)]
            starts.append(csize)
            block_crc = 0
            for piece in block:
                block_crc = zlib_ng.crc32(piece, block_crc)
                crc = zlib_ng.crc32(piece, crc)
                usize += len(piece)
                out = comp.compress(piece)
                self.f.write(out)
                csize += len(out)
            crcs.append(block_crc)
            out = comp.flush(zlib_ng.Z_FULL_FLUSH if k + 1 < len(cuts) else zlib_ng.Z_FINISH)
            self.f.write(out)
            csize += len(out)
        end_at = self.f.tell()
        self.f.seek(at)
        self.f.write(self._local_header(fname, crc, csize, usize))
        self.f.seek(end_at)
        self.entries.append((fname, crc, csize, usize, at))
        return starts, crcs

    @staticmethod
    def _local_header(fname: bytes, crc: int, csize: int, usize: int) -> bytes:
        # always with a ZIP64 extra field (as numpy writes members): sizes are known only afterwards
        extra = struct.pack("<HHQQ", 1, 16, usize, csize)
        return struct.pack("<4s5H3L2H", b"PK\x03\x04", 45, 0, 8, _DOS_TIME, _DOS_DATE, crc, 0xFFFFFFFF,
                           0xFFFFFFFF, len(fname), len(extra)) + fname + extra

    def close(self) -> None:
        cd_at = self.f.tell()
        for fname, crc, csize, usize, at in self.entries:
            big = [v for v in (usize, csize, at) if v >= ZIP64_LIMIT]
            extra = struct.pack(f"<HH{len(big)}Q", 1, 8 * len(big), *big) if big else b""
            self.f.write(struct.pack(
                "<4s6H3L5H2L", b"PK\x01\x02", 3 << 8 | 45, 45 if big else 20, 0, 8, _DOS_TIME, _DOS_DATE, crc,
                0xFFFFFFFF if csize >= ZIP64_LIMIT else csize, 0xFFFFFFFF if usize >= ZIP64_LIMIT else usize,
                len(fname), len(extra), 0, 0, 0, 0o644 << 16, 0xFFFFFFFF if at >= ZIP64_LIMIT else at)
                + fname + extra)
        cd_end = self.f.tell()
        n, size = len(self.entries), cd_end - cd_at
        if n >= ZIP64_COUNT or size >= ZIP64_LIMIT or cd_at >= ZIP64_LIMIT:  # ZIP64 end record and locator
            self.f.write(struct.pack("<4sQ2H2L4Q", b"PK\x06\x06", 44, 45, 45, 0, 0, n, n, size, cd_at))
            self.f.write(struct.pack("<4sLQL", b"PK\x06\x07", 0, cd_end, 1))
        self.f.write(struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, min(n, ZIP64_COUNT), min(n, ZIP64_COUNT),
                                 0xFFFFFFFF if size >= ZIP64_LIMIT else size,
                                 0xFFFFFFFF if cd_at >= ZIP64_LIMIT else cd_at, 0))
