"""Whole commands as a user runs them, one process each: `archive --denoise paper`, `replay --save` and
`convert` on a 10 M-event recording (346×260, the turntable with background activity and hot pixels of
bench_archive, tiled to 10 M events), serial (EVSTREAM_THREADS=0) against threaded (reading, stages and
writing on their own threads, evstream.threads), with the kernels compiled ahead of time (evstream._aot,
`make aot`) and with numba's cached kernels (EVSTREAM_AOT=0), interleaved; and the start-up of a command
(imports, kernels) on a 2,000-event file, both ways.

    .venv/bin/python -m benchmarks.bench_commands            # the table (about 3 minutes on a quiet machine)
    .venv/bin/python -m benchmarks.bench_commands --repeat 1 --inputs raw   # quicker

Each row is the best of `--repeat` runs (by wall time). Columns: wall time and CPU time of the process (all
its threads), events per wall second; and, for a machine shared with other work, per-thread CPU (reader,
stages, writer, other: threads not ours, Rerun's; for `replay`, a line more: Rerun's file writer thread's
CPU, and how much of it came after the run, which the command waited for) and the critical path —
start-up CPU plus the busiest thread's CPU, what the wall time would be with a free core per thread — and
the events per second it allows; and the 2-core floor: start-up CPU plus the larger of the busiest thread's
CPU and half the run's CPU (all threads, Rerun's included), the wall time two free cores would give with a
perfect overlap. On a quiet 2-core machine the wall column is the one to quote (wall ÷ floor says how well the threads
overlap); under load, the CPU columns.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

N_EVENTS = 10_000_000
ROLES = ("reader", "stages", "writer", "other")


def make_inputs(folder: Path, kinds: list[str]) -> dict[str, Path]:
    """The 10 M-event recording in each asked format, and a 2,000-event one for start-up."""
    from evstream.sources import native, prophesee_raw

    from evstream.events import Geometry, concat

    from .common import noisy_scene

    g, duration_us = Geometry(346, 260), 2_000_000
    one = noisy_scene("turntable", g, duration_us)
    reps = -(-N_EVENTS // len(one))
    events = concat([one.replace(t=one.t + k * duration_us) for k in range(reps)])[:N_EVENTS]
    paths = {"tiny": folder / "tiny.npz"}  # named by their stems
    native.save(paths["tiny"], events[:2000], compress=False)
    if "native" in kinds:
        paths["native"] = folder / "native.npz"
        native.save(paths["native"], events, compress=False)
    if "zipped" in kinds:
        paths["zipped"] = folder / "zipped.npz"
        native.save(paths["zipped"], events, compress=True)
    if "raw" in kinds:
        paths["raw"] = folder / "raw.raw"
        prophesee_raw.save(paths["raw"], events, g, version="evt3")
    return paths


def child(argv: list[str]) -> None:
    """Run `evstream ARGV` in this process, then write wall, CPU and per-thread CPU to $BENCH_OUT."""
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    from evstream import pipeline
    from evstream.cli import main

    run, seen = pipeline.Pipeline.run, {}

    def timed_run(self, *a, **k):
        cpu = time.process_time()
        stats = run(self, *a, **k)
        seen.update(run_cpu_s=time.process_time() - cpu, threads=dict(self.cpu_s), events=stats.events_in)
        return stats

    pipeline.Pipeline.run = timed_run
    if argv[0] == "replay":  # Rerun's file writer: its CPU when the run ended and once all was written
        from evstream.sinks import rerun_viewer

        flushed = rerun_viewer.wait_flushed

        def timed_flush(rec, part=None):
            at_end = _thread_cpu_s("file_writer")
            flushed(rec, part)
            seen.update(rerun_writer_s=_thread_cpu_s("file_writer"), rerun_writer_after_run_s=
                        _thread_cpu_s("file_writer") - at_end)

        rerun_viewer.wait_flushed = timed_flush
    code = main(argv)
    seen.update(code=code, wall_s=time.perf_counter() - t_wall, cpu_s=time.process_time() - t_cpu)
    Path(os.environ["BENCH_OUT"]).write_text(json.dumps(seen))


def _thread_cpu_s(name: str) -> float:
    """CPU time (user + system) of this process's threads called `name`, from /proc."""
    total = 0.0
    for tid in os.listdir("/proc/self/task"):
        try:
            if Path(f"/proc/self/task/{tid}/comm").read_text().strip() != name:
                continue
            fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended meanwhile
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def run_child(argv: list[str], threads: bool, folder: Path, aot: bool = True) -> dict:
    out = folder / "child.json"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}  # as installed: bytecode cached
    env.update(EVSTREAM_THREADS="1" if threads else "0", EVSTREAM_AOT="1" if aot else "0", BENCH_OUT=str(out))
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.bench_commands", "--child", *argv], env=env,
                            cwd=Path(__file__).resolve().parents[1], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode()
    proc.stderr.close()
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"evstream {' '.join(argv)} failed: {err}")
    seen = json.loads(out.read_text())
    seen.update(process_wall_s=wall, process_cpu_s=usage.ru_utime + usage.ru_stime, rss_mb=usage.ru_maxrss / 1024)
    return seen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--inputs", nargs="+", default=["raw", "native"], choices=["raw", "native", "zipped"])
    ap.add_argument("--commands", nargs="+", default=["archive", "replay", "convert"])
    ap.add_argument("--child", nargs=argparse.REMAINDER)
    ap.add_argument("--make-inputs", nargs="+", metavar=("FOLDER", "KIND"))
    args = ap.parse_args()
    if args.child is not None:
        child(args.child)
        return
    if args.make_inputs:
        make_inputs(Path(args.make_inputs[0]), args.make_inputs[1:])
        return
    run(args.repeat, args.inputs, args.commands)


def run(repeat: int = 3, inputs=("raw", "native"), commands=("archive", "replay", "convert")) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        # made in a child: this process stays small (a child's peak RSS counts its parent's pages before exec)
        subprocess.run([sys.executable, "-m", "benchmarks.bench_commands", "--make-inputs", str(folder), *inputs],
                       check=True, cwd=Path(__file__).resolve().parents[1])
        paths = {p.stem: p for p in folder.iterdir()}
        print(f"-- load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; best of {repeat}; "
              f"{N_EVENTS:,} events, 346x260", flush=True)
        from evstream import jit

        if not jit._aot_index():
            print("   (no evstream._aot built from these sources: `make aot`; the 'aot' rows are numba's)")
        for threads in (False, True):  # warm: kernels compiled and cached, bytecode written
            for aot in (True, False):
                run_child(["archive", str(paths["tiny"]), str(folder / "w.mcap"), "--denoise", "paper", "-q"],
                          threads, folder, aot)
        startup = {True: [], False: []}
        for _ in range(max(5, 2 * repeat)):
            for aot in (True, False):  # interleaved
                startup[aot].append(run_child(["archive", str(paths["tiny"]), str(folder / "s.mcap"), "--denoise",
                                               "paper", "-q"], True, folder, aot))
        for aot in (True, False):
            best = min(startup[aot], key=lambda r: r["process_wall_s"])
            cpu = min(r["process_cpu_s"] for r in startup[aot])
            how = "kernels ahead of time (evstream._aot)" if aot else "numba's cached kernels (EVSTREAM_AOT=0)"
            print(f"start-up: `evstream archive --denoise paper` of 2,000 events, {how}: wall "
                  f"{best['process_wall_s']:.3f} s, CPU {cpu:.3f} s (best of {len(startup[aot])})", flush=True)
        # the floor under any command that runs a kernel: numba's import and its first cached kernel (numba
        # initialises its target, importing its whole lowering library, before loading from the cache)
        (folder / "one_kernel.py").write_text("import numba\n\n\n@numba.njit(cache=True)\ndef f(x):\n"
                                              "    return x + 1\n\n\nf(1)\n")
        for what, argv in (("python -c pass", ["-c", "pass"]), ("import numpy", ["-c", "import numpy"]),
                           ("import numba", ["-c", "import numba"]),
                           ("import numba + one cached kernel", [str(folder / "one_kernel.py")]),
                           ("import evstream.cli", ["-c", "import evstream.cli"])):
            wall, cpu = [], []
            for _ in range(6):
                t0 = time.perf_counter()
                proc = subprocess.Popen([sys.executable, *argv])
                _, _, usage = os.wait4(proc.pid, 0)
                wall.append(time.perf_counter() - t0)
                cpu.append(usage.ru_utime + usage.ru_stime)
            print(f"  (for scale) {what}: wall {min(wall[1:]):.3f} s, CPU {min(cpu[1:]):.3f} s", flush=True)
        print(f"{'command':<44} {'thr':>3} {'aot':>3} {'wall s':>7} {'CPU s':>6} {'M ev/s':>7} | {'reader':>6} "
              f"{'stages':>6} {'writer':>6} {'other':>6} {'crit s':>6} {'M ev/s':>7} {'floor s':>7} | {'RSS MB':>6}",
              flush=True)
        for kind in inputs:
            src = str(paths[kind])
            runs = {
                "archive": ["archive", src, str(folder / "a.mcap"), "--denoise", "paper", "-q"],
                "replay": ["replay", src, "--denoise", "paper", "--save", str(folder / "r.rrd"), "-q"],
                "convert": ["convert", src, str(folder / "c.raw"), "-q"],
            }
            for name in commands:
                argv = runs[name]
                variants = [(False, True), (True, True), (True, False)]  # (threads, aot)
                results = {v: [] for v in variants}
                for _ in range(repeat):
                    for v in variants:  # interleaved: the same load on each
                        results[v].append(run_child(argv, v[0], folder, v[1]))
                for threads, aot in variants:
                    r = min(results[threads, aot], key=lambda r: r["process_wall_s"])
                    th = dict(r.get("threads") or {})
                    if th:  # CPU of threads not ours (Rerun's encoder and writer)
                        th["other"] = max(0.0, r["run_cpu_s"] - sum(th.values()))
                    startup_cpu = r["cpu_s"] - r.get("run_cpu_s", 0.0)
                    busiest = max(th.values()) if th else r.get("run_cpu_s", 0.0)
                    crit = startup_cpu + busiest
                    floor = startup_cpu + max(busiest, r.get("run_cpu_s", 0.0) / 2)  # two cores, perfect overlap
                    label = f"{name} {kind}" + (" --denoise paper" if name != "convert" else " -> .raw")
                    print(f"{label:<44} {'yes' if threads else 'no':>3} {'yes' if aot else 'no':>3} "
                          f"{r['process_wall_s']:7.2f} "
                          f"{r['process_cpu_s']:6.2f} {N_EVENTS / r['process_wall_s'] / 1e6:7.1f} | "
                          + " ".join(f"{th[k]:6.2f}" if k in th else f"{'-':>6}" for k in ROLES)
                          + f" {crit:6.2f} {N_EVENTS / crit / 1e6:7.1f} {floor:7.2f} | {r['rss_mb']:6.0f}", flush=True)
                    if "rerun_writer_s" in r:
                        print(f"{'':<44}   Rerun's file writer: {r['rerun_writer_s']:.2f} s CPU, of which "
                              f"{r['rerun_writer_after_run_s']:.2f} s after the run ended (the wait)", flush=True)


if __name__ == "__main__":
    main()
