"""Build `evstream._aot`: the kernels of the everyday commands compiled ahead of time, so that they start
without numba (evstream.jit).

    python -m evstream.aot          # make .venv/.installed runs it; a few minutes on a cold numba cache

Which kernels, for which argument types: those the commands call on small synthetic recordings — `archive
--denoise paper` of a .raw and a .npz, `replay --denoise paper --save`, `replay --framer fw --save`
(`make demo`; of a small .npz too: its columns are read-only views), `convert` both ways; `archive` of an
EVT2 .raw of a 640x480 sensor (the kernels' variants for maps larger than the L2 cache, `far`, which every
sensor from 640x480 up uses), of a DAT and an N-MNIST file, `archive --denoise learned`, `convert --evt 2` —
run here under numba's JIT; each (kernel, closure values, argument types) seen from Python is exported with
numba.pycc, for this machine's CPU (as the JIT compiles), releasing the GIL as `nogil` kernels do. The
index `evstream/_aot.json` maps kernel keys and argument types to the module's functions and records the
size and time of every source file: after an edit the module is ignored (numba compiles, as without
it) until this is run again. Other kernels, options or types are compiled by numba as before.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from . import jit

COMMANDS = (
    ["archive", "{raw}", "{out}/a.mcap", "--denoise", "paper", "-q"],
    ["archive", "{npz}", "{out}/b.mcap", "--denoise", "paper", "-q"],
    ["archive", "{small}", "{out}/s.mcap", "--denoise", "paper", "-q"],  # in one block: columns not writeable
    ["archive", "{small}", "{out}/t.mcap", "--denoise", "learned", "-q"],
    ["replay", "{raw}", "--denoise", "paper", "--save", "{out}/r.rrd", "-q"],
    ["convert", "{raw}", "{out}/c.raw", "-q"],
    ["convert", "{npz}", "{out}/d.raw", "-q"],
    ["replay", "{npz}", "--framer", "fw", "--save", "{out}/f.rrd", "-q"],  # make demo, README's first command
    ["replay", "{small}", "--framer", "fw", "--save", "{out}/u.rrd", "-q"],  # in one block: not writeable
    ["archive", "{vga_evt2}", "{out}/g.mcap", "--denoise", "paper", "-q"],  # EVT2; 640x480 and up: `far` kernels
    ["replay", "{vga_evt2}", "--denoise", "paper", "--save", "{out}/h.rrd", "-q"],
    ["archive", "{dat}", "{out}/i.mcap", "--denoise", "paper", "-q"],
    ["archive", "{nmnist}", "{out}/j.mcap", "--denoise", "paper", "-q"],
    ["archive", "{npz}", "{out}/k.mcap", "--denoise", "learned", "-q"],
    ["convert", "{npz}", "{out}/l.raw", "--evt", "2", "-q"],
)
# What COMMANDS' fields name, and each one's file suffix (`recordings`).
RECORDINGS = {"npz": ".npz", "raw": ".raw", "small": ".npz", "vga_evt2": ".raw", "dat": ".dat", "nmnist": ".bin"}
OPTIONS = {"cache", "nogil", "inline", "fastmath"}  # kernels compiled with other numba options stay with the JIT


def arg_key(ty):
    """`jit.arg_key` of an argument numba typed `ty`, as JSON; None when not exported (layout other than
    C, or a type the run-time check does not know)."""
    from numba.core import types
    from numba.np.numpy_support import as_dtype

    if isinstance(ty, types.Array):
        if ty.layout != "C" or not isinstance(ty.dtype, (types.Integer, types.Float, types.Boolean)):
            return None
        return [as_dtype(ty.dtype).str, ty.ndim, 0x1 | (0x100 if ty.aligned else 0) | (0x400 if ty.mutable else 0)]
    if isinstance(ty, (types.Integer, types.Float, types.Boolean)):
        return as_dtype(ty).str
    return None


def recording_paths(folder: Path) -> dict[str, Path]:
    """Where `recordings` puts each of COMMANDS' recordings in `folder`."""
    return {name: folder / f"rec-{name}{suffix}" for name, suffix in RECORDINGS.items()}


def recordings(folder: Path) -> dict[str, Path]:
    """Small synthetic recordings in `folder`, one per field of COMMANDS: the turntable (346x260) as .npz and
    EVT3 .raw, its first 2,000 events as a stored (not deflated) .npz, as a 640x480 EVT2 .raw, a DAT file
    (304x240) and an N-MNIST binary (34x34)."""
    from . import noise, synth
    from .events import Geometry

    def scene(width: int, height: int):
        events = synth.scene("turntable", Geometry(width, height), duration_us=300_000, seed=1)
        return noise.inject(events, noise.NoiseSpec(noise_ratio=0.5), seed=2, t_start_us=0, t_stop_us=300_000)

    from .sources import dat, native, nmnist, prophesee_raw

    paths = recording_paths(folder)
    davis = scene(346, 260)
    native.save(paths["npz"], davis)
    native.save(paths["small"], davis[:2000], compress=False)  # stored: its columns are views of the bytes read
    prophesee_raw.save(paths["raw"], davis, Geometry(346, 260))
    prophesee_raw.save(paths["vga_evt2"], scene(640, 480), Geometry(640, 480), version="evt2")
    dat.save(paths["dat"], scene(304, 240))
    nmnist.save(paths["nmnist"], scene(34, 34))
    return paths


def record(folder: Path) -> list[jit.Kernel]:
    """Run the commands on small recordings in `folder`; the kernels they called from Python."""
    from .cli import main

    script = "import sys\nfrom pathlib import Path\nfrom evstream.aot import recordings\nrecordings(Path(sys.argv[1]))"
    # in a process of its own: the kernels that make them (synth, noise) are not the commands'
    subprocess.run([sys.executable, "-c", script, str(folder)], check=True, env=dict(os.environ, EVSTREAM_AOT="0"))
    paths = recording_paths(folder)
    for argv in COMMANDS:
        with contextlib.redirect_stdout(io.StringIO()):
            code = main([a.format(out=folder, **paths) for a in argv])
        if code != 0:
            raise RuntimeError(f"evstream {' '.join(argv)}: exit {code}")
    return [k for k in jit.KERNELS if k.jit_calls and exportable(k)]


def exportable(kernel: jit.Kernel) -> bool:
    """Compiled ahead of time: a kernel with a key, numba options among OPTIONS, and `nogil` (the module's
    wrappers release the GIL: a kernel numba runs holding it may rely on that to serialise its callers)."""
    return kernel.key is not None and set(kernel.targetoptions) <= OPTIONS and bool(kernel.targetoptions.get("nogil"))


def build(out_dir: Path | None = None) -> dict:
    """Compile the recorded kernels into `evstream._aot` and write the index; returns the index."""
    jit.use_aot(False)  # record what numba compiles, not what an older module serves
    out_dir = out_dir or Path(__file__).resolve().parent
    jit._numba()
    import numba.pycc.compiler as pycc_compiler
    from numba.core.compiler import Flags
    from numba.pycc import CC

    class ReleaseGil(Flags):  # pycc's wrappers hold the GIL; the kernels are `nogil`, so these do not
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.release_gil = True

    pycc_compiler.Flags = ReleaseGil
    fastmath: set = set()  # the py_funcs of `fastmath` kernels: compiled with it, as numba's JIT does
    plain_compile = pycc_compiler.compile_extra

    def compile_extra(typingctx, targetctx, func, args, return_type, flags, *rest, **options):
        if func in fastmath:  # pycc compiles every export with one set of flags
            flags = flags.copy()
            flags.fastmath = True
        return plain_compile(typingctx, targetctx, func, args, return_type, flags, *rest, **options)

    pycc_compiler.compile_extra = compile_extra
    cc = CC("_aot")  # first: without a C compiler this fails at once, not after recording
    cc.target_cpu = "host"  # built where it runs, like numba's JIT
    with tempfile.TemporaryDirectory() as tmp:
        kernels = record(Path(tmp))
    fastmath.update(k.py_func for k in kernels if k.targetoptions.get("fastmath"))
    index: dict = {"kernels": {}}
    with tempfile.TemporaryDirectory(dir=out_dir, prefix=".aot-build-") as build_dir:
        cc.output_dir = build_dir  # built aside, then moved in whole: a process loading the module meanwhile
        # keeps the old file, and no index ever names a half-written one
        for kernel in kernels:
            for sig in kernel.dispatcher.signatures:
                keys = [arg_key(t) for t in sig]
                if None in keys:
                    continue
                symbol = symbol_name(kernel.key, keys)  # the same kernel, the same name in every build
                cc.export(symbol, kernel.dispatcher.overloads[sig].signature)(kernel.py_func)
                index["kernels"].setdefault(kernel.key, []).append([symbol, keys])
        index["sources"] = jit.source_stamps(source_files())
        index["cpu"] = jit.cpu_id()
        index["package"] = str(Path(jit.__file__).resolve().parent)
        cc.compile()
        built = Path(build_dir) / cc.output_file
        index["module"] = built.name
        index["module_sha256"] = jit.file_digest(built)
        index_tmp = Path(build_dir) / jit.AOT_INDEX.name
        index_tmp.write_text(json.dumps(index, indent=1) + "\n")
        os.replace(built, out_dir / built.name)
        os.replace(index_tmp, out_dir / jit.AOT_INDEX.name)
    return index


def symbol_name(kernel_key: str, arg_keys: list) -> str:
    """The module's name for one kernel's variant, from its key and argument types."""
    return "k" + hashlib.sha256(json.dumps([kernel_key, arg_keys]).encode()).hexdigest()[:20]


def source_files() -> list[Path]:
    """Every Python file of the package (evstream/, sources/, sinks/): a kernel also compiles in the
    helpers and constants it imports, so any edit sets the module aside."""
    from . import sinks, sources

    folders = [Path(__file__).resolve().parent, *map(Path, sources.__path__), *map(Path, sinks.__path__)]
    return sorted({p.resolve() for folder in folders for p in folder.rglob("*.py")})


def main() -> int:
    t0 = time.perf_counter()
    try:
        index = build()
    except Exception as e:  # no C compiler, a failed link: the commands still run, numba compiling
        reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        print(f"evstream.aot: evstream._aot not built ({type(e).__name__}: {reason})", file=sys.stderr)
        return 1
    n = sum(map(len, index["kernels"].values()))
    print(f"evstream._aot: {n} kernels ahead of time ({len(index['kernels'])} kinds) in "
          f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
