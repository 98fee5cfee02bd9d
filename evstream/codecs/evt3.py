"""Prophesee EVT 3.0 <-> event arrays: a streaming numba decoder and an encoder (no file I/O).

EVT 3.0 is a stream of little-endian 16-bit words, the type in bits 15..12:

| type | word          | payload (bits 11..0)                                             |
|------|---------------|------------------------------------------------------------------|
| 0x0  | ADDR_Y        | y (10..0), system type (11)                                      |
| 0x2  | ADDR_X        | x (10..0), polarity (11): one event at (x, y, p, t)              |
| 0x3  | VECT_BASE_X   | x (10..0), polarity (11): base of the following vector words     |
| 0x4  | VECT_12       | 12-bit mask: events at base + i for each set bit i; base += 12   |
| 0x5  | VECT_8        | 8-bit mask (7..0): the same with 8; base += 8                    |
| 0x6  | TIME_LOW      | timestamp bits 11..0                                             |
| 0x7  | CONTINUED_4   | payload of the previous word (skipped)                           |
| 0x8  | TIME_HIGH     | timestamp bits 23..12                                            |
| 0xA  | EXT_TRIGGER   | trigger value (0) and channel (11..8) (counted, not an event)    |
| 0xE  | OTHERS        | sub-type (skipped, counted)                                      |
| 0xF  | CONTINUED_12  | payload of the previous word (skipped)                           |

Other types are unknown: skipped and counted. The decode is spec-literal: t = TIME_HIGH·4096 +
TIME_LOW (+ 2^24 per time-high wrap), so a TIME_LOW that steps back under the same TIME_HIGH gives
a timestamp that steps back (counted in `time_back`); the source's timestamp policy decides what to do
with it. A TIME_HIGH that drops from the top of its range to the bottom (by ≥ 4080, as a camera's
4095 -> 0) is a wrap of the 24-bit clock (2^24 µs ≈ 16.8 s); a smaller drop is a step back.
Events before the first TIME_HIGH have no time base and are skipped (counted in `no_time`).
"""

from __future__ import annotations

import numpy as np

from ..jit import njit
from ..nowrap import ix
from .words import COUNTER_NAMES, WordDecoder

__all__ = ["Evt3Decoder", "Evt3Encoder", "decode", "encode"]

# state slots of the decoder (an int64 array, so the kernel stays a pure function of arrays)
_HIGH, _LOW, _Y, _BASE_X, _POL, _LOOPS, _HAS_HIGH, _LAST_T = range(8)
_N_STATE = 8
# counter slots
_UNKNOWN, _TRIGGER, _OTHERS, _CONTINUED, _TIME_BACK, _NO_TIME, _WRAPS = range(len(COUNTER_NAMES))

_WRAP_US = 1 << 24
_HIGH_HALF_RANGE = 2048
_WRAP_MIN_DROP = 4096 - 16  # a camera wraps 4095 -> 0; a smaller drop is a step back
_MAX_EVENTS_PER_WORD = 12


@njit(cache=True, nogil=True, inline="always")
def _load(state):
    """The decoder's registers kept in `state` between calls: TIME_HIGH, TIME_LOW, y, vector base x,
    polarity, clock wraps, whether a TIME_HIGH was seen (`_decode_kernel` and `_follow` share them)."""
    return state[_HIGH], state[_LOW], state[_Y], state[_BASE_X], state[_POL], state[_LOOPS], state[_HAS_HIGH]


@njit(cache=True, nogil=True, inline="always")
def _store(state, high, low, y, base_x, pol, loops, has_high):
    """The registers back into `state` (`_load`'s inverse)."""
    state[_HIGH] = high
    state[_LOW] = low
    state[_Y] = y
    state[_BASE_X] = base_x
    state[_POL] = pol
    state[_LOOPS] = loops
    state[_HAS_HIGH] = has_high


@njit(cache=True, nogil=True)
def _decode_kernel(words, state, counters, out_t, out_x, out_y, out_p):
    """Decode `words` into the out arrays until the words or the room run out.

    Returns (events written, words consumed); stops before a word that might not fit. Word types are
    tested in order of frequency in camera streams.
    """
    high, low, y, base_x, pol, loops, has_high = _load(state)
    last_t = state[_LAST_T]
    cap = len(out_t)
    n = 0
    i = 0
    nw = len(words)
    t = (loops << 24) + (high << 12) + low
    while i < nw:
        w = np.int64(words[ix(i)])
        kind = w >> 12
        payload = w & 0xFFF
        if not has_high:
            # before the first TIME_HIGH there is no time base: events are counted, not decoded
            if kind == 0x8:
                high = payload
                has_high = 1
                t = (loops << 24) + (high << 12) + low
            elif kind == 0x2:
                counters[_NO_TIME] += 1
            elif kind == 0x4 or kind == 0x5:
                m = payload if kind == 0x4 else payload & 0xFF
                while m:
                    counters[_NO_TIME] += m & 1
                    m >>= 1
                base_x += 12 if kind == 0x4 else 8
            elif kind == 0x0:
                y = payload & 0x7FF
            elif kind == 0x3:
                base_x = payload & 0x7FF
                pol = payload >> 11
            elif kind == 0x6:
                low = payload
                t = (loops << 24) + (high << 12) + low
            else:
                _count_other(kind, counters)
            i += 1
            continue
        if n + _MAX_EVENTS_PER_WORD > cap:
            break
        if kind == 0x2:  # ADDR_X: one event
            if t < last_t:
                counters[_TIME_BACK] += 1
            last_t = t
            out_t[ix(n)] = t
            out_x[ix(n)] = payload & 0x7FF
            out_y[ix(n)] = y
            out_p[ix(n)] = payload >> 11
            n += 1
        elif kind == 0x6:  # TIME_LOW
            low = payload
            t = (loops << 24) + (high << 12) + low
        elif kind == 0x0:  # ADDR_Y
            y = payload & 0x7FF
        elif kind == 0x4 or kind == 0x5:  # VECT_12, VECT_8
            width = 12 if kind == 0x4 else 8
            mask = payload if kind == 0x4 else payload & 0xFF
            if mask != 0:
                if t < last_t:
                    counters[_TIME_BACK] += 1
                last_t = t
            b = 0
            while mask:
                if mask & 1:
                    out_t[ix(n)] = t
                    out_x[ix(n)] = base_x + b
                    out_y[ix(n)] = y
                    out_p[ix(n)] = pol
                    n += 1
                mask >>= 1
                b += 1
            base_x += width
        elif kind == 0x3:  # VECT_BASE_X
            base_x = payload & 0x7FF
            pol = payload >> 11
        elif kind == 0x8:  # TIME_HIGH
            if payload < high and high - payload >= _WRAP_MIN_DROP:
                loops += 1
                counters[_WRAPS] += 1
            high = payload
            t = (loops << 24) + (high << 12) + low
        else:
            _count_other(kind, counters)
        i += 1
    _store(state, high, low, y, base_x, pol, loops, has_high)
    state[_LAST_T] = last_t
    return n, i


@njit(cache=True, nogil=True, inline="always")
def _count_other(kind, counters):
    """Words that carry no CD event: triggers, OTHERS, CONTINUED, and unknown types."""
    if kind == 0xA:
        counters[_TRIGGER] += 1
    elif kind == 0xE:
        counters[_OTHERS] += 1
    elif kind == 0x7 or kind == 0xF:
        counters[_CONTINUED] += 1
    else:
        counters[_UNKNOWN] += 1


class Evt3Decoder(WordDecoder):
    """Streaming EVT3 decoder: feed byte blocks of any size; partial words and the time base carry over.

    `counters` (dict) counts skipped words (unknown, trigger, others, continued), events before the
    first TIME_HIGH (no_time), timestamps stepping back (time_back) and 24-bit clock wraps (wraps).
    """

    word, n_state, last_t_slot = "<u2", _N_STATE, _LAST_T

    @property
    def has_time(self) -> bool:
        return bool(self.state[_HAS_HIGH])

    @property
    def time_us(self) -> int:
        """The current time base (TIME_HIGH, TIME_LOW and wraps seen so far)."""
        s = self.state
        return int((s[_LOOPS] << 24) + (s[_HIGH] << 12) + s[_LOW])

    def decode(self, data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Decode a block; returns (t int64 µs, x uint16, y uint16, p uint8) in stream order."""
        words = self._words(data)
        parts = []
        start = 0
        while start < len(words):
            rest = words[start:]
            # most streams carry about one event per word; grow only when vectors are denser
            cap = min(len(rest) * _MAX_EVENTS_PER_WORD, len(rest) + 64)
            out_t = np.empty(cap, np.int64)
            out_x = np.empty(cap, np.uint16)
            out_y = np.empty(cap, np.uint16)
            out_p = np.empty(cap, np.uint8)
            n, used = _decode_kernel(rest, self.state, self._counters, out_t, out_x, out_y, out_p)
            parts.append((out_t[:n], out_x[:n], out_y[:n], out_p[:n]))
            start += used
        if not parts:
            return (np.zeros(0, np.int64), np.zeros(0, np.uint16), np.zeros(0, np.uint16),
                    np.zeros(0, np.uint8))
        if len(parts) == 1:
            return parts[0]
        return tuple(np.concatenate([p[k] for p in parts]) for k in range(4))


    def _skip(self, words, start_us: int) -> int:
        """Up to the first TIME_HIGH or TIME_LOW word that sets the time to `start_us` or later: every
        event before it takes a time set before it, earlier than `start_us`."""
        return _skip_kernel(words, self.state, self._counters, start_us)


@njit(cache=True, nogil=True)
def _skip_kernel(words, state, counters, start_us):
    """The decoder's state over `words` (events not written) up to the first word that sets the time to
    start_us or later (a TIME_HIGH or TIME_LOW, once there is a time base); returns its index (len(words):
    none), the state left as before that word.

    Two passes: TIME_HIGH words alone (wraps counted) find the first period whose times can reach
    start_us (its TIME_HIGH + 4095); the row, time low and vector base standing before it are read back
    from the last words that set them; `_follow` then goes word by word through that period."""
    high = state[_HIGH]
    loops = state[_LOOPS]
    has_high = state[_HAS_HIGH]
    nw = len(words)
    stop = nw
    if has_high and (loops << 24) + (high << 12) + 0xFFF >= start_us:
        stop = 0  # the period of the block before already reaches start_us: on word by word
    for i in range(stop):
        w = np.int64(words[ix(i)])
        if w >> 12 == 0x8:
            payload = w & 0xFFF
            wrap = has_high and payload < high and high - payload >= _WRAP_MIN_DROP
            new_loops = loops + 1 if wrap else loops
            if (new_loops << 24) + (payload << 12) + 0xFFF >= start_us:
                stop = i
                break
            if wrap:
                counters[_WRAPS] += 1
            high = payload
            loops = new_loops
            has_high = 1
    _restore(words, stop, state)
    state[_HIGH] = high
    state[_LOOPS] = loops
    state[_HAS_HIGH] = has_high
    if stop == nw:
        return nw
    return stop + _follow(words[stop:], state, counters, start_us)


@njit(cache=True, nogil=True)
def _restore(words, stop, state):
    """state's time low, row and vector base (base x, polarity) as they stand before word `stop`, from the
    last words before it that set them (those not set there keep the state's values; vector words
    after the last VECT_BASE_X move the base on)."""
    need_low = True
    need_y = True
    need_base = True
    moved = 0
    j = stop - 1
    while j >= 0 and (need_low or need_y or need_base):
        w = np.int64(words[ix(j)])
        kind = w >> 12
        payload = w & 0xFFF
        if kind == 0x6:
            if need_low:
                state[_LOW] = payload
                need_low = False
        elif kind == 0x0:
            if need_y:
                state[_Y] = payload & 0x7FF
                need_y = False
        elif need_base:
            if kind == 0x4:
                moved += 12
            elif kind == 0x5:
                moved += 8
            elif kind == 0x3:
                state[_BASE_X] = (payload & 0x7FF) + moved
                state[_POL] = payload >> 11
                need_base = False
        j -= 1
    if need_base:
        state[_BASE_X] += moved


@njit(cache=True, nogil=True)
def _follow(words, state, counters, start_us):
    """`_skip_kernel`'s second pass: every word, as `_decode_kernel` (events not written)."""
    high, low, y, base_x, pol, loops, has_high = _load(state)
    i = 0
    nw = len(words)
    while i < nw:
        w = np.int64(words[ix(i)])
        kind = w >> 12
        payload = w & 0xFFF
        if kind == 0x2:
            pass
        elif kind == 0x8 or kind == 0x6:
            new_high, new_low, new_loops, wrap = high, low, loops, False
            if kind == 0x8:
                wrap = has_high and payload < high and high - payload >= _WRAP_MIN_DROP
                new_loops = loops + 1 if wrap else loops
                new_high = payload
            else:
                new_low = payload
            if (has_high or kind == 0x8) and (new_loops << 24) + (new_high << 12) + new_low >= start_us:
                break
            if wrap:
                counters[_WRAPS] += 1
            if kind == 0x8:
                has_high = 1
            high, low, loops = new_high, new_low, new_loops
        elif kind == 0x0:
            y = payload & 0x7FF
        elif kind == 0x4 or kind == 0x5:
            base_x += 12 if kind == 0x4 else 8
        elif kind == 0x3:
            base_x = payload & 0x7FF
            pol = payload >> 11
        i += 1
    _store(state, high, low, y, base_x, pol, loops, has_high)
    return i


def decode(data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One-shot decode of a whole EVT3 byte string (no header) into (t, x, y, p)."""
    return Evt3Decoder().decode(data)


# -- encoder -------------------------------------------------------------------------------------
_MAX_HIGH_STEP = _HIGH_HALF_RANGE - 1  # TIME_HIGH increments the decoder cannot mistake for a wrap
_VECTOR_MIN_EVENTS = 3  # VECT_BASE_X + VECT_12 (2 words) beats ADDR_X words from 3 events on
MAX_WRAPS_PER_CALL = 1 << 16  # ~13 days of silence: beyond it the TIME_HIGH steps would swamp the data


@njit(cache=True, nogil=True, inline="always")
def _advance_time_high(out, k, frm, to):
    """TIME_HIGH words from absolute time-high `frm` to `to` (> frm, or == frm at the start).

    Forward steps stay under half the 12-bit range, and each 24-bit wrap is spelled 4095 -> 0, the
    way a camera sends it, so no decoder can take a step for a wrap or a wrap for a step back.
    """
    cur = frm
    while (to >> 12) > (cur >> 12):  # wrap(s) ahead
        end = (cur | 0xFFF)
        while end - cur > _MAX_HIGH_STEP:
            cur += _MAX_HIGH_STEP
            out[ix(k)] = 0x8000 | (cur & 0xFFF)
            k += 1
        out[ix(k)] = 0x8FFF
        out[ix(k + 1)] = 0x8000
        k += 2
        cur = end + 1
    while to - cur > _MAX_HIGH_STEP:
        cur += _MAX_HIGH_STEP
        out[ix(k)] = 0x8000 | (cur & 0xFFF)
        k += 1
    out[ix(k)] = 0x8000 | (to & 0xFFF)
    return k + 1


@njit(cache=True, nogil=True)
def _check_kernel(t, x, y, p, prev):
    """Index of the first event EVT3 cannot carry (t < prev or going back, x/y ≥ 2048, p > 1), else -1."""
    for i in range(len(t)):
        if t[i] < prev or x[i] > 0x7FF or y[i] > 0x7FF or p[i] > 1:
            return i
        prev = t[i]
    return -1


@njit(cache=True, nogil=True)
def _encode_kernel(t, x, y, p, out, state, last_t):
    """Write EVT3 words for the events, in stream order, into `out`; returns the word count, or -1 - i when
    event i cannot be written (`_check_kernel`, with `last_t` the stream's last time; nothing written).

    `state` = [started, time-high, time-low, y] carries the stream's position across calls.
    """
    bad = _check_kernel(t, x, y, p, last_t)  # in the same call: a packet pays one dispatch, not two
    if bad >= 0:
        return -1 - bad
    n = len(t)
    k = 0
    started = state[0] != 0
    cur_high = state[1]
    cur_low = state[2]
    cur_y = state[3]
    i = 0
    while i < n:
        ti = t[ix(i)]
        h = ti >> 12
        lo = ti & 0xFFF
        if not started or h != cur_high:
            k = _advance_time_high(out, k, cur_high if started else np.int64(0), h)
            cur_high = h
            cur_low = -1
            started = True
        if lo != cur_low:
            out[ix(k)] = 0x6000 | lo
            k += 1
            cur_low = lo
        yi = np.int64(y[ix(i)])
        if yi != cur_y:
            out[ix(k)] = yi
            k += 1
            cur_y = yi
        xi = np.int64(x[ix(i)])
        pi = np.int64(p[ix(i)])
        # a vector pays from 3 events of one run (same t, y, p; x increasing) within 12 pixels;
        # t of the event two ahead is the cheapest test that rules it out
        if (i + 2 < n and t[ix(i + 2)] == ti and np.int64(x[ix(i + 2)]) < xi + 12 and t[ix(i + 1)] == ti
                and y[ix(i + 1)] == yi and y[ix(i + 2)] == yi and p[ix(i + 1)] == pi and p[ix(i + 2)] == pi
                and x[ix(i + 1)] > xi and x[ix(i + 2)] > x[ix(i + 1)]):
            out[ix(k)] = 0x3000 | (pi << 11) | xi
            k += 1
            base = xi
            m = i
            while True:
                mask = 1 << (np.int64(x[ix(m)]) - base)
                m += 1
                while (m < n and t[ix(m)] == ti and np.int64(x[ix(m)]) < base + 12
                       and y[ix(m)] == yi and p[ix(m)] == pi and x[ix(m)] > x[ix(m - 1)]):
                    mask |= 1 << (np.int64(x[ix(m)]) - base)
                    m += 1
                out[ix(k)] = 0x4000 | mask
                k += 1
                base += 12
                if not (m < n and t[ix(m)] == ti and np.int64(x[ix(m)]) < base + 12
                        and y[ix(m)] == yi and p[ix(m)] == pi and x[ix(m)] > x[ix(m - 1)]):
                    break
            i = m
        else:
            out[ix(k)] = 0x2000 | (pi << 11) | xi
            k += 1
            i += 1
    state[0] = 1 if started else 0
    state[1] = cur_high
    state[2] = cur_low
    state[3] = cur_y
    return k


@njit(cache=True, nogil=True)
def _encode_packets_kernel(t, x, y, p, bounds, high, out, ends):
    """Packets j = events bounds[j]:bounds[j+1], each on the sensor clock as `packets.evt3_sensor_clock`
    writes one: a TIME_HIGH word where the previous packet left the clock (`high`: its absolute time-high,
    -1 before the first packet: the first event's own), then the events from there. Word ends in `ends`.
    Returns the number of packets written; fewer when packet j cannot be (no event, a time before 0 or going
    back, x or y >= 2048, p > 1, or not room enough in `out` for its worst case): the caller then writes from j
    one by one, which says why. One call for a batch's packets: the GIL is given up once, not per packet."""
    m = len(bounds) - 1
    k = 0
    state = np.empty(4, np.int64)
    for j in range(m):
        a = bounds[ix(j)]
        b = bounds[ix(j + 1)]
        if b <= a:  # no event: its first and last would be read from outside it
            return j
        t0 = t[ix(a)]
        if t0 < 0:
            return j
        h = t0 >> 12 if high < 0 else high
        if h > t0 >> 12:
            return j
        t_last = t[ix(b - 1)]
        wraps = (t_last >> 24) - ((h << 12) >> 24)
        if wraps > MAX_WRAPS_PER_CALL:
            return j
        ramp = 5 * (wraps + 1) + ((t_last >> 12) - h) // _MAX_HIGH_STEP + 2
        if k + 1 + 4 * (b - a) + ramp > len(out):
            return j
        out[ix(k)] = 0x8000 | (h & 0xFFF)
        k += 1
        state[0] = 1
        state[1] = h
        state[2] = -1
        state[3] = -1
        n = _encode_kernel(t[a:b], x[a:b], y[a:b], p[a:b], out[k:], state, h << 12)
        if n < 0:
            return j
        k += n
        ends[ix(j)] = k
        high = t_last >> 12
    return m


class Evt3Encoder:
    """Streaming EVT3 encoder: successive `encode` calls continue one stream (time base, row).

    The first call's bytes start with TIME_HIGH, TIME_LOW and ADDR_Y; later calls only add what changed,
    so the concatenation of all outputs decodes to all events. Timestamps must not go back across calls.
    """

    def __init__(self):
        self.state = np.array([0, 0, -1, -1], np.int64)
        self.last_t = 0
        self.events_in = 0
        self._scratch = np.empty(0, np.uint16)  # reused between calls: no fresh pages per chunk

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
        t_last = int(t[-1])
        wraps = (t_last >> 24) - (self.last_t >> 24)
        if wraps > MAX_WRAPS_PER_CALL:
            raise ValueError(
                f"encode: timestamps jump from {self.last_t} to {t_last} µs ({wraps:,} wraps of the 24-bit "
                "clock, 5 words each): subtract a time origin first (RAW writers keep it in the header)")
        # room: 4 words per event at most, plus TIME_HIGH steps over long gaps (bounded by the span)
        ramp = max(0, 5 * (wraps + 1) + ((t_last >> 12) - (self.last_t >> 12)) // _MAX_HIGH_STEP + 2)
        if len(self._scratch) < 4 * n + ramp:
            self._scratch = np.empty(4 * n + ramp, np.uint16)
        out = self._scratch
        k = _encode_kernel(t, x, y, p, out, self.state, np.int64(self.last_t))
        if k < 0:
            bad = -1 - k
            prev = t[bad - 1] if bad else self.last_t
            raise ValueError(
                f"encode: event {self.events_in + bad} (t={t[bad]} µs, previous {prev} µs, x={x[bad]}, "
                f"y={y[bad]}, p={p[bad]}) cannot be written: EVT3 needs non-decreasing t >= 0, x and y "
                "< 2048, p 0 or 1"
            )
        self.last_t = t_last
        self.events_in += n
        return out[:k].tobytes()


def encode(t, x, y, p) -> bytes:
    """EVT3 bytes (no header) for events with non-decreasing t ≥ 0 µs and x, y < 2048.

    Self-contained: starts with TIME_HIGH, TIME_LOW and ADDR_Y words; timestamps past 2^24 µs are
    reached by TIME_HIGH steps from 0, so `decode(encode(...))` returns the events exactly, in order.
    Runs of ≥ 3 events with the same t, y, p and increasing x within 12 pixels go into vector words.
    """
    return Evt3Encoder().encode(t, x, y, p)
