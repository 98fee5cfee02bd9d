"""`njit` and `intrinsic` as numba's, but lazy: a command whose kernels were compiled ahead of time never
imports numba.

Importing numba and loading its first cached kernel costs ≈ 0.4 s of CPU (numba initialises its whole
compiler, lowering library included, before it reads its cache): most of a command's start-up. A kernel
here is a `Kernel`. Called from Python, it runs the function of `evstream._aot` — the commands' kernels,
compiled ahead of time on this machine by `python -m evstream.aot` (`make .venv/.installed`) — when that
module holds this kernel for these argument types (dtype, dimensions, C order, writeable, aligned) and was
built from the sources as they are (size and time of every file); otherwise numba's dispatcher, made on
first use with the same options (and numba's on-disk cache, as before). Inside other kernels numba sees
the dispatcher (`typeof` below) and inlines `inline="always"` kernels as before (it reads `py_func` and
`targetoptions`).

EVSTREAM_AOT=0 (or `use_aot(False)`) leaves the ahead-of-time module aside: A/B runs, tests. With
NUMBA_DISABLE_JIT=1 these are numba's own objects, so kernels run as plain Python (tests/mutation.py).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.machinery
import importlib.util
import json
import os
import signal
import sys
import threading
import weakref
from pathlib import Path

import numpy as np

from . import _start

_LOCK = threading.RLock()
KERNELS: weakref.WeakSet = weakref.WeakSet()  # every Kernel made (evstream.aot picks the ones the commands call)
AOT_INDEX = Path(__file__).with_name("_aot.json")  # beside the module `evstream._aot` (both built, not in git)
_FLAGS = 0x1 | 0x100 | 0x400  # NPY_ARRAY_C_CONTIGUOUS | ALIGNED | WRITEABLE: what numba's array type records
_SCALARS = {t: np.dtype(t) for t in (np.bool_, np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16,
                                     np.uint32, np.uint64, np.float32, np.float64)}
_ARRAY = np.ndarray
_SCALARS.update({bool: np.dtype(np.bool_), int: np.dtype(np.int64), float: np.dtype(np.float64)})


def _plain() -> bool:
    return os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")


def njit(fn=None, **options):
    """`numba.njit(**options)`, compiled on first use or served ahead of time (module docstring)."""
    if _plain():
        import numba

        return numba.njit(fn, **options) if fn is not None else numba.njit(**options)
    if fn is None:
        return functools.partial(njit, **options)
    return Kernel(fn, options)


def intrinsic(definition):
    """`numba.extending.intrinsic(definition)`, made when numba first needs it."""
    if _plain():
        from numba.extending import intrinsic as numba_intrinsic

        return numba_intrinsic(definition)
    return Intrinsic(definition)


def arg_key(a):
    """What numba's type of argument `a` depends on, as the ahead-of-time index writes it (`aot.arg_key`)."""
    if type(a) is _ARRAY:
        return a.dtype, a.ndim, a.flags.num & _FLAGS
    return _SCALARS.get(type(a), type(a))


class Kernel:
    """One numba kernel: `kernel(*args)` runs it; `.dispatcher` is numba's (made on first use)."""

    def __init__(self, py_func, options: dict):
        functools.update_wrapper(self, py_func)
        self.py_func = py_func
        self.targetoptions = dict(options)
        self._dispatcher = None
        self.key = kernel_key(py_func)
        self.jit_calls = 0  # calls numba's dispatcher served (the others: the ahead-of-time module)
        KERNELS.add(self)
        self.aot = aot_table(self.key)  # {argument keys: compiled function}; empty without the module

    def __call__(self, *args):
        if self.aot:  # arg_key, inline (a call per argument would double the cost: ~0.2 µs an argument)
            fn = self.aot.get(tuple([(a.dtype, a.ndim, a.flags.num & _FLAGS) if type(a) is _ARRAY
                                     else _SCALARS.get(type(a), type(a)) for a in args]))
            if fn is not None:
                return fn(*args)
        self.jit_calls += 1
        return self.dispatcher(*args)

    def bind(self, head: int, fixed: tuple) -> Bound:
        """`call(*args)` running `self(*args[:head], *fixed, *args[head:])` (module function `bind`)."""
        return Bound(self, head, fixed)

    @property
    def dispatcher(self):
        if self._dispatcher is None:
            with _LOCK:
                if self._dispatcher is None:
                    _say_stale()
                    self._dispatcher = _numba().njit(**self.targetoptions)(self.py_func)
        return self._dispatcher

    def __repr__(self):
        return f"Kernel({self.key})"

    def __reduce__(self):
        """Pickled as its key: numba hashes a kernel's closure values into its cache's index, and a kernel
        factory may close over another kernel (the same key, the same compiled code)."""
        if self.key is None:
            raise TypeError(f"{self.py_func.__qualname__}: a kernel without a key cannot be pickled")
        return _kernel_by_key, (self.key,)


def _kernel_by_key(key: str) -> Kernel:
    """The live kernel of this key (`Kernel.__reduce__`)."""
    for kernel in list(KERNELS):
        if kernel.key == key:
            return kernel
    raise LookupError(f"no kernel {key} in this process")


class Bound:
    """A kernel with its middle arguments fixed (a stage's state arrays and parameters), their types keyed
    once: a call keys only the arguments it passes (about 0.2 µs each; a stage's ~20 arguments would
    otherwise cost more per call than the dispatch itself). The functions of the ahead-of-time module
    for these fixed types are looked up by the passed arguments' types alone, each dtype by its identity
    (a dtype hashes in ~0.1 µs, not cached, and tuples of them are hashed at every look-up): a dtype equal
    to a built-in one but another object misses and goes to numba, as any type not compiled ahead."""

    __slots__ = ("kernel", "head", "fixed", "fixed_key", "_aot", "_table")

    def __init__(self, kernel: Kernel, head: int, fixed: tuple):
        self.kernel, self.head, self.fixed = kernel, head, tuple(fixed)
        self.fixed_key = tuple(arg_key(a) for a in self.fixed)
        self._aot, self._table = None, {}

    def __call__(self, *args):
        kernel, h = self.kernel, self.head
        aot = kernel.aot
        if aot:
            if self._aot is not aot:  # kernel.aot is replaced, never changed in place (use_aot, tests)
                self._table = self.table(aot)
                self._aot = aot
            fn = self._table.get(tuple([(id(a.dtype), a.ndim, a.flags.num & _FLAGS) if type(a) is _ARRAY
                                        else id(_SCALARS.get(type(a), type(a))) for a in args]))
            if fn is not None:
                return fn(*args[:h], *self.fixed, *args[h:])
        kernel.jit_calls += 1
        return kernel.dispatcher(*args[:h], *self.fixed, *args[h:])

    def table(self, aot: dict) -> dict:
        """{the passed arguments' keys, dtypes by identity: function} of `aot`'s entries for the fixed types."""
        h, n = self.head, len(self.fixed_key)
        by_id = lambda k: (id(k[0]), k[1], k[2]) if isinstance(k, tuple) else id(k)  # noqa: E731
        return {tuple(map(by_id, key[:h] + key[h + n :])): fn for key, fn in aot.items()
                if key[h : h + n] == self.fixed_key}


def bind(kernel, head: int, fixed: tuple):
    """`call(*args)` = `kernel(*args[:head], *fixed, *args[head:])`: a `Bound` for a `Kernel`; for numba's own
    dispatcher (NUMBA_DISABLE_JIT=1) or a plain function, the same call without the keying."""
    if isinstance(kernel, Kernel):
        return kernel.bind(head, fixed)
    fixed = tuple(fixed)
    return lambda *args: kernel(*args[:head], *fixed, *args[head:])


class Intrinsic:
    """A numba intrinsic, defined when a kernel using it is first compiled."""

    def __init__(self, definition):
        functools.update_wrapper(self, definition)
        self._definition = definition
        self._real = None

    @property
    def real(self):
        if self._real is None:
            with _LOCK:
                if self._real is None:
                    _numba()
                    from numba.extending import intrinsic as numba_intrinsic

                    self._real = numba_intrinsic(self._definition)
        return self._real


@functools.cache
def _numba():
    """numba, taught to type `Kernel` and `Intrinsic` objects met inside kernels as what they stand for."""
    with _LOCK:
        import numba
        from numba.core import types
        from numba.core.registry import cpu_target
        from numba.core.typing.typeof import typeof_impl

        @typeof_impl.register(Kernel)
        def _typeof_kernel(val, c):
            return types.Dispatcher(val.dispatcher)

        @typeof_impl.register(Intrinsic)
        def _typeof_intrinsic(val, c):
            real = val.real
            cpu_target.typing_context.refresh()  # installs the intrinsic's typing template
            return cpu_target.typing_context.resolve_value_type(real)

        from numba.core.compiler_lock import global_compiler_lock

        hold_ctrl_c_while_compiling(global_compiler_lock)
        return numba


def hold_ctrl_c_while_compiling(lock) -> None:
    """While the main thread holds numba's compiler lock, a SIGINT's Python handler waits until the outermost
    compile has released it. A KeyboardInterrupt raised inside the compiler could leave llvmlite owning a
    module LLVM had already freed (after `LLVMPY_LinkModules`, before `detach`: `free(): double free` at
    exit, 1 in ~25 interrupted `eval`s), or land in a ctypes callback that drops it (the command ran on).
    Other threads' compiles are not interrupted by a Python handler (it runs in the main thread)."""
    acquire, release = lock.acquire, lock.release
    held = {"depth": 0, "handler": None, "signum": None}

    def wait(signum, frame):
        held["signum"] = signum

    def acquire_held():
        acquire()
        if threading.current_thread() is threading.main_thread():
            held["depth"] += 1
            if held["depth"] == 1 and callable(handler := signal.getsignal(signal.SIGINT)):
                held["handler"], held["signum"] = handler, None
                signal.signal(signal.SIGINT, wait)

    def release_held():
        handler = None
        if threading.current_thread() is threading.main_thread() and held["depth"]:
            held["depth"] -= 1
            if held["depth"] == 0:
                handler, held["handler"] = held["handler"], None
        release()
        if handler is not None:
            if signal.getsignal(signal.SIGINT) is wait:  # not replaced meanwhile
                signal.signal(signal.SIGINT, handler)
            if held["signum"] is not None:
                signum, held["signum"] = held["signum"], None
                handler(signum, None)  # KeyboardInterrupt now, outside the compiler

    lock.acquire, lock.release = acquire_held, release_held


def kernel_key(py_func) -> str | None:
    """`module:qualname`, plus the values a kernel factory's closure fixes (None: not a plain value)."""
    key = f"{py_func.__module__}:{py_func.__qualname__}"
    cells = py_func.__closure__ or ()
    values = []
    for cell in cells:
        v = cell.cell_contents
        if isinstance(v, Kernel):  # a kernel calling another kernel its factory was given: that one's key
            if v.key is None:
                return None
            v = v.key
        if not _plain_value(v):
            return None
        values.append(v)
    return key + (repr(tuple(values)) if cells else "")


def _plain_value(v) -> bool:
    if isinstance(v, tuple):
        return all(map(_plain_value, v))
    return v is None or type(v) in (bool, int, float, str)


_USE_AOT = [os.environ.get("EVSTREAM_AOT", "1").lower() not in ("0", "no", "off", "false")]


def use_aot(on: bool) -> None:
    """Serve kernels from the ahead-of-time module when it has them (on: the default unless EVSTREAM_AOT=0),
    or always from numba (A/B runs, tests, `evstream.aot` recording what numba compiles)."""
    _USE_AOT[0] = on
    for kernel in list(KERNELS):
        kernel.aot = aot_table(kernel.key)


def aot_table(key: str | None) -> dict:
    if key is None or not _USE_AOT[0]:
        return {}
    return _aot_index().get(key, {})


@functools.cache
def _aot_index() -> dict:
    return {} if _plain() else load_aot(AOT_INDEX)


_MODULES: list = []  # the ahead-of-time modules loaded (kept alive)
_STALE: list = []  # the note on a module older than the sources (load_aot), until said or dropped
_QUIET = [False]


@contextlib.contextmanager
def quiet_notes(quiet: bool = True):
    """No note on stderr inside (a command's `--quiet`): the one on a stale module is dropped, not kept."""
    before = _QUIET[0]
    _QUIET[0] = quiet
    try:
        yield
    finally:
        _QUIET[0] = before


def _say_stale() -> None:
    """The note of a module older than the sources, once, when numba is about to compile a kernel (not at
    import: a command has not read its `--quiet` yet, and one that compiles nothing has nothing to say).
    Only to a person at a terminal, and not from a batch's worker (its command says it once)."""
    note = _STALE.pop() if _STALE else None
    if note and not _QUIET[0] and sys.stderr is not None and sys.stderr.isatty() and not _start._a_spawned_worker():
        print(note, file=sys.stderr)


def load_aot(index_path: Path) -> dict:
    """{kernel key: {argument keys: function}} of `evstream._aot` as `index_path` describes it, or {} when
    either is missing, they were built from other sources than these, the module file is not the one the
    index was written for (truncated, damaged, another build's), or the CPU or Python is not the one it was
    built for (then numba compiles, as without). The module is checked before it is loaded: loading a cut-short or
    damaged shared object kills the process (SIGBUS, SIGILL), it raises no ImportError."""
    try:
        index = json.loads(index_path.read_text())
        if index["package"] != str(Path(__file__).resolve().parent):  # a copy of the tree (tests/mutation.py)
            return {}
        changed = changed_sources(index["sources"])
        if changed or index["cpu"] != cpu_id():
            if changed:  # said when numba first compiles (_say_stale), if to a person at a terminal
                first = os.path.relpath(changed[0], Path(index["package"]).parent)
                more = f" and {len(changed) - 1} more file{'s' if len(changed) > 2 else ''}" if len(changed) > 1 else ""
                _STALE[:] = [f"evstream: note: {first}{more} changed since the kernels were compiled ahead of time: "
                             "numba compiles them instead (seconds at first use); `make aot` rebuilds them"]
            return {}
        if not index["module"].endswith(importlib.machinery.EXTENSION_SUFFIXES[0]):
            return {}  # built for another Python (its ABI in the name): loaded by path, it would not be refused
        module_path = index_path.with_name(index["module"])
        if file_digest(module_path) != index["module_sha256"]:
            return {}
        spec = importlib.util.spec_from_file_location("evstream._aot", module_path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _MODULES.append(module)  # alive as long as the process, as an imported module (sys.modules)
        return {key: {_decode(arg_keys): getattr(module, symbol) for symbol, arg_keys in entries}
                for key, entries in index["kernels"].items()}
    except (OSError, ValueError, KeyError, TypeError, ImportError, AttributeError):
        return {}


def file_digest(path: Path) -> str:
    """SHA-256 of a file (≈ 0.7 ms for the module's 0.8 MB)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def cpu_id() -> str:
    """What the module's machine code depends on (it is compiled for the host CPU): the CPU's model and
    instruction-set flags from /proc/cpuinfo (first processor), and the machine's name."""
    try:
        with open("/proc/cpuinfo") as f:
            first = f.read().split("\n\n")[0]
    except OSError:
        first = ""
    keys = ("vendor_id", "cpu family", "model", "model name", "flags", "Features", "CPU implementer",
            "CPU architecture", "CPU variant", "CPU part")
    fields = [line for line in first.splitlines() if line.split(":")[0].strip() in keys]
    machine = os.uname().machine if hasattr(os, "uname") else ""
    return hashlib.sha256("\n".join([machine, *fields]).encode()).hexdigest()[:16]


def source_stamps(paths) -> dict[str, list[int]]:
    """{path: [size, mtime in ns]} of source files (absolute paths: the module is built for this checkout)."""
    stamps = {}
    for path in paths:
        st = os.stat(path)
        stamps[str(path)] = [st.st_size, st.st_mtime_ns]
    return stamps


def changed_sources(stamps: dict) -> list[str]:
    """The files of `stamps` ({path: [size, mtime in ns]}) whose size or time is not that now, or gone."""
    return [path for path, stamp in stamps.items()
            if not os.path.exists(path) or source_stamps([path])[path] != stamp]


def _decode(arg_keys: list) -> tuple:
    """Argument keys as written in the index (`aot.arg_key`) back to `arg_key`'s form."""
    return tuple((np.dtype(k[0]), k[1], k[2]) if isinstance(k, list) else np.dtype(k) for k in arg_keys)
