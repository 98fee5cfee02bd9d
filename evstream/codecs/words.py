"""Blocks of bytes as whole words, for the EVT2 and EVT3 decoders: a block may end inside a word, and
that word's first bytes wait for the next block. `WordDecoder` is what the two decoders share."""

from __future__ import annotations

import numpy as np


def as_bytes(data) -> np.ndarray:
    """`data` (bytes, bytearray, memoryview or a numpy array) as a flat uint8 array, without a copy."""
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).view(np.uint8).reshape(-1)
    return np.frombuffer(memoryview(data), np.uint8)


def whole_words(pending: bytes, raw: np.ndarray, word_bytes: int) -> tuple[np.ndarray, bytes]:
    """(the bytes held back from the last block then `raw`, cut to whole words of `word_bytes`; the bytes
    past the last whole word, to hold back for the next block)."""
    if pending:
        raw = np.concatenate((np.frombuffer(pending, np.uint8), raw))
    cut = len(raw) - len(raw) % word_bytes
    return raw[:cut], raw[cut:].tobytes()


COUNTER_NAMES = ("unknown", "trigger", "others", "continued", "time_back", "no_time", "wraps")


class WordDecoder:
    """A streaming decoder of fixed-size words: its kernels' state (an int64 array) and counters, the
    bytes of a word cut by a block's end held back for the next block, and the bytes taken in.

    A subclass names its word (`word`, a numpy dtype), its state's size and last-time slot, and gives
    `decode` and `_skip(words, start_us)` (its skip kernel: the index of the first word from which
    decoding gives every event at or after `start_us`, len(words) when there is none)."""

    word = "<u4"
    n_state = 1
    last_t_slot = 0

    def __init__(self):
        self.state = np.zeros(self.n_state, np.int64)
        self.state[self.last_t_slot] = np.iinfo(np.int64).min
        self._counters = np.zeros(len(COUNTER_NAMES), np.int64)
        self._pending = b""
        self.bytes_in = 0

    @property
    def counters(self) -> dict:
        return {name: int(v) for name, v in zip(COUNTER_NAMES, self._counters)}

    @property
    def pending_bytes(self) -> int:
        """Bytes held back (part of a word) waiting for the next block."""
        return len(self._pending)

    def _words(self, data) -> np.ndarray:
        """`data` after the bytes held back, as whole words; the bytes past the last one held back."""
        raw = as_bytes(data)
        self.bytes_in += len(raw)
        raw, self._pending = whole_words(self._pending, raw, np.dtype(self.word).itemsize)
        return raw.view(self.word)

    def _skip(self, words: np.ndarray, start_us: int) -> int:
        raise NotImplementedError

    def skip_before(self, data, start_us: int) -> bytes | None:
        """Skip ahead to `start_us` without decoding events: follow the decoder's state through the block
        up to the first word from which `decode` gives exactly the events decoding from the start would
        at or after `start_us` (the subclass's `_skip` says which word). Returns the bytes from that word
        on; None when the whole block lies before (part of a word is kept for the next block). Only
        wraps are counted in the words skipped."""
        size = np.dtype(self.word).itemsize
        raw, rest = whole_words(self._pending, as_bytes(data), size)  # no copy when nothing was held back
        self._pending = b""
        i = self._skip(raw.view(self.word), start_us)
        if size * i == len(raw):
            self._pending = rest
            self.bytes_in += len(raw)
            return None
        self.bytes_in += size * i
        return raw[size * i:].tobytes() + rest
