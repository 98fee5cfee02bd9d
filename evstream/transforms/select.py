"""Transforms that drop events by what they are or when they happen: polarity selection, a time range,
and the event-rate limiter (a token bucket in event time).

`rate_limit`: a bucket holding at most `burst_events` tokens refills at `rate_hz` tokens per second of
event time; an event passes when a whole token is there (and takes it), else it is dropped and counted.
So any interval of event time T passes at most `burst_events + rate_hz·T` events: a flooding sensor is
capped, a quiet one passes everything. The tokens are kept in integer units of 1/1e6 event
(rate_hz·1 µs each microsecond), so the decisions are exact and the same for any chunking. The stage
counts what it saw and dropped (`passed`, `dropped`, `report()`). Memory: two integers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..events import EventChunk, shown
from ..jit import njit
from ..pipeline import register
from .base import Transform, select, select_flagged

UNIT = 1_000_000  # token units per event: a rate in events/s adds rate_hz units per µs


@register("stage", "polarity")
@dataclass(eq=False)
class Polarity(Transform):
    """Keep the events of one polarity: `keep` "on" (p = 1) or "off" (p = 0)."""

    keep: str = "on"
    drops_events = True

    def __post_init__(self):
        if self.keep not in ("on", "off"):
            raise ValueError(f"polarity: keep must be 'on' or 'off', got {shown(self.keep)}")

    def __call__(self, chunk: EventChunk) -> EventChunk:
        return select_flagged(chunk, chunk.p if self.keep == "on" else chunk.p ^ np.uint8(1))


@register("stage", "time_range")
@dataclass(eq=False)
class TimeRange(Transform):
    """Keep the events with `start_us` <= t < `end_us` (either None: open on that side)."""

    start_us: int | None = None
    end_us: int | None = None
    drops_events = True

    def __post_init__(self):
        for name in ("start_us", "end_us"):
            v = getattr(self, name)
            if v is not None:
                if isinstance(v, float) and v.is_integer():
                    v = int(v)
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                    raise ValueError(f"time_range: {name} must be a whole number of µs, got {shown(v)}")
                setattr(self, name, int(v))
        if self.start_us is not None and self.end_us is not None and self.end_us <= self.start_us:
            raise ValueError(f"time_range: end_us ({self.end_us}) must be after start_us ({self.start_us})")

    def __call__(self, chunk: EventChunk) -> EventChunk:
        a = 0 if self.start_us is None else int(np.searchsorted(chunk.t, self.start_us, side="left"))
        b = len(chunk) if self.end_us is None else int(np.searchsorted(chunk.t, self.end_us, side="left"))
        if a == 0 and b == len(chunk):
            return chunk
        return select(chunk, slice(a, max(a, b)), chunk.geometry)


@njit(cache=True, nogil=True)
def token_bucket(t, state, rate_hz, capacity, flags):
    """Token bucket over events in time order. `state` = [tokens, last_t, started] (tokens in 1/UNIT
    events). Sets flags[i] to 1 for the events that pass, 0 for the others; returns how many pass."""
    tokens = state[0]
    last_t = state[1]
    if state[2] == 0 and len(t):
        last_t = t[0]
        state[2] = 1
    k = 0
    for i in range(len(t)):
        dt = t[i] - last_t
        last_t = t[i]
        if tokens < capacity:  # refill; dt * rate can be huge after a pause: cap before adding
            room = capacity - tokens
            tokens = capacity if dt >= room // rate_hz + 1 else tokens + dt * rate_hz
            if tokens > capacity:
                tokens = capacity
        ok = tokens >= UNIT
        tokens -= UNIT * ok
        flags[i] = ok
        k += ok
    state[0] = tokens
    state[1] = last_t
    return k


@register("stage", "rate_limit")
@dataclass(eq=False)
class RateLimit(Transform):
    """Cap the event rate: a token bucket of `burst_events` refilled at `rate_hz` events per second of
    event time (default burst: 10 ms at that rate, at least 1). Drops the excess and counts it."""

    rate_hz: float = 1e6
    burst_events: int | None = None
    drops_events = True
    passed: int = field(default=0, init=False)
    dropped: int = field(default=0, init=False)

    def __post_init__(self):
        r = self.rate_hz
        if isinstance(r, bool) or not isinstance(r, (int, float, np.number)) or not math.isfinite(r) or r < 1:
            raise ValueError(f"rate_limit: rate_hz must be a finite number >= 1 event/s, got {shown(r)}")
        self.rate_hz = r
        if self.burst_events is None:
            self.burst_events = max(1, round(r * 0.01))
        b = self.burst_events
        if isinstance(b, bool) or not isinstance(b, (int, np.integer)) or b < 1:
            raise ValueError(f"rate_limit: burst_events must be an integer >= 1, got {shown(b)}")
        self.burst_events = int(b)
        self._rate_units = round(r)  # units of 1/UNIT event per µs: events/s, to the nearest whole
        self._capacity = self.burst_events * UNIT
        self._state = np.array([self._capacity, 0, 0], np.int64)  # a full bucket at the start

    def __call__(self, chunk: EventChunk) -> EventChunk:
        n = len(chunk)
        flags = np.empty(n, np.uint8)
        k = token_bucket(chunk.t, self._state, self._rate_units, self._capacity, flags)
        self.passed += k
        self.dropped += n - k
        return chunk if k == n else select_flagged(chunk, flags)

    def report(self) -> str:
        seen = self.passed + self.dropped
        share = 100 * self.dropped / seen if seen else 0.0
        return (f"rate_limit {self.rate_hz:g} ev/s: dropped {self.dropped:,} of {seen:,} events "
                f"({share:.1f} %)")


class TimeRangeSource:
    """The events of `source` with `start_us` <= t < `end_us` (None: open on that side), as a source.

    A reader that can seek (it has `set_time_range(start_us, end_us)` and returns True: RAW EVT 2/3, .npy, .mat,
    native .npz with a seek index, evstream MCAP archives) starts at the range itself, with the events reading from
    the start would give; any other is decoded from its start. Either way the range is filtered here. Either way
    reading stops at the first chunk whose watermark reaches `end_us` (nothing later can be in range), and the last
    chunk's watermark is capped at `end_us`, so no frame past the range is closed by the watermark. Every other
    attribute (geometry, fraction_read, info) is the source's."""

    def __init__(self, source, start_us: int | None = None, end_us: int | None = None):
        self._range = TimeRange(start_us, end_us)
        self.source = source
        self.start_us, self.end_us = self._range.start_us, self._range.end_us
        seek = getattr(source, "set_time_range", None)
        self.seeks = bool(callable(seek) and seek(self.start_us, self.end_us))

    def __getattr__(self, name):
        return getattr(self.source, name)

    def __iter__(self):
        end = self.end_us
        started = False
        span = None  # the first and last times read, for the warning below
        failed = False
        try:
            for chunk in self.source:
                if len(chunk):
                    span = (int(chunk.t[0]) if span is None else span[0], int(chunk.t[-1]))
                out = self._range(chunk)
                done = end is not None and chunk.t_end >= end
                if done and out.t_end > end:
                    out = out.replace(t_end=end)
                if len(out) or started:
                    started = True
                    yield out
                if done:
                    return
        except Exception:
            failed = True  # the error is the news (a damaged file), not an empty range
            raise
        finally:
            if not started and not failed and (span is not None or self.seeks):
                self._warn_empty(span)

    def _warn_empty(self, span) -> None:
        """An empty range is most often a typo or a time in the wrong unit or origin (a recording's times
        may be since 1970): said once, in one line, instead of an empty output without a word."""
        import warnings

        where = getattr(self.source, "path", None)
        lo = "" if self.start_us is None else f"{self.start_us} <= "
        hi = "" if self.end_us is None else f" < {self.end_us}"
        read = f"; the events read run from {span[0]} to {span[1]} µs" if span is not None else ""
        warnings.warn(f"{where + ': ' if where else ''}no event in the time range {lo}t{hi} µs "
                      f"(start_us/end_us, --start-us/--end-us){read}", UserWarning, stacklevel=3)
