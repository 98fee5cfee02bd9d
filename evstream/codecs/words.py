"""Blocks of bytes as whole words, for the EVT2 and EVT3 decoders: a block may end inside a word, and
that word's first bytes wait for the next block."""

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
