"""iniVation AEDAT 4.0 files (flatbuffers packets, LZ4/zstd compressed), read with the `aedat`
package: a small Rust decoder from the faery authors, which SOURCES.md found identical to faery,
dv-processing, evlib and tonic on our samples, and faster than a Python flatbuffers parse would be.
Packets stream one at a time (constant memory). The first event stream is replayed (`stream_id=` to
pick another); frames, IMU and trigger packets are counted and skipped. Sensor size from the stream's
description; timestamps are the camera's absolute µs.
"""

from __future__ import annotations

import builtins
from collections.abc import Iterator

import numpy as np

from evstream.events import Geometry

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
            streams = _aedat().Decoder(self.path).id_to_stream()
        except _DECODER_ERRORS as e:  # the Rust decoder raises plain exceptions with its reason, or panics
            if isinstance(e, _NOT_OURS):
                raise
            raise self.error(f"unreadable AEDAT4 file: {_reason(e)}") from None
        events = {k: v for k, v in streams.items() if v.get("type") == "events"}
        if not events:
            raise self.error(f"no event stream (streams: { {k: v.get('type') for k, v in streams.items()} })")
        self.stream_id = stream_id if stream_id is not None else min(events)
        if self.stream_id not in events:
            raise ValueError(f"stream_id {stream_id}: the event streams are {sorted(events)}")
        s = events[self.stream_id]
        self.set_geometry(Geometry(int(s["width"]), int(s["height"])), "stream description")
        self.details = {"streams": {int(k): v.get("type") for k, v in streams.items()},
                        "stream_id": self.stream_id}

    def _check_description(self) -> None:
        """The header's XML stream description must be UTF-8: the decoder takes it unchecked, and one
        flipped byte there made it panic (a Rust traceback on stderr) instead of saying where."""
        with builtins.open(self.path, "rb") as f:
            head = f.read(_HEADER_OFFSET)
            if len(head) < _HEADER_OFFSET:
                return  # too short for a header: the decoder says so
            size = int.from_bytes(head[-4:], "little")
            header = f.read(min(size, 1 << 24))
        start, end = header.find(b"<"), header.rfind(b">")
        if start < 0 or end < start:
            return
        try:
            header[start : end + 1].decode("utf-8")
        except UnicodeDecodeError as e:
            raise self.error(f"corrupt AEDAT4 header: its stream description is not UTF-8 "
                             f"({e.reason})", offset=_HEADER_OFFSET + start + e.start) from None

    def _blocks(self) -> Iterator[Block]:
        skipped: dict[str, int] = {}
        n_packets = 0
        batch = dtype = None  # event packets are small: copy their records into one reused batch
        fill = 0
        try:
            for packet in _aedat().Decoder(self.path):
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
            if n_packets and "fill whole buffer" in str(e):  # a recording cut short: keep what was read
                self.warn(f"truncated after {n_packets} packets ({e}); the events before are kept")
            else:
                raise self.error(f"AEDAT4 decoding failed after {n_packets} packets: {_reason(e)}") from None
        finally:
            self.counters = {f"{k}_packets_skipped": v for k, v in skipped.items()}
        if fill:
            yield _block(batch[:fill].view(dtype))


_BATCH_EVENTS = 1 << 16
_HEADER_OFFSET = 18  # "#!AER-DAT4.0\r\n" then the header's size (uint32) then the header
# A Rust panic in the decoder (a header byte flipped into half a UTF-8 character: "end byte index 1124
# is not a char boundary") arrives as pyo3's PanicException, a BaseException: `except Exception` let it
# through as a traceback. Catch every exception but the ones that are not about the file.
_DECODER_ERRORS = BaseException
_NOT_OURS = (KeyboardInterrupt, SystemExit, GeneratorExit, MemoryError)


def _reason(e: BaseException) -> str:
    return f"decoder panic: {e}" if type(e).__name__ == "PanicException" else str(e)


def _block(ev: np.ndarray) -> Block:
    """Our own arrays (copies): the batch they come from is reused."""
    return Block(ev["t"].astype(np.int64), ev["x"].copy(), ev["y"].copy(), ev["on"].astype(np.uint8))


def open(path, **options) -> Aedat4Source:  # noqa: A001 - the format-module interface
    return Aedat4Source(path, **options)
