"""`ix(i)`: an array index numba compiles without negative-index wraparound.

numba indexes with Python semantics: a signed index gets a sign test and a fix-up (three instructions
and a register) on every access, which LLVM can rarely prove away in a streaming kernel. An unsigned
index skips it. On the paper's cascade this alone measured +40 % (30 -> 42 M events/s at 346×260).
Use it only where the index is non-negative by construction: a negative one is not wrapped, it reads
out of bounds.
"""

import numpy as np

from .jit import njit


@njit(cache=True, nogil=True, inline="always")
def ix(i):
    """`i` (>= 0) as an unsigned index."""
    return np.uintp(i)
