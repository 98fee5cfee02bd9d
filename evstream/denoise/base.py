"""What every denoise stage shares: classify the events still SIGNAL, write `cls`, never drop."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..events import EventChunk, NoiseClass


def fifo_capacity(entries: int) -> int:
    """A FIFO's first capacity: 4,096, or the power of two >= `entries` (what a stage's window holds on a
    large sensor), so that a fresh stage grows it once or twice, not five or six times (each: the kernel
    returns, the ring is copied, the call resumes; ~2 ns/event of a fresh cascade's first 1.4 M events at
    1280×720)."""
    return max(1 << 12, 1 << (max(1, int(entries)) - 1).bit_length())


def grow_fifo(state: dict, keys: tuple[str, ...], state_key: str = "fifo_state", record: int = 1) -> None:
    """Double the FIFO rings `state[k]` a kernel fills (it returns early when they are full), unrolling
    them so that the head is at 0; `state[state_key]` starts with [head, size], both counted in records
    of `record` consecutive cells (a ring of (time, entry) pairs: 2)."""
    head, size = (int(v) for v in state[state_key][:2])
    cap = len(state[keys[0]]) // record
    first = min(size, cap - head)  # from the head to the ring's end, then the rest from its start
    for k in keys:
        old, new = state[k], np.zeros(2 * cap * record, state[k].dtype)
        new[: first * record] = old[head * record : (head + first) * record]  # two copies: a gather
        new[first * record : size * record] = old[: (size - first) * record]  # by index took ~0.4 ms a grow
        state[k] = new
    state[state_key][:2] = (0, size)


class Classifier:
    """Base of denoise stages (subclasses are dataclasses holding parameters and state).

    A stage sees only the events its input still classes SIGNAL, so stages in a pipeline form a
    cascade: later stages judge (and learn from) what earlier ones kept. Subclasses implement
    `classify(chunk) -> uint8 class codes` for that sub-stream, and `score(chunk)` where they can.
    """

    def __call__(self, chunk: EventChunk) -> EventChunk:
        cls = chunk.cls
        if cls is None or not np.count_nonzero(cls):  # all live (the usual first stage): no copy, no gather
            return chunk.with_classes(np.ascontiguousarray(self.classify(chunk), dtype=np.uint8))
        cls = cls.copy()
        live = np.flatnonzero(cls == NoiseClass.SIGNAL)
        if len(live):
            cls[live] = self.classify(chunk[live])
        else:
            self.classify(chunk[live])  # let the stage see the watermark
        return chunk.with_classes(cls)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        raise NotImplementedError

    def params(self) -> dict:
        """The constructor parameters (units in their names), for provenance and TOML round trips."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}


class InPlaceClassifier(Classifier):
    """Base of stages whose kernel classifies in place: `_run(chunk, codes, want_score)` judges the
    events whose `codes` are SIGNAL, writes the class of those it rejects, and returns the scores
    (empty unless `want_score`). No gather of the live events, no copy."""

    def _run(self, chunk: EventChunk, codes: np.ndarray, want_score: bool) -> np.ndarray:
        raise NotImplementedError

    def __call__(self, chunk: EventChunk) -> EventChunk:
        codes = chunk.cls.copy() if chunk.cls is not None else np.zeros(len(chunk), np.uint8)
        self._run(chunk, codes, want_score=False)
        return chunk.with_classes(codes)

    def classify(self, chunk: EventChunk) -> np.ndarray:
        codes = np.zeros(len(chunk), np.uint8)
        self._run(chunk, codes, want_score=False)
        return codes

    def classify_scored(self, chunk: EventChunk) -> tuple[np.ndarray, np.ndarray]:
        """Class codes and per-event scores of an unclassified chunk (see the subclass for the score)."""
        codes = np.zeros(len(chunk), np.uint8)
        return codes, self._run(chunk, codes, want_score=True)
