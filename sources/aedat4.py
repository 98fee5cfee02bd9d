"""iniVation AEDAT 4.0 files (flatbuffers packets, LZ4/zstd compressed), read with the `aedat`
package: a small Rust decoder from the faery authors, which SOURCES.md found identical to faery,
dv-processing, evlib and tonic on our samples, and faster than a Python flatbuffers parse would be.
Packets stream one at a time (constant memory). The first event stream is replayed (`stream_id=` to
pick another); frames, IMU and trigger packets are counted and skipped. Sensor size from the stream's
description; timestamps are the camera's absolute µs.
"""

from __future__ import annotations

import builtins
import os
import re
import struct
import sys
from collections.abc import Iterator

import numpy as np

from evstream.events import Geometry, counted

from ._base import Block, FileSource

NAME = "AEDAT 4.0 (iniVation)"
FORMAT = "aedat4"


def probe(head: bytes, path: str) -> bool:
    return head.startswith(b"#!AER-DAT4")


def _aedat():
    try:
        import aedat
    except ImportError:  # pragma: no cover - aedat is a dependency
        raise ImportError("reading AEDAT4 needs the 'aedat' package: pip install aedat") from None
    return aedat


class Aedat4Source(FileSource):
    """Replays an AEDAT4 file; timestamp policy 'sort' (camera clocks)."""

    format = FORMAT
    default_timestamps = "sort"

    def __init__(self, path, stream_id: int | None = None, **options):
        super().__init__(path, **options)
        self._check_description()
        try:
            with _quiet_panics():
                streams = _aedat().Decoder(self.path).id_to_stream()
        except _DECODER_ERRORS as e:  # the Rust decoder raises plain exceptions with its reason, or panics
            if isinstance(e, _NOT_OURS):
                raise
            raise self._decoder_error(_reason(e)) from None
        events = {k: v for k, v in streams.items() if v.get("type") == "events"}
        if not events:
            raise self.error(f"no event stream (streams: { {k: v.get('type') for k, v in streams.items()} })")
        self.stream_id = stream_id if stream_id is not None else min(events)
        if self.stream_id not in events:
            raise ValueError(f"stream_id {stream_id}: the event streams are {sorted(events)}")
        s = events[self.stream_id]
        self._cut = self._check_packets({int(k) for k in streams})
        self.set_geometry(Geometry(int(s["width"]), int(s["height"])), "stream description")
        self.details = {"streams": {int(k): v.get("type") for k, v in streams.items()},
                        "stream_id": self.stream_id}

    def _decoder_error(self, reason: str):
        """The decoder's error as ours; its XML parser says where as LINE:COLUMN of the stream description,
        turned here into the file's byte (a flipped byte there named no offset)."""
        m = re.search(r" at (\d+):(\d+)$", reason)
        if m is None or not self._info:
            return self.error(f"unreadable AEDAT4 file: {reason}")
        line, column = int(m.group(1)), int(m.group(2))
        at = 0
        for _ in range(line - 1):
            at = self._info.find(b"\n", at) + 1
            if at == 0:
                return self.error(f"unreadable AEDAT4 file: {reason}")
        return self.error(f"corrupt AEDAT4 header: its stream description (XML) is malformed: {reason[:m.start()]}",
                          offset=self._info_at + at + column - 1)

    def _check_description(self) -> None:
        """Check the header before the Rust decoder reads it: it follows the header's flatbuffer offsets
        unchecked, and one flipped byte there (an offset, or the XML description no longer UTF-8) made it
        panic (a Rust traceback on stderr) instead of saying where. Keeps where the packets start and
        the file data table's position (`_packets_at`, `_table_at`) for `_chain_break`."""
        self._packets_at, self._table_at, self._info_at, self._info = None, -1, _HEADER_OFFSET, b""
        self._packet_at: list[int] = []
        with builtins.open(self.path, "rb") as f:
            head = f.read(_HEADER_OFFSET)
            size = int.from_bytes(head[-4:], "little") if len(head) == _HEADER_OFFSET else None
            header = f.read(min(size, 1 << 24)) if size is not None else b""
        if size is None or len(header) < size:  # the decoder said only "failed to fill whole buffer"
            claim = "" if size is None else f" of {counted(size, 'byte')}"
            raise self.error(f"truncated in its header{claim}: the file ends at byte {self.file_size}")
        self._packets_at = _HEADER_OFFSET + size
        info, self._table_at = self._header_fields(header)
        self._info = info
        start, end = info.find(b"<"), info.rfind(b">")
        if start < 0 or end < start:
            return
        try:
            info[start : end + 1].decode("utf-8")
        except UnicodeDecodeError as e:
            raise self.error(f"corrupt AEDAT4 header: its stream description is not UTF-8 "
                             f"({e.reason})", offset=self._info_at + start + e.start) from None

    def _header_fields(self, h: bytes) -> tuple[bytes, int]:
        """(infoNode XML bytes, dataTablePosition) of the IOHeader flatbuffer `h`, every offset checked
        to stay inside it (a bad one is an error naming the byte that holds it)."""

        def u(fmt: str, at: int, what: str) -> int:
            n = struct.calcsize(fmt)
            if not 0 <= at <= len(h) - n:
                raise self.error(f"corrupt AEDAT4 header: {what} points outside the {len(h)}-byte header "
                                 f"(to byte {_HEADER_OFFSET + at})", offset=_HEADER_OFFSET + where[0])
            where[0] = at
            return struct.unpack_from(fmt, h, at)[0]

        where = [0]
        root = u("<I", 0, "the root table offset")
        vtable = root - u("<i", root, "the root table")
        vtable_bytes = u("<H", vtable, "the table's field list")
        table_bytes = u("<H", vtable + 2, "the table's size")
        fields = [u("<H", vtable + 4 + 2 * i, "a field entry") for i in range(max(0, vtable_bytes - 4) // 2)]
        for i, (off, n) in enumerate(zip(fields, (4, 8, 4))):
            if off and off + n > table_bytes:
                raise self.error(f"corrupt AEDAT4 header: field {i} lies at {off} bytes into a "
                                 f"{table_bytes}-byte table", offset=_HEADER_OFFSET + vtable + 4 + 2 * i)
        table_at = -1
        if len(fields) > 1 and fields[1]:
            table_at = u("<q", root + fields[1], "the data table position")
        info = b""
        if len(fields) > 2 and fields[2]:
            at = root + fields[2]
            s = at + u("<I", at, "the stream description offset")
            n = u("<I", s, "the stream description")
            u("<B", s + 4 + n - 1 if n else s, "the stream description's end")
            where[0] = at
            info = h[s + 4 : s + 4 + n]
            self._info_at = _HEADER_OFFSET + s + 4
        return info, table_at

    def _check_packets(self, stream_ids) -> str:
        """Walks the packet headers (int32 stream id, uint32 size) without decoding them; the decoder
        trusts them, and a flipped size either panicked inside it or looked like the file's end.
        A file whose data table (written last, at `_table_at`) is still there is complete: a header
        with an unknown stream or running past the packets' end is then an error naming its byte.
        Otherwise returns where the packets run past the file's end ('' if they do not): a cut."""
        if self._packets_at is None:
            return ""
        size = os.path.getsize(self.path)
        complete = 0 <= self._table_at <= size
        end = self._table_at if complete else size
        at, k, previous = self._packets_at, 0, None
        self._packet_at = []  # byte of each packet header, to say where a packet that fails to decode is
        with builtins.open(self.path, "rb") as f:
            while at + 8 <= end:
                f.seek(at)
                stream_id, n = struct.unpack("<iI", f.read(8))
                bad = (f"stream id {stream_id} (the file has {sorted(stream_ids)})" if stream_id not in stream_ids
                       else f"a size of {counted(n, 'byte')}, past the packets' end at byte {end}" if at + 8 + n > end
                       else None)
                if bad is None:
                    self._packet_at.append(at)
                    previous, at, k = at, at + 8 + n, k + 1
                    continue
                if not complete:
                    return f"packet {k} at byte {at} claims {counted(n, 'byte')}; the file ends at byte {end}"
                blame = f"; the size of packet {k - 1} at byte {previous} may be what is wrong" if k else ""
                raise self.error(f"corrupt AEDAT4 packet header: packet {k} has {bad}{blame}", offset=at)
        if complete and at != end:
            raise self.error(f"corrupt AEDAT4 packet header: packet {k} starts {counted(end - at, 'byte')} before the "
                             f"data table at byte {end}", offset=at)
        return ""

    def _blocks(self) -> Iterator[Block]:
        skipped: dict[str, int] = {}
        n_packets = 0
        batch = dtype = None  # event packets are small: copy their records into one reused batch
        fill = 0
        try:
            for packet in _quietly(_aedat().Decoder(self.path)):
                n_packets += 1
                ev = packet.get("events")
                if ev is None or packet["stream_id"] != self.stream_id:
                    kind = "events" if ev is not None else next((k for k in packet if k != "stream_id"), "other")
                    skipped[kind] = skipped.get(kind, 0) + 1
                    continue
                if batch is not None and ev.dtype != dtype:  # never seen, but a view must not lie
                    if fill:
                        yield _block(batch[:fill].view(dtype))
                    batch, fill = None, 0
                if batch is None:
                    dtype = ev.dtype
                    batch = np.empty(_BATCH_EVENTS * dtype.itemsize, np.uint8)
                raw = np.ascontiguousarray(ev).view(np.uint8).reshape(-1)  # a plain copy is fastest
                i = 0
                while i < len(raw):
                    k = min(len(raw) - i, len(batch) - fill)
                    batch[fill : fill + k] = raw[i : i + k]
                    fill += k
                    i += k
                    if fill == len(batch):
                        yield _block(batch.view(dtype))
                        fill = 0
        except _DECODER_ERRORS as e:  # the Rust decoder's errors (truncated packet, bad LZ4 frame, ...)
            if isinstance(e, _NOT_OURS):
                raise
            if n_packets and "fill whole buffer" in str(e):  # cut short, or a packet size that lies
                self.warn(f"truncated after {counted(n_packets, 'packet')} ({self._cut or e}); the events before "
                          "are kept")
            else:
                at = self._packet_at[n_packets] if n_packets < len(self._packet_at) else None
                which = f"packet {n_packets}" if at is not None else f"after {counted(n_packets, 'packet')}"
                raise self.error(f"AEDAT4 decoding failed at {which}: {_reason(e)}", offset=at) from None
        finally:
            self.counters = {f"{k}_packets_skipped": v for k, v in skipped.items()}
        if fill:
            yield _block(batch[:fill].view(dtype))


_BATCH_EVENTS = 1 << 16
_HEADER_OFFSET = 18  # "#!AER-DAT4.0\r\n" then the header's size (uint32) then the header
# A Rust panic in the decoder (a header byte flipped into half a UTF-8 character: "end byte index 1124
# is not a char boundary") arrives as pyo3's PanicException, a BaseException: `except Exception` let it
# through as a traceback. Catch every exception but the ones that are not about the file.
class _quiet_panics:
    """Around a call into the Rust decoder: what it writes to stderr (file descriptor 2) goes to a side
    file, and comes back unless it is a Rust panic message ("thread '...' panicked at ..."), which the
    decoder prints before raising; the reader turns that exception into its own one-line error."""

    _side = None

    def __enter__(self):
        if _quiet_panics._side is None:
            import tempfile

            _quiet_panics._side = tempfile.TemporaryFile()
        self.side = _quiet_panics._side
        self.side.seek(0)
        self.side.truncate()
        try:
            sys.stderr.flush()
            self.saved = os.dup(2)
            os.dup2(self.side.fileno(), 2)
        except (OSError, ValueError, AttributeError):  # no real stderr (embedded): nothing to quiet
            self.saved = None
        return self

    def __exit__(self, *exc):
        if self.saved is None:
            return False
        os.dup2(self.saved, 2)
        os.close(self.saved)
        if os.fstat(self.side.fileno()).st_size:
            self.side.seek(0)
            text = self.side.read(1 << 16)
            if b"panicked at" not in text and b"RUST_BACKTRACE" not in text:
                os.write(2, text)
        return False


def _quietly(decoder):
    """Iterate the decoder with each step inside `_quiet_panics`."""
    it = iter(decoder)
    while True:
        with _quiet_panics():
            try:
                packet = next(it)
            except StopIteration:
                return
        yield packet


_DECODER_ERRORS = BaseException
_NOT_OURS = (KeyboardInterrupt, SystemExit, GeneratorExit, MemoryError)


def _reason(e: BaseException) -> str:
    return f"decoder panic: {e}" if type(e).__name__ == "PanicException" else str(e)


def _block(ev: np.ndarray) -> Block:
    """Our own arrays (copies): the batch they come from is reused."""
    return Block(ev["t"].astype(np.int64), ev["x"].copy(), ev["y"].copy(), ev["on"].astype(np.uint8))


def open(path, **options) -> Aedat4Source:  # noqa: A001 - the format-module interface
    return Aedat4Source(path, **options)
