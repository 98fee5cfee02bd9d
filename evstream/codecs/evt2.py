"""Prophesee EVT 2.0 <-> event arrays: a streaming numba decoder and an encoder (no file I/O).

EVT 2.0 is a stream of little-endian 32-bit words, the type in bits 31..28:

| type | word        | payload                                                             |
|------|-------------|---------------------------------------------------------------------|
| 0x0  | CD_OFF      | timestamp bits 5..0 (27..22), x (21..11), y (10..0)                 |
| 0x1  | CD_ON       | the same, ON polarity                                               |
| 0x8  | TIME_HIGH   | timestamp bits 33..6 (27..0)                                        |
| 0xA  | EXT_TRIGGER | timestamp bits 5..0 (27..22), channel (12..8), value (0) (counted)  |
| 0xE  | OTHERS      | skipped, counted                                                    |
| 0xF  | CONTINUED   | skipped, counted                                                    |

Other types are unknown: skipped and counted. t = TIME_HIGH·64 + the event's 6 low bits
(+ 2^34 µs per clock wrap: a TIME_HIGH that drops by more than half its 28-bit range).
Events before the first TIME_HIGH have no time base and are skipped (counted in `no_time`).
"""

from __future__ import annotations

import numpy as np

from ..jit import njit
from .words import COUNTER_NAMES, WordDecoder

__all__ = ["Evt2Decoder", "Evt2Encoder", "decode", "encode"]

_HIGH, _LOOPS, _HAS_HIGH, _LAST_T = range(4)
_N_STATE = 4
_UNKNOWN, _TRIGGER, _OTHERS, _CONTINUED, _TIME_BACK, _NO_TIME, _WRAPS = range(len(COUNTER_NAMES))
_HIGH_RANGE = 1 << 28
_WRAP_MIN_DROP = 1 << 27


@njit(cache=True, nogil=True)
def _decode_kernel(words, state, counters, out_t, out_x, out_y, out_p):
    """Decode all `words` (out arrays hold at least one event per word); returns the event count."""
    high = state[_HIGH]
    loops = state[_LOOPS]
    has_high = state[_HAS_HIGH]
    last_t = state[_LAST_T]
    base = (loops << 34) + (high << 6)
    n = 0
    for i in range(len(words)):
        w = np.int64(words[i])
        kind = w >> 28
        if kind <= 1:
            if has_high:
                t = base + ((w >> 22) & 0x3F)
                if t < last_t:
                    counters[_TIME_BACK] += 1
                last_t = t
                out_t[n] = t
                out_x[n] = (w >> 11) & 0x7FF
                out_y[n] = w & 0x7FF
                out_p[n] = kind
                n += 1
            else:
                counters[_NO_TIME] += 1
        elif kind == 0x8:
            new_high = w & 0xFFFFFFF
            if has_high and high - new_high >= _WRAP_MIN_DROP:
                loops += 1
                counters[_WRAPS] += 1
            high = new_high
            has_high = 1
            base = (loops << 34) + (high << 6)
        elif kind == 0xA:
            counters[_TRIGGER] += 1
        elif kind == 0xE:
            counters[_OTHERS] += 1
        elif kind == 0xF:
            counters[_CONTINUED] += 1
        else:
            counters[_UNKNOWN] += 1
    state[_HIGH] = high
    state[_LOOPS] = loops
    state[_HAS_HIGH] = has_high
    state[_LAST_T] = last_t
    return n


class Evt2Decoder(WordDecoder):
    """Streaming EVT2 decoder: feed byte blocks of any size; partial words and the time base carry over.

    `counters` (dict) counts skipped words (unknown, trigger, others, continued), events before the
    first TIME_HIGH (no_time), timestamps stepping back (time_back) and clock wraps (wraps).
    """

    word, n_state, last_t_slot = "<u4", _N_STATE, _LAST_T

    @property
    def time_us(self) -> int:
        """The time base of the last TIME_HIGH seen (its 6 low bits zero)."""
        s = self.state
        return int((s[_LOOPS] << 34) + (s[_HIGH] << 6))

    def decode(self, data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Decode a block; returns (t int64 µs, x uint16, y uint16, p uint8) in stream order."""
        words = self._words(data)
        n = len(words)
        out_t = np.empty(n, np.int64)
        out_x = np.empty(n, np.uint16)
        out_y = np.empty(n, np.uint16)
        out_p = np.empty(n, np.uint8)
        k = _decode_kernel(words, self.state, self._counters, out_t, out_x, out_y, out_p)
        return out_t[:k], out_x[:k], out_y[:k], out_p[:k]

    def _skip(self, words, start_us: int) -> int:
        """Up to the first TIME_HIGH whose events may be at or after `start_us` (base + 63 >= start_us):
        every event before it is earlier (a CD word's time is at most its TIME_HIGH's base + 63)."""
        return _skip_kernel(words, self.state, self._counters, start_us)


@njit(cache=True, nogil=True)
def _skip_kernel(words, state, counters, start_us):
    """The decoder's time base over `words` up to the first TIME_HIGH word whose base + 63 >= start_us;
    returns its index (len(words): none), the state left as before that word."""
    high = state[_HIGH]
    loops = state[_LOOPS]
    has_high = state[_HAS_HIGH]
    for i in range(len(words)):
        w = np.int64(words[i])
        if w >> 28 == 0x8:
            new_high = w & 0xFFFFFFF
            wrap = has_high and high - new_high >= _WRAP_MIN_DROP
            new_loops = loops + 1 if wrap else loops
            if (new_loops << 34) + (new_high << 6) + 63 >= start_us:
                state[_HIGH] = high
                state[_LOOPS] = loops
                state[_HAS_HIGH] = has_high
                return i
            if wrap:
                counters[_WRAPS] += 1
            high = new_high
            loops = new_loops
            has_high = 1
    state[_HIGH] = high
    state[_LOOPS] = loops
    state[_HAS_HIGH] = has_high
    return len(words)


def decode(data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One-shot decode of a whole EVT2 byte string (no header) into (t, x, y, p)."""
    return Evt2Decoder().decode(data)


_MAX_HIGH_STEP = _WRAP_MIN_DROP - 1


@njit(cache=True, nogil=True)
def _check_kernel(t, x, y, p, prev):
    for i in range(len(t)):
        if t[i] < prev or x[i] > 0x7FF or y[i] > 0x7FF or p[i] > 1:
            return i
        prev = t[i]
    return -1


@njit(cache=True, nogil=True)
def _encode_kernel(t, x, y, p, out, state):
    """EVT2 words for checked events into `out`; `state[0]` is the last TIME_HIGH written (-1: none)."""
    k = 0
    cur = state[0]
    for i in range(len(t)):
        h = t[i] >> 6
        if h != cur:
            # TIME_HIGH is 28 bits: cross a wrap as top -> 0, the way a camera does
            frm = cur if cur >= 0 else np.int64(0)
            while (h >> 28) > (frm >> 28):
                out[k] = 0x8FFFFFFF
                out[k + 1] = 0x80000000
                k += 2
                frm = ((frm >> 28) + 1) << 28
            out[k] = 0x80000000 | (h & 0xFFFFFFF)
            k += 1
            cur = h
        out[k] = (np.int64(p[i]) << 28) | ((t[i] & 0x3F) << 22) | (np.int64(x[i]) << 11) | np.int64(y[i])
        k += 1
    state[0] = cur
    return k


class Evt2Encoder:
    """Streaming EVT2 encoder: successive `encode` calls continue one stream."""

    def __init__(self):
        self.state = np.array([-1], np.int64)
        self.last_t = 0
        self.events_in = 0

    def encode(self, t, x, y, p) -> bytes:
        t = np.ascontiguousarray(t, np.int64)
        x = np.ascontiguousarray(x, np.uint16)
        y = np.ascontiguousarray(y, np.uint16)
        p = np.ascontiguousarray(p, np.uint8)
        n = len(t)
        if not (len(x) == len(y) == len(p) == n):
            raise ValueError(f"encode: arrays differ in length (t {n}, x {len(x)}, y {len(y)}, p {len(p)})")
        if n == 0:
            return b""
        bad = _check_kernel(t, x, y, p, np.int64(self.last_t))
        if bad >= 0:
            raise ValueError(
                f"encode: event {self.events_in + bad} (t={t[bad]} µs, x={x[bad]}, y={y[bad]}, p={p[bad]}) "
                "cannot be written: EVT2 needs non-decreasing t >= 0, x and y < 2048, p 0 or 1"
            )
        out = np.empty(2 * n + 2 * int(t[-1] >> 34) + 2, np.uint32)
        k = _encode_kernel(t, x, y, p, out, self.state)
        self.last_t = int(t[-1])
        self.events_in += n
        return out[:k].astype("<u4", copy=False).tobytes()


def encode(t, x, y, p) -> bytes:
    """EVT2 bytes (no header) for events with non-decreasing t ≥ 0 µs and x, y < 2048.

    Starts with a TIME_HIGH word, so `decode(encode(...))` returns the events exactly, in order.
    """
    return Evt2Encoder().encode(t, x, y, p)
