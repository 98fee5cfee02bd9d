"""Chunks cut so that a framer never hands on more frames at once than `FRAMES_BYTES` hold.

A framer returns, from each chunk, every frame the chunk closes, each with arrays of its own (two uint16
count planes; a representation's float32 channels too). So the frames of one chunk took memory in
proportion to how many windows it spans: `evstream frames REC --framer fw --window-us 1` made ~140,000
frames of 346x260 from one 50,000-event chunk and was killed by the kernel at 20 GB; a 30 s pause before
a chunk made 1,000 time surfaces of 640x480 at once (2.5 GB; a representation's empty windows have
arrays too). `cut` hands the framer each chunk in pieces that span at most `frames_at_once` frame steps
of event time (`frame_step`: a window's least advance) and hold at most that many frames' worth of
events, and crosses a pause in empty pieces until the framer stops emitting empty frames
(`max_empty_frames`): the frames come out in batches of bounded size. Framers are chunk-invariant, so
they are the same frames. A chunk that closes fewer frames passes as it is (as with every default).
"""

from __future__ import annotations

import math

import numpy as np

from ..events import EventChunk

FRAMES_BYTES = 64 << 20  # the frames one piece may close, at most (about)
DEFAULT_MAX_EMPTY = 1000  # the windowing framers' max_empty_frames default


def frames_at_once(framer, n_pixels: int, budget_bytes: int = FRAMES_BYTES) -> int:
    """How many of `framer`'s frames of `n_pixels` fit in `budget_bytes` (at least 1)."""
    return max(1, budget_bytes // max(1, framer.frame_bytes(n_pixels)))


def cut(chunks, framer, budget_bytes: int = FRAMES_BYTES):
    """`chunks` (EventChunks in stream order) as pieces from which `framer` closes at most about
    `frames_at_once` frames each (twice that for fn windows with a time limit, cut by both); the chunks
    themselves when there is no framer or nothing to bound."""
    step_us, step_events = framer.frame_step() if framer is not None else (None, None)
    if step_us is None and step_events is None:
        yield from chunks
        return
    inner = getattr(framer, "inner", framer)
    gap_pieces = None
    mark = None  # the watermark handed on last; the frames start at the first event
    empty_run = 0  # empty pieces handed on in a row (a pause)
    for chunk in chunks:
        n = len(chunk)
        if mark is None:
            if not n:
                yield chunk
                continue
            mark = int(chunk.t[0])
            k = frames_at_once(framer, chunk.geometry.n_pixels, budget_bytes)
            max_us = None if step_us is None else k * step_us
            max_events = None if step_events is None else k * step_events
            # a pause's empty frames come every pause_step_us: enough steps that the framer has stopped
            # emitting them (max_empty_frames) before the jump to the next event
            max_empty = getattr(inner, "max_empty_frames", None)
            max_empty = DEFAULT_MAX_EMPTY if max_empty is None else max_empty
            pause_us = framer.pause_step_us() or step_us or 1
            gap_pieces = math.ceil(max_empty * pause_us / max_us) + 1 if max_us else 0
        t, i = chunk.t, 0
        end_of_chunk = max(int(chunk.t_end), int(t[-1])) if n else int(chunk.t_end)
        while i < n or mark < end_of_chunk:
            if max_us is not None and empty_run >= gap_pieces:  # the framer skips empty frames by now
                nxt = int(t[i]) if i < n else end_of_chunk
                if nxt > mark:  # on to the next event at once
                    yield EventChunk.empty(chunk.geometry, nxt, with_cls=chunk.cls is not None,
                                           with_label=chunk.label is not None)
                    mark = nxt
                empty_run = 0
                continue
            limit = None if max_us is None else mark + max_us
            j = n if limit is None else i + int(np.searchsorted(t[i:], limit, side="left"))
            if max_events is not None:
                j = min(j, i + max_events)
            end = int(t[j]) if j < n else end_of_chunk
            if limit is not None:
                end = min(end, limit)
            if j > i:
                end = max(end, int(t[j - 1]))
                whole = i == 0 and j == n and end == end_of_chunk
                yield chunk if whole else chunk[i:j].replace(t_end=end)
                empty_run = 0
            else:  # a pause: its frames in steps until the framer stops emitting empty ones
                yield EventChunk.empty(chunk.geometry, end, with_cls=chunk.cls is not None,
                                       with_label=chunk.label is not None)
                empty_run += 1
            i, mark = j, max(mark, end)


class Cut:
    """A source (or any iterable of chunks) read through `cut`; its other attributes (geometry, path,
    fraction_read, ...) are the source's."""

    def __init__(self, source, framer):
        self.source, self.framer = source, framer

    def __iter__(self):
        return cut(self.source, self.framer)

    def __getattr__(self, name):
        if name in ("source", "framer"):
            raise AttributeError(name)
        return getattr(self.source, name)
