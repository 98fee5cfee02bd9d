"""Kernels compiled ahead of time (evstream.aot, evstream.jit): on every call the commands make they return
and write what numba's JIT does; they serve only the argument types they were compiled for; the module
is set aside once a source file changes; and a command served by them does not import numba."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from evstream.sources import dat, native, nmnist, prophesee_raw
from hypothesis import given, settings
from hypothesis import strategies as st

from evstream import aot, jit
from evstream.cli import main
from evstream.events import Geometry, _first_invalid
from evstream.testing import random_stream

needs_aot = pytest.mark.skipif(not jit._aot_index(), reason="no evstream._aot built from these sources: run "
                               "`python -m evstream.aot` (make .venv/.installed does)")
G = Geometry(64, 48)


def _same(a, b) -> bool:
    if isinstance(a, tuple):
        return isinstance(b, tuple) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
    return type(a) is type(b) and a == b


class AgainstJit:
    """An ahead-of-time function that also runs numba's dispatcher on copies of the arguments and checks
    that both return the same and leave the same arrays."""

    def __init__(self, kernel: jit.Kernel, fn):
        self.kernel, self.fn, self.calls = kernel, fn, 0

    def __call__(self, *args):
        copies = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
        got = self.fn(*args)
        want = self.kernel.dispatcher(*copies)
        assert _same(got, want), f"{self.kernel}: returned {got!r}, numba {want!r}"
        for i, (a, b) in enumerate(zip(args, copies)):
            assert _same(a, b), f"{self.kernel}: argument {i} differs from numba's"
        self.calls += 1
        return got


@needs_aot
@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2_000, 40_000), mean_dt_us=st.sampled_from([2.0, 20.0, 200.0]))
def test_every_ahead_of_time_call_of_the_commands_matches_numba(tmp_path_factory, seed, n, mean_dt_us):
    """The commands `evstream.aot` compiles for, run on random recordings (bursts, border pixels, a hot
    pixel): every call served ahead of time is checked against numba on the same arguments, and every
    compiled kernel is called (from 2,000 events: an archive of fewer may hold no signal, so no packet)."""
    folder = tmp_path_factory.mktemp("aot")
    paths = random_recordings(folder, seed, n, mean_dt_us)
    commands = [[a.format(out=folder, **paths) for a in argv] for argv in aot.COMMANDS]
    with contextlib.redirect_stdout(io.StringIO()):
        for argv in commands:  # makes the kernel factories' kernels (cached), so that all are checked below
            assert main(argv) == 0
    kernels = [k for k in list(jit.KERNELS) if k.aot]
    saved = {k: k.aot for k in kernels}
    checks = {k: {key: AgainstJit(k, fn) for key, fn in k.aot.items()} for k in kernels}
    try:
        for k in kernels:
            k.aot = checks[k]
        with contextlib.redirect_stdout(io.StringIO()):
            for argv in commands:
                assert main(argv) == 0
    finally:
        for k in kernels:
            k.aot = saved[k]
    calls = {k.key: sum(c.calls for c in checks[k].values()) for k in kernels}
    assert set(calls) == set(json.loads(jit.AOT_INDEX.read_text())["kernels"])
    assert all(calls.values()), [k for k, v in calls.items() if not v]


def random_recordings(folder: Path, seed: int, n: int, mean_dt_us: float = 50.0) -> dict[str, Path]:
    """Random streams (bursts, border pixels, a hot pixel) in the files `aot.COMMANDS` name: native and EVT3
    at 64x48, EVT2 at 640x480 (the `far` kernels), DAT, N-MNIST; and EVT3 at 1280x720."""
    small = random_stream(seed, n, G, mean_dt_us=mean_dt_us)
    vga, hd = Geometry(640, 480), Geometry(1280, 720)
    paths = {"npz": folder / "rec.npz", "raw": folder / "rec.raw", "small": folder / "small.npz",
             "vga_evt2": folder / "vga.raw",
             "dat": folder / "rec.dat", "nmnist": folder / "rec.bin", "hd_evt3": folder / "hd.raw"}
    native.save(paths["npz"], small)  # deflated, as `evstream.aot` makes it: chunks of inflated (writeable) blocks
    native.save(paths["small"], small[:2000], compress=False)  # stored, in one block: its columns not writeable
    prophesee_raw.save(paths["raw"], small, G, version="evt3")
    prophesee_raw.save(paths["vga_evt2"], random_stream(seed, n, vga, mean_dt_us=mean_dt_us), vga, version="evt2")
    prophesee_raw.save(paths["hd_evt3"], random_stream(seed, n, hd, mean_dt_us=mean_dt_us), hd, version="evt3")
    dat.save(paths["dat"], small)
    nmnist.save(paths["nmnist"], small)
    assert set(aot.RECORDINGS) <= set(paths)
    return paths


# What a fresh clone's user runs that used to load numba after `make`: EVT2, DAT and N-MNIST files, sensors of
# 640x480 and up (the kernels' `far` variants), the learned denoiser.
STARTS_WITHOUT_NUMBA = {
    "archive EVT2 640x480": ["archive", "{vga_evt2}", "{out}/a.mcap"],
    "archive EVT3 1280x720": ["archive", "{hd_evt3}", "{out}/b.mcap", "--denoise", "paper"],
    "archive DAT": ["archive", "{dat}", "{out}/c.mcap"],
    "archive N-MNIST": ["archive", "{nmnist}", "{out}/d.mcap"],
    "archive --denoise learned": ["archive", "{npz}", "{out}/e.mcap", "--denoise", "learned"],
    "replay EVT2 640x480": ["replay", "{vga_evt2}", "--save", "{out}/f.rrd"],
    "convert to EVT2": ["convert", "{npz}", "{out}/g.raw", "--evt", "2"],
}


@needs_aot
@pytest.mark.parametrize("name", sorted(STARTS_WITHOUT_NUMBA))
def test_these_commands_start_without_numba(tmp_path, name):
    """Each ran with numba (0.7 s more start-up, a first run's compile 9-15 s): now served ahead of time."""
    paths = random_recordings(tmp_path, 3, 20_000)
    argv = [a.format(out=tmp_path, **paths) for a in STARTS_WITHOUT_NUMBA[name]] + ["-q"]
    script = (f"import sys\nfrom evstream.cli import main\ncode = main({argv!r})\n"
              "from evstream import jit\n"
              "print(code, 'numba' in sys.modules, sorted(k.key for k in jit.KERNELS if k.jit_calls))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).parents[1])
    assert out.stdout.splitlines()[-1] == "0 False []", out.stdout + out.stderr


@needs_aot
def test_other_argument_types_go_to_numba():
    """A strided array, or another dtype, is not what the module was compiled for: numba compiles it."""
    t = np.arange(0, 40, dtype=np.int64)
    x = np.arange(40, dtype=np.uint16) % 7
    p = np.zeros(40, np.uint8)
    args = (t, x, x, p, 5, 7, np.int64(-1))
    before = _first_invalid.jit_calls
    assert _first_invalid(*args) == _first_invalid.py_func(*args)  # the module's variant
    assert _first_invalid.jit_calls == before
    for odd in ((t[::2], x[::2], x[::2], p[::2], 5, 7, -1), (t.astype(np.int32), x, x, p, 5, 7, -1)):
        assert _first_invalid(*odd) == _first_invalid.py_func(*odd)
    assert _first_invalid.jit_calls == before + 2


@needs_aot
def test_a_bound_call_is_the_kernel_call():
    """`jit.bind` (a stage's state and parameters fixed, keyed once) serves what the kernel itself serves:
    the module's variant for its argument types, numba's for others, and the same result either way."""
    t = np.arange(0, 40, dtype=np.int64)
    x = np.arange(40, dtype=np.uint16) % 7
    p = np.zeros(40, np.uint8)
    call = jit.bind(_first_invalid, 2, (x, p, 7))  # t, x | y, p, width | height, last_t
    before = _first_invalid.jit_calls
    assert call(t, x, 7, np.int64(-1)) == _first_invalid(t, x, x, p, 7, 7, np.int64(-1)) == (-1, -1)
    assert _first_invalid.jit_calls == before
    assert call(t, x, 3, np.int64(-1)) == _first_invalid.py_func(t, x, x, p, 7, 3, np.int64(-1)) != (-1, -1)
    assert call(t[::2], x[::2], 7, -1) == _first_invalid.py_func(t[::2], x[::2], x, p, 7, 7, -1)  # strided: numba
    assert _first_invalid.jit_calls == before + 1
    plain = jit.bind(_first_invalid.py_func, 2, (x, p, 7))  # not a Kernel (NUMBA_DISABLE_JIT=1): the same call
    assert plain(t, x, 3, -1) == _first_invalid.py_func(t, x, x, p, 7, 3, -1)


@needs_aot
def test_a_changed_source_file_sets_the_module_aside(tmp_path):
    _, index = _copy_of_the_module(tmp_path)
    index_path = tmp_path / jit.AOT_INDEX.name
    assert jit.load_aot(index_path)
    path = next(iter(index["sources"]))
    index["sources"][path][1] += 1  # as if edited after the build
    index_path.write_text(json.dumps(index))
    assert jit.load_aot(index_path) == {}
    assert jit.load_aot(tmp_path / "missing.json") == {}
    index = json.loads(jit.AOT_INDEX.read_text())
    index["package"] = str(tmp_path / "evstream")  # built for a copy of the package elsewhere
    (tmp_path / "elsewhere.json").write_text(json.dumps(index))
    assert jit.load_aot(tmp_path / "elsewhere.json") == {}


@needs_aot
@pytest.mark.parametrize("use_aot", ["1", "0"])
def test_a_command_served_ahead_of_time_does_not_import_numba(tmp_path, use_aot):
    """The point of it all: `archive --denoise paper` without numba's ~0.4 s of start-up (EVSTREAM_AOT=0:
    numba compiles or loads its cache, as before)."""
    rec = tmp_path / "rec.npz"
    native.save(rec, random_stream(1, 5_000, G), compress=False)
    script = ("import sys\nfrom evstream.cli import main\n"
              f"code = main(['archive', {str(rec)!r}, {str(tmp_path / 'a.mcap')!r}, '--denoise', 'paper', '-q'])\n"
              "print(code, 'numba' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                         env=dict(os.environ, EVSTREAM_AOT=use_aot), cwd=Path(__file__).parents[1])
    assert out.stdout.split()[-2:] == ["0", "False" if use_aot == "1" else "True"]


def test_importing_the_package_does_not_import_numba():
    """Kernels are made with evstream.jit, whose numba import waits for a compile: a module importing numba
    itself would put numba's ~0.2 s import back into every command's start-up."""
    script = ("import sys\nimport evstream, evstream.cli, evstream.denoise, evstream.framing, evstream.transforms\n"
              "import evstream.synth, evstream.sources, evstream.sinks.mcap_sink\n"
              "from evstream.sources import native, prophesee_raw, text\n"
              "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).parents[1])
    assert out.stdout.strip() == "[]"


def _copy_of_the_module(folder: Path) -> tuple[Path, dict]:
    index = json.loads(jit.AOT_INDEX.read_text())
    module = jit.AOT_INDEX.with_name(index["module"])
    (folder / module.name).write_bytes(module.read_bytes())
    (folder / jit.AOT_INDEX.name).write_text(json.dumps(index))
    return folder / module.name, index


@needs_aot
def test_a_cut_short_or_damaged_module_file_is_set_aside_before_it_is_loaded(tmp_path):
    """Loading a truncated shared object kills the process (SIGBUS), a damaged one may run garbage (SIGILL):
    no ImportError to catch. The index names its module file's SHA-256, checked first; the module is the
    file beside the index, never another build's."""
    (tmp_path / "intact").mkdir()
    _copy_of_the_module(tmp_path / "intact")
    assert jit.load_aot(tmp_path / "intact" / jit.AOT_INDEX.name)  # an intact copy loads, from beside its index
    module, _ = _copy_of_the_module(tmp_path)  # (not the file loaded above: cutting a loaded one short kills)
    index_path = tmp_path / jit.AOT_INDEX.name
    whole = module.read_bytes()
    module.write_bytes(whole[: len(whole) // 3])
    assert jit.load_aot(index_path) == {}
    damaged = bytearray(whole)
    damaged[len(whole) // 2] ^= 0xFF
    module.write_bytes(bytes(damaged))
    assert jit.load_aot(index_path) == {}
    module.unlink()
    assert jit.load_aot(index_path) == {}


@needs_aot
def test_a_module_built_for_another_cpu_is_set_aside(tmp_path):
    """It is compiled for the host CPU: on another (a copied venv, a shared disk) it could die on an illegal
    instruction."""
    _, index = _copy_of_the_module(tmp_path)
    index["cpu"] = "another cpu"
    (tmp_path / jit.AOT_INDEX.name).write_text(json.dumps(index))
    assert jit.load_aot(tmp_path / jit.AOT_INDEX.name) == {}


def test_no_c_compiler_is_one_line_and_leaves_the_module_as_it_was(tmp_path):
    """`python -m evstream.aot` without a working C compiler (CC=false) says so in one line and exits 1,
    before recording anything; the module and index are left as they were."""
    before = {p.name: p.read_bytes() for p in jit.AOT_INDEX.parent.glob("_aot.*")}
    out = subprocess.run([sys.executable, "-m", "evstream.aot"], capture_output=True, text=True,
                         env=dict(os.environ, CC="false"), cwd=tmp_path)
    assert out.returncode == 1, out
    assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert out.stderr.startswith("evstream.aot: evstream._aot not built"), out.stderr
    assert {p.name: p.read_bytes() for p in jit.AOT_INDEX.parent.glob("_aot.*")} == before


@needs_aot
def test_a_module_built_for_another_python_is_set_aside(tmp_path):
    """Another Python sharing the checkout finds the index naming a module of another ABI (its name says
    which): it is not loaded, though its file is whole."""
    module, index = _copy_of_the_module(tmp_path)
    other = module.with_name("_aot.cpython-39-x86_64-linux-gnu.so")
    module.rename(other)
    index["module"] = other.name
    (tmp_path / jit.AOT_INDEX.name).write_text(json.dumps(index))
    assert jit.load_aot(tmp_path / jit.AOT_INDEX.name) == {}


def _plain_sum(a):
    return a.sum()


def test_only_nogil_kernels_are_compiled_ahead_of_time():
    """The module's functions release the GIL: a kernel numba runs holding it stays with numba."""
    assert aot.exportable(jit.Kernel(_plain_sum, {"cache": True, "nogil": True}))
    assert aot.exportable(jit.Kernel(_plain_sum, {"cache": True, "nogil": True, "fastmath": True}))  # compiled with it
    assert not aot.exportable(jit.Kernel(_plain_sum, {"cache": True}))
    assert not aot.exportable(jit.Kernel(_plain_sum, {"cache": True, "nogil": True, "boundscheck": True}))


def test_every_make_target_a_user_types_rebuilds_stale_kernels_and_only_then(tmp_path):
    """The Makefile's rules, on a copy of the tree's shape with set file times (`make -n`: what it would
    run): after a `git pull` (a source newer than the module's index) `make demo` and `make
    .venv/.installed` rebuild the module once; when it is fresh they do not, nor does `make lint` when
    it is stale; pyproject.toml newer: the venv's install, then the build."""
    import shutil

    if shutil.which("make") is None:
        pytest.skip("no make")
    root = Path(__file__).resolve().parents[1]
    shutil.copy(root / "Makefile", tmp_path / "Makefile")
    for name in ("evstream/events.py", "sources/a.py", "sinks/b.py", "pyproject.toml", ".venv/bin/python",
                 ".venv/.pip", ".venv/.installed", "evstream/_aot.json", ".venv/.numba-cache"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("")

    def at(name, t):
        os.utime(tmp_path / name, (t, t))

    def would_run(target) -> str:
        return subprocess.run(["make", "-n", target], cwd=tmp_path, capture_output=True, text=True, check=True).stdout

    for name in ("evstream/events.py", "sources/a.py", "sinks/b.py", "pyproject.toml"):
        at(name, 1_000)
    at(".venv/.pip", 1_500)
    at("evstream/_aot.json", 2_000)
    at(".venv/.installed", 3_000)
    at(".venv/.numba-cache", 3_000)
    for target in ("demo", ".venv/.installed"):
        assert "evstream.aot" not in would_run(target) and "clean-cache" not in would_run(target)  # fresh
    at("sources/a.py", 4_000)  # a pull changed a source
    for target in ("demo", ".venv/.installed", "bench", "recordings", "test"):
        out = would_run(target)
        assert out.count("-m evstream.aot") == 1, target
        # numba's cache emptied first: its kernels would miss an edit to a helper they inline (a crash, seen)
        assert "clean-cache" in out and out.index("clean-cache") < out.index("-m evstream.aot"), target
    assert "evstream.aot" not in would_run("lint")
    at("pyproject.toml", 5_000)
    out = would_run("demo")
    assert "pip install" in out and out.index("pip install") < out.index("-m evstream.aot")
    assert out.count("-m evstream.aot") == 1


def _load_at_a_terminal(index_path, monkeypatch, quiet: bool = False) -> str:
    """What `jit.load_aot(index_path)` (which must load nothing) and numba's next compile say on stderr when
    stderr is a terminal (inside `jit.quiet_notes()` with `quiet`)."""
    terminal, tty_name = os.openpty()
    with open(tty_name, "w", closefd=True) as tty:
        monkeypatch.setattr(sys, "stderr", tty)
        assert jit.load_aot(index_path) == {}
        with jit.quiet_notes(quiet):
            jit._say_stale()
        print("end", file=tty)  # the read below waits for something
    said = os.read(terminal, 4096).decode()
    os.close(terminal)
    assert said.endswith("end\r\n")
    return said.removesuffix("end\r\n")


@needs_aot
def test_a_module_older_than_the_sources_says_so_on_a_terminal(tmp_path, monkeypatch, capsys):
    """After a `git pull` that changed a kernel's module, a command ran numba (seconds) without a word on why
    (session 9's audit). At a terminal: one note naming the file and `make aot`; captured (tests, pipes): none."""
    _, index = _copy_of_the_module(tmp_path)
    index_path = tmp_path / jit.AOT_INDEX.name
    path = next(iter(index["sources"]))
    index["sources"][path][1] += 1  # as if pulled after the build
    index_path.write_text(json.dumps(index))
    assert jit.load_aot(index_path) == {} and capsys.readouterr().err == ""
    jit._say_stale()
    assert capsys.readouterr().err == ""
    assert _load_at_a_terminal(index_path, monkeypatch, quiet=True) == ""
    said = _load_at_a_terminal(index_path, monkeypatch)
    name = os.path.relpath(path, Path(index["package"]).parent)
    assert said == (f"evstream: note: {name} changed since the kernels were compiled ahead of time: numba compiles "
                    "them instead (seconds at first use); `make aot` rebuilds them\r\n")
    for n in (2, 3):  # the others counted, in agreement ('and 1 more files' before)
        for other in list(index["sources"])[1:n]:
            index["sources"][other][1] += 1
        index_path.write_text(json.dumps(index))
        said = _load_at_a_terminal(index_path, monkeypatch)
        more = f"and {n - 1} more file{'s' if n > 2 else ''} changed since"
        assert said.startswith("evstream: note: ") and more in said.splitlines()[0], said


def _stale_copy_of_the_package(ws: Path) -> None:
    """`ws/evstream`: the package as it installs (sources/ and sinks/ inside), with a copy of the ahead-of-time
    module whose index is for this copy, built before its last edit of a kernel's module (events.py)."""
    index = json.loads(jit.AOT_INDEX.read_text())
    package = jit.AOT_INDEX.parent
    ignore = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.pyc", "_aot.*", ".aot-build-*")
    shutil.copytree(package, ws / "evstream", ignore=ignore)
    for sub in ("sources", "sinks"):
        shutil.copytree(package.parent / sub, ws / "evstream" / sub, ignore=ignore)
    (ws / "evstream" / index["module"]).write_bytes(package.joinpath(index["module"]).read_bytes())
    index["package"] = str((ws / "evstream").resolve())
    index["sources"] = jit.source_stamps(sorted((ws / "evstream").rglob("*.py")))
    index["sources"][str((ws / "evstream" / "events.py").resolve())][1] -= 1  # as if pulled after the build
    (ws / "evstream" / jit.AOT_INDEX.name).write_text(json.dumps(index))


@needs_aot
def test_the_stale_module_note_keeps_to_quiet(tmp_path):
    """The note on a module older than the sources was printed at import, before a command had read its
    flags: `--quiet` at a terminal still printed it (session 12). Now said when numba first compiles (once),
    and not under `--quiet`."""
    _stale_copy_of_the_package(tmp_path)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))
    env.pop("EVSTREAM_AOT", None)

    def at_a_terminal(*argv) -> str:
        terminal, tty = os.openpty()
        code = ("import sys; sys.path.insert(0, sys.argv[1]); from evstream.cli import main; "
                "sys.exit(main(sys.argv[2:]))")
        proc = subprocess.run([sys.executable, "-c", code, str(tmp_path), *argv], cwd=tmp_path, env=env,
                              stderr=tty, stdout=subprocess.DEVNULL, timeout=600)
        os.write(tty, b"end\n")
        os.close(tty)
        said = os.read(terminal, 65536).decode()
        os.close(terminal)
        assert proc.returncode == 0, said
        return said.removesuffix("end\r\n")

    synth = ["synth", "bar", "bar.npz", "--duration-ms", "20"]
    assert at_a_terminal(*synth, "--quiet") == ""
    said = at_a_terminal(*synth)
    assert said.startswith("evstream: note: evstream/events.py changed since the kernels were compiled ahead of "
                           "time: numba compiles them instead"), said
    assert said.count("evstream: note:") == 1
