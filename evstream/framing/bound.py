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
A `Pipeline` cuts for its framer this way (a `Cutter` per stream), so every way of running one is bounded.
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
    cutter = Cutter(framer, budget_bytes)
    for chunk in chunks:
        yield from cutter.pieces(chunk)


class Cutter:
    """One stream's chunks cut for `framer`, chunk by chunk (`pieces`): what `cut` does, holding between chunks
    the watermark handed on last and the empty pieces of a pause. `Pipeline` keeps one per stream."""

    def __init__(self, framer, budget_bytes: int | None = FRAMES_BYTES):
        # a framer of the user's own may not say its step, its frames' size or a pause's step: passed whole
        says = all(hasattr(framer, m) for m in ("frame_step", "frame_bytes", "pause_step_us"))
        step = framer.frame_step if says else None
        self.step_us, self.step_events = step() if step is not None else (None, None)
        self.framer, self.budget_bytes = framer, FRAMES_BYTES if budget_bytes is None else budget_bytes
        self.mark = None  # the watermark handed on last; the frames start at the first event
        self.empty_run = 0  # empty pieces handed on in a row (a pause)

    def _first(self, chunk: EventChunk) -> None:
        """The bounds, from the first events' sensor."""
        framer = self.framer
        k = frames_at_once(framer, chunk.geometry.n_pixels, self.budget_bytes)
        self.max_us = None if self.step_us is None else k * self.step_us
        self.max_events = None if self.step_events is None else k * self.step_events
        # a pause's empty frames come every pause_step_us: enough steps that the framer has stopped
        # emitting them (max_empty_frames) before the jump to the next event
        max_empty = getattr(getattr(framer, "inner", framer), "max_empty_frames", None)
        max_empty = DEFAULT_MAX_EMPTY if max_empty is None else max_empty
        pause_us = framer.pause_step_us() or self.step_us or 1
        self.gap_pieces = math.ceil(max_empty * pause_us / self.max_us) + 1 if self.max_us else 0
        self.mark = int(chunk.t[0])

    def pieces(self, chunk: EventChunk):
        """`chunk` in pieces, in order (at least one: an empty chunk behind the watermark is itself)."""
        n = len(chunk)
        if (self.step_us is None and self.step_events is None) or (self.mark is None and not n):
            yield chunk
            return
        if self.mark is None:
            self._first(chunk)
        max_us, max_events, mark = self.max_us, self.max_events, self.mark
        t, i, given = chunk.t, 0, False
        end_of_chunk = max(int(chunk.t_end), int(t[-1])) if n else int(chunk.t_end)
        while i < n or mark < end_of_chunk:
            if max_us is not None and self.empty_run >= self.gap_pieces:  # the framer skips empty frames by now
                nxt = int(t[i]) if i < n else end_of_chunk
                self.empty_run = 0
                if nxt > mark:  # on to the next event at once
                    self.mark = mark = nxt
                    given = True
                    yield EventChunk.empty(chunk.geometry, nxt, with_cls=chunk.cls is not None,
                                           with_label=chunk.label is not None)
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
                piece = chunk if whole else chunk[i:j].replace(t_end=end)
                self.empty_run = 0
            else:  # a pause: its frames in steps until the framer stops emitting empty ones
                piece = EventChunk.empty(chunk.geometry, end, with_cls=chunk.cls is not None,
                                         with_label=chunk.label is not None)
                self.empty_run += 1
            i, mark = j, max(mark, end)
            self.mark = mark
            given = True
            yield piece
        if not given:
            yield chunk
