""".npy data read in bounded memory: the header parsed by us (one-line errors, no 10,000-byte limit of
numpy's, no pickle), and `.npz` members streamed — a stored member straight from its bytes in the file,
a deflated one through an incremental inflater — so memory does not grow with the recording, and what a
reader allocates is bounded by what the file can hold.

A member's claims are checked before anything is allocated: its header's shape must match the bytes the
zip says it holds, and a deflated member may not claim more than `MAX_DEFLATE_RATIO` times its
compressed size (deflate cannot do better than 1032:1; a larger claim is a lie or a bomb). The CRC is
checked as the bytes stream by, and the error names the member's bytes in the file.
"""

from __future__ import annotations

import ast
import builtins
import math
import struct
import zipfile
from collections.abc import Iterator

import numpy as np
from zlib_ng import zlib_ng

from evstream.events import counted

MAX_HEADER_BYTES = 1 << 20  # npy 2.0/3.0 headers; 1.0 headers stop at 65,535 bytes by format
MAX_DEFLATE_RATIO = 1032  # deflate's best case (runs of one byte): more is not a deflate stream
READ_BYTES = 1 << 18  # compressed bytes handed to the inflater at a time
SMALL_MEMBER_BYTES = 64 << 20  # a member read whole (width, height, meta): at most this


def parse_header(head: bytes) -> tuple[tuple[int, ...], bool, np.dtype, int]:
    """(shape, fortran_order, dtype, byte where the data starts) from the first bytes of an .npy.
    ValueError with a one-line reason for anything numpy would refuse, and for Python objects."""
    if head[:6] != b"\x93NUMPY":
        raise ValueError("not an .npy array (no \\x93NUMPY magic)")
    if len(head) < 10:
        raise ValueError("cut short in its .npy header")
    major, minor = head[6], head[7]
    if major == 1:
        size, start = struct.unpack("<H", head[8:10])[0], 10
    elif major in (2, 3):
        if len(head) < 12:
            raise ValueError("cut short in its .npy header")
        size, start = struct.unpack("<I", head[8:12])[0], 12
    else:
        raise ValueError(f".npy format version {major}.{minor} is unknown (1.0, 2.0 and 3.0 are)")
    if size > MAX_HEADER_BYTES:
        raise ValueError(f".npy header of {size} bytes: more than any array needs ({MAX_HEADER_BYTES})")
    if len(head) < start + size:
        raise ValueError(f"cut short in its .npy header ({counted(size, 'byte')} from byte {start})")
    try:
        text = head[start:start + size].decode("utf-8" if major == 3 else "latin-1")
        d = ast.literal_eval(text)
    except (ValueError, SyntaxError, UnicodeDecodeError, MemoryError, RecursionError, TypeError):
        raise ValueError(".npy header is not a Python literal (damaged)") from None
    if not isinstance(d, dict) or set(d) != {"descr", "fortran_order", "shape"}:
        raise ValueError(".npy header lacks its keys descr, fortran_order, shape (damaged)")
    shape, fortran = d["shape"], d["fortran_order"]
    if (not isinstance(shape, tuple) or not all(isinstance(n, int) and n >= 0 for n in shape)
            or not isinstance(fortran, bool)):
        raise ValueError(f".npy header: shape {shape!r}, fortran_order {fortran!r} (damaged)")
    try:
        dtype = np.lib.format.descr_to_dtype(d["descr"])
    except Exception:  # numpy raises anything from TypeError to ValueError on a bad descr
        raise ValueError(f".npy header: dtype {str(d['descr'])[:60]!r} is not a NumPy dtype (damaged)") from None
    if dtype.hasobject:
        raise ValueError("it holds Python objects, which are not unpickled")
    if dtype.itemsize == 0 and math.prod(shape):
        raise ValueError(f".npy header: dtype {dtype} has no size")
    return shape, fortran, dtype, start + size


class Member:
    """One `.npy` member of a zip, its header read and checked; `read()` whole (small members), `blocks()`
    in pieces of rows. `where` is the member's data in the file, for errors."""

    def __init__(self, path: str, info: zipfile.ZipInfo, file_size: int):
        self.path = path
        self.info = info
        self.name = info.filename
        self.array = info.filename.removesuffix(".npy")
        try:
            self._open(file_size)
        except ValueError as e:
            raise ValueError(f"array {self.array!r}: {e}") from None

    def _open(self, file_size: int) -> None:
        info = self.info
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise ValueError(f"zip compression method {info.compress_type} (numpy writes stored or deflated)")
        if not 0 <= info.header_offset <= file_size - 30:
            raise ValueError(f"its local zip header at byte {info.header_offset} lies outside the file "
                             f"({counted(file_size, 'byte')})")
        with builtins.open(self.path, "rb") as f:
            f.seek(info.header_offset)
            local = f.read(30)
            if len(local) < 30 or local[:4] != b"PK\x03\x04":
                raise ValueError(f"no local zip header at byte {info.header_offset}")
        self.start = info.header_offset + 30 + sum(struct.unpack("<HH", local[26:30]))
        self.where = f"bytes {self.start}..{self.start + info.compress_size}"
        if self.start + info.compress_size > file_size:
            raise ValueError(f"cut short at byte {file_size} (it ends at byte {self.start + info.compress_size})")
        if info.compress_type == zipfile.ZIP_STORED and info.file_size != info.compress_size:
            raise ValueError(f"{self.where}: a stored member of {counted(info.compress_size, 'byte')} "
                             f"claims {info.file_size}")
        if info.compress_type == zipfile.ZIP_DEFLATED and info.file_size > MAX_DEFLATE_RATIO * max(
                info.compress_size, 1) + 64:
            raise ValueError(f"{self.where}: {counted(info.compress_size, 'compressed byte')} claim "
                             f"{counted(info.file_size, 'byte')}, "
                             f"more than deflate can pack ({MAX_DEFLATE_RATIO}:1): damaged, or a zip bomb")
        stream = _MemberBytes(self.path, self.start, info, f"array {self.array!r}: ")
        head = stream.read(min(info.file_size, 12))  # the header and no more: a seek inflates nothing else
        need = len(head)
        if head[6:7] == b"\x01" and len(head) >= 10:
            need = 10 + struct.unpack("<H", head[8:10])[0]
        elif head[6:7] in (b"\x02", b"\x03") and len(head) >= 12:  # a long 2.0/3.0 header
            need = 12 + struct.unpack("<I", head[8:12])[0]
        if len(head) < need <= MAX_HEADER_BYTES + 12:
            head += stream.read(need - len(head))
        self.shape, self.fortran, self.dtype, self.offset = parse_header(head)
        self.count = math.prod(self.shape)
        if self.offset + self.count * self.dtype.itemsize != info.file_size:
            raise ValueError(f"its header says {self.shape} of {self.dtype}, its data is "
                             f"{counted(info.file_size - self.offset, 'byte')}")
        self._stream = stream
        self._file = stream.f
        self._head = head[self.offset:]  # data bytes already read

    @property
    def rows(self) -> int:
        return self.shape[0] if self.shape else 1

    def close(self) -> None:
        """Close the file of a member not read to its end (only its header looked at, or a stream left early)."""
        self._file.close()  # reading it again raises "read twice"; closing twice is nothing
        self._stream = None

    def skip_to_block(self, row: int, at: int, crcs, block_rows: int) -> None:
        """Read the data from row `row` on, a block start: the member's compressed bytes from `at`, a flush
        point of its deflate stream (`npz_writer`), each block of `block_rows` rows from there checked
        against its CRC-32 in `crcs` (the member's own CRC covers the bytes skipped too)."""
        if self._stream is None:
            raise RuntimeError(f"{self.name}: read twice")
        if self.info.compress_type != zipfile.ZIP_DEFLATED or self.fortran or not self.shape:
            raise ValueError(f"array {self.array!r}: not a deflated array of rows: no block to start at")
        row_bytes = self.dtype.itemsize * math.prod(self.shape[1:])
        if not 0 < row < self.rows or not 0 < at < self.info.compress_size:
            raise ValueError(f"array {self.array!r}: {self.where}: no block at row {row}, byte {at}")
        self._file.close()
        self._stream = _MemberBytes(self.path, self.start, self.info, f"array {self.array!r}: ",
                                    skip=(at, self.offset + row * row_bytes),
                                    block_crcs=(block_rows * row_bytes, [int(c) for c in crcs]))
        self._file = self._stream.f
        self._head = b""

    def _data(self) -> Iterator[bytes]:
        """The data bytes, once, in pieces (from where the header ended)."""
        if self._stream is None:
            raise RuntimeError(f"{self.name}: read twice")
        stream, head = self._stream, self._head
        self._stream = None
        if head:
            yield head
        while True:
            piece = stream.read(READ_BYTES)
            if not piece:
                stream.finish()
                return
            yield piece

    def read(self, limit: int = SMALL_MEMBER_BYTES) -> np.ndarray:
        """The whole member as a writable array (at most `limit` bytes of data)."""
        nbytes = self.count * self.dtype.itemsize
        if nbytes > limit:
            raise ValueError(f"array {self.array!r}: {self.where}: {nbytes} bytes is more than it needs")
        data = bytearray(nbytes)
        at = 0
        for piece in self._data():
            data[at:at + len(piece)] = piece
            at += len(piece)
        a = np.frombuffer(data, self.dtype, self.count)
        return a.reshape(self.shape, order="F" if self.fortran else "C")

    def blocks(self, rows: int) -> Iterator[np.ndarray]:
        """The member's rows (axis 0), `rows` at a time, in order; C order only (Fortran-ordered arrays of
        more than one dimension are read whole, as `read` does, bounded by what the file holds)."""
        if self.fortran and len(self.shape) > 1:
            yield self.read(limit=self.info.file_size)
            return
        row_shape = self.shape[1:]
        row_bytes = self.dtype.itemsize * math.prod(row_shape)
        if row_bytes == 0 or not self.shape:
            yield self.read(limit=self.info.file_size)
            return
        want = rows * row_bytes
        buf = bytearray()
        for piece in self._data():
            buf += piece
            while len(buf) >= want:
                yield np.frombuffer(bytes(buf[:want]), self.dtype).reshape((rows, *row_shape))
                del buf[:want]
        if buf:
            yield np.frombuffer(bytes(buf), self.dtype).reshape((len(buf) // row_bytes, *row_shape))


class _MemberBytes:
    """A member's uncompressed bytes as a stream, its CRC and size checked at the end (`finish`).

    `skip` = (compressed, uncompressed) bytes to start after: a flush point of a deflated member, whose
    blocks from there are checked against `block_crcs` = (bytes per block, their CRC-32s) instead."""

    def __init__(self, path: str, start: int, info: zipfile.ZipInfo, prefix: str = "", skip: tuple[int, int] = (0, 0),
                 block_crcs: tuple[int, list[int]] | None = None):
        self.prefix = prefix
        self.f = builtins.open(path, "rb")  # noqa: SIM115 - closed in finish() or by the GC
        self.f.seek(start + skip[0])
        self.start = start
        self.info = info
        self.left = info.compress_size - skip[0]  # compressed bytes not yet read
        self.inflate = zlib_ng.decompressobj(-15) if info.compress_type == zipfile.ZIP_DEFLATED else None
        self.pending = b""  # compressed input the inflater has not used yet
        self.crc = 0
        self.size = skip[1]  # uncompressed bytes so far
        self.blocks = block_crcs
        self.block = [0, 0, 0]  # block checks: the block's index, its bytes so far, their CRC

    def _fail(self, reason: str) -> ValueError:
        self.f.close()
        return ValueError(f"{self.prefix}bytes {self.start}..{self.start + self.info.compress_size} {reason}")

    def read(self, n: int) -> bytes:
        out = b""
        if self.inflate is None:
            out = self.f.read(min(n, self.left))
            if len(out) < min(n, self.left):
                raise self._fail("are cut short (the file ended)")
            self.left -= len(out)
        else:
            while len(out) < n:
                if not self.pending:
                    if not self.left:
                        break
                    self.pending = self.f.read(min(READ_BYTES, self.left))
                    if not self.pending:
                        raise self._fail("are cut short (the file ended)")
                    self.left -= len(self.pending)
                try:
                    got = self.inflate.decompress(self.pending, n - len(out))
                except zlib_ng.error as e:
                    raise self._fail(f"are not a valid deflate stream ({e}): the file is damaged") from None
                self.pending = self.inflate.unconsumed_tail
                out += got
                if self.inflate.eof:
                    break
        self.size += len(out)
        if self.size > self.info.file_size:
            raise self._fail(f"inflate to more than the {counted(self.info.file_size, 'byte')} the zip says")
        if self.blocks is None:
            self.crc = zlib_ng.crc32(out, self.crc)
            return out
        view, size = memoryview(out), self.blocks[0]
        while len(view):
            take = min(len(view), size - self.block[1])
            self.block[2] = zlib_ng.crc32(view[:take], self.block[2])
            self.block[1] += take
            view = view[take:]
            if self.block[1] == size:
                self._end_block()
        return out

    def _end_block(self) -> None:
        i, _, crc = self.block
        crcs = self.blocks[1]
        if i >= len(crcs) or crc != crcs[i]:
            raise self._fail(f"fail the CRC check of their block {i} from the seek point: the file is damaged")
        self.block = [i + 1, 0, 0]

    def finish(self) -> None:
        self.f.close()
        if self.blocks is not None:
            if self.block[1]:
                self._end_block()
            if self.size != self.info.file_size or self.block[0] != len(self.blocks[1]):
                raise self._fail("fail their size check from the seek point: the file is damaged")
            return
        if self.size != self.info.file_size or self.crc != self.info.CRC:
            raise self._fail("fail their CRC check: the file is damaged")


def lockstep(members: dict[str, Member], rows: int) -> Iterator[dict[str, np.ndarray]]:
    """Blocks of `rows` rows of every member at once (members of equal length), as {name: array}."""
    try:
        yield from _lockstep(members, rows)
    finally:  # left early (a time range's end reached, an error): the members' files closed now, not by the GC
        for m in members.values():
            m.close()


def _lockstep(members: dict[str, Member], rows: int) -> Iterator[dict[str, np.ndarray]]:
    its = {k: m.blocks(rows) for k, m in members.items()}
    while True:
        block = {k: next(it, None) for k, it in its.items()}  # every member to its end: its CRC is checked
        ended = [k for k, a in block.items() if a is None]
        if ended:
            if len(ended) < len(block):
                raise ValueError(f"members {sorted(set(block) - set(ended))} hold more rows than {ended}")
            return
        yield block
