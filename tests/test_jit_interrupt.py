"""Ctrl-C while numba compiles a kernel (evstream.jit): the KeyboardInterrupt comes once the compile is over.

Raised inside numba's compiler it could leave llvmlite owning a module LLVM had already freed (`eval`
aborted once in ~25 Ctrl-C runs: `free(): double free detected in tcache 2`), or land in a ctypes callback
that prints "Exception ignored" and drops it (the command then ran to its end, exit 0, its output written).
Here a real compile in a fresh process and numba cache, the SIGINT raised from inside the compiler."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

KERNEL = """
from evstream.jit import njit


@njit(cache=True)
def add_one(a):
    s = 0
    for v in a:
        s += v + 1
    return s
"""

SCRIPT = """
import signal, sys
import numpy as np
import numba.core.event as ev
from numba.core.compiler_lock import global_compiler_lock
import kmod

fired, inside = [], []


def on_ctrl_c(signum, frame):  # Python's own handler, telling where it ran
    inside.append(global_compiler_lock.is_locked())
    raise KeyboardInterrupt


class CtrlC(ev.Listener):
    def on_start(self, event):
        if not fired and global_compiler_lock.is_locked():  # inside the compiler (not the target's set-up)
            fired.append(1)
            signal.raise_signal(signal.SIGINT)

    def on_end(self, event):
        pass


signal.signal(signal.SIGINT, on_ctrl_c)
ev.register(sys.argv[1], CtrlC())
try:
    kmod.add_one(np.arange(3))
    print("not interrupted")
except KeyboardInterrupt:
    print("interrupted; inside the compiler:", inside)
print(kmod.add_one(np.arange(3)))
"""


@pytest.mark.parametrize("inside", ["numba:compile", "numba:run_pass", "numba:llvm_lock"])
def test_ctrl_c_while_a_kernel_compiles_comes_after_the_compile(tmp_path, inside):
    (tmp_path / "kmod.py").write_text(textwrap.dedent(KERNEL))
    env = dict(os.environ, EVSTREAM_AOT="0", NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", SCRIPT, inside], capture_output=True, text=True, cwd=tmp_path,
                         env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:2] == ["interrupted; inside the compiler: [False]", "6"], out.stdout
    assert out.stderr == ""
