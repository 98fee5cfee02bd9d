"""The event_camera_msgs "mono" encoding <-> event arrays (vectorised numpy; no state across packets).

Each event is one 64-bit word (little-endian unless the packet says `is_bigendian`):

| bits   | field                                   |
|--------|-----------------------------------------|
| 63     | polarity (1 = ON, 0 = OFF)              |
| 48..62 | y (15 bits)                             |
| 32..47 | x (16 bits)                             |
| 0..31  | dt, ns after the packet's `time_base`   |

Event time in ns = `time_base` + dt (event_camera_codecs' mono decoder), so a packet spans at most
2^32 ns ≈ 4.29 s. evstream's event times are µs: we write dt = t·1000 − time_base and read t = ⌊(time_base +
dt) / 1000⌋, exact for times that were whole µs (ours always are).
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_SPAN_NS", "decode", "encode"]

MAX_SPAN_NS = (1 << 32) - 1
_NS_PER_US = 1000


def encode(t, x, y, p, time_base_ns: int) -> bytes:
    """Mono bytes for events at t µs (t·1000 − time_base_ns in 0..2^32−1 ns), x < 65536, y < 32768."""
    t = np.asarray(t, np.int64)
    x = np.asarray(x)
    y = np.asarray(y)
    p = np.asarray(p)
    n = len(t)
    if not (len(x) == len(y) == len(p) == n):
        raise ValueError(f"mono.encode: arrays differ in length (t {n}, x {len(x)}, y {len(y)}, p {len(p)})")
    if n == 0:
        return b""
    dt = t * _NS_PER_US - np.int64(time_base_ns)
    bad = (dt < 0) | (dt > MAX_SPAN_NS) | (x < 0) | (x > 0xFFFF) | (y < 0) | (y > 0x7FFF) | (p < 0) | (p > 1)
    if bad.any():  # (an x past 65535 or a negative field would spill into the bits above it)
        i = int(np.argmax(bad))
        raise ValueError(
            f"mono.encode: event {i} (t={t[i]} µs, x={x[i]}, y={y[i]}, p={p[i]}) cannot be written with time_base "
            f"{time_base_ns} ns: dt must be 0..2^32-1 ns, x < 65536, y < 32768, p 0 or 1"
        )
    words = (dt.astype(np.uint64) | (x.astype(np.uint64) << np.uint64(32))
             | (y.astype(np.uint64) << np.uint64(48)) | (p.astype(np.uint64) << np.uint64(63)))
    return words.astype("<u8", copy=False).tobytes()


def decode(data, time_base_ns: int, big_endian: bool = False):
    """(t µs int64, x uint16, y uint16, p uint8) from mono bytes; a trailing partial word is an error."""
    raw = memoryview(data).cast("B")
    if len(raw) % 8:
        raise ValueError(f"mono.decode: {len(raw)} bytes is not a whole number of 8-byte events")
    words = np.frombuffer(raw, ">u8" if big_endian else "<u8").astype(np.uint64, copy=False)
    dt = (words & np.uint64(0xFFFFFFFF)).astype(np.int64)
    t = (np.int64(time_base_ns) + dt) // _NS_PER_US
    x = ((words >> np.uint64(32)) & np.uint64(0xFFFF)).astype(np.uint16)
    y = ((words >> np.uint64(48)) & np.uint64(0x7FFF)).astype(np.uint16)
    p = (words >> np.uint64(63)).astype(np.uint8)
    return t, x, y, p
