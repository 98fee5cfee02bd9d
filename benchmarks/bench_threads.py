"""Where a threaded `archive` spends its wall time, per thread: CPU, run-queue wait and sleep.

`archive --denoise paper` of a 10 M-event recording (bench_commands' turntable) run in this process,
serial and threaded, with reader chunks of 50,000 and 200,000 events, interleaved. For each thread (the
reader, the stages on the caller's thread, the writer), from `/proc/self/task/TID/schedstat`: its CPU
time, its run-queue wait (runnable but another process had the core: the machine's other work) and its
sleep (the rest of its wall time: waiting on a queue, or for the GIL), and how much of that sleep was
spent in the queues' `get` and `put`. On a shared machine the run-queue wait says how much of the wall
time was other work's; giving this process priority (`echo -15 > /proc/self/autogroup` in the shell,
for the seconds of the run) brings it near a quiet machine. Linux only.

    .venv/bin/python -m benchmarks.bench_threads            # about a minute
"""

from __future__ import annotations

import collections
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

VARIANTS = ((False, 50_000), (True, 50_000), (False, 200_000), (True, 200_000))  # (threads, chunk events)


def schedstat() -> tuple[float, float, float]:
    """(wall s, CPU s, run-queue wait s) of the calling thread now."""
    with open(f"/proc/self/task/{threading.get_native_id()}/schedstat") as f:
        cpu_ns, wait_ns, _ = f.read().split()
    return time.perf_counter(), int(cpu_ns) * 1e-9, int(wait_ns) * 1e-9


class Probe:
    """Per thread name: (wall, CPU, run-queue wait) of its life, and the wall time it spent in queue calls."""

    def __init__(self):
        self.threads: dict[str, tuple[float, float, float]] = {}
        self.in_queue: dict[str, float] = collections.defaultdict(float)

    def __enter__(self) -> Probe:
        from evstream import threads

        self._saved = [(cls, cls._run) for cls in (threads.ReadAhead, threads.WriteBehind)]
        self._get, self._put = queue.Queue.get, queue.Queue.put
        probe = self

        def timed(call):
            def wrapper(q, *args, **kwargs):
                t0 = time.perf_counter()
                try:
                    return call(q, *args, **kwargs)
                finally:
                    probe.in_queue[threading.current_thread().name] += time.perf_counter() - t0
            return wrapper

        def watched(run):
            def wrapper(self):
                start = schedstat()
                try:
                    run(self)
                finally:
                    probe.threads[threading.current_thread().name] = tuple(
                        b - a for a, b in zip(start, schedstat()))
            return wrapper

        queue.Queue.get, queue.Queue.put = timed(self._get), timed(self._put)
        for cls, run in self._saved:
            cls._run = watched(run)
        self.start = schedstat()
        return self

    def __exit__(self, *exc) -> None:
        self.threads["stages"] = tuple(b - a for a, b in zip(self.start, schedstat()))
        self.in_queue["stages"] = self.in_queue.pop(threading.main_thread().name, 0.0)
        queue.Queue.get, queue.Queue.put = self._get, self._put
        for cls, run in self._saved:
            cls._run = run


def archive_once(path: Path, out: Path, threads: bool, chunk_events: int) -> tuple[float, Probe]:
    from evstream.sources import open_source

    from evstream.writers import archive

    os.environ["EVSTREAM_THREADS"] = "1" if threads else "0"
    with Probe() as probe:
        t0 = time.perf_counter()
        archive(open_source(path, chunk_events=chunk_events), out, path=path)
        wall = time.perf_counter() - t0
    return wall, probe


def run(repeat: int = 3) -> None:
    saved = os.environ.get("EVSTREAM_THREADS")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        subprocess.run([sys.executable, "-m", "benchmarks.bench_commands", "--make-inputs", str(folder), "raw"],
                       check=True, cwd=Path(__file__).resolve().parents[1])
        path, out = folder / "raw.raw", folder / "out.mcap"
        archive_once(path, out, True, 200_000)  # warm: imports, kernels
        runs = {v: [] for v in VARIANTS}
        try:
            for _ in range(repeat):
                for v in VARIANTS:
                    runs[v].append(archive_once(path, out, *v))
        finally:
            if saved is None:
                os.environ.pop("EVSTREAM_THREADS", None)
            else:
                os.environ["EVSTREAM_THREADS"] = saved
    print(f"-- archive --denoise paper, 10 M events .raw, in this process; best of {repeat} by wall time; load "
          f"average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores. Per thread: CPU / run-queue wait / "
          "sleep (of which in queue calls), s")
    for (threads, chunk_events), results in runs.items():
        wall, probe = min(results, key=lambda r: r[0])
        cells = []
        for name in ("evstream-reader", "stages", "evstream-writer"):
            if name in probe.threads:
                w, cpu, wait = probe.threads[name]
                cells.append(f"{name.removeprefix('evstream-')} {cpu:.3f} / {wait:.3f} / {w - cpu - wait:.3f} "
                             f"({probe.in_queue.get(name, 0.0):.3f})")
        print(f"  {'threaded' if threads else 'serial':8} {chunk_events:>7,}-event chunks: wall {wall:.3f} s "
              f"({1e7 / wall / 1e6:.1f} M ev/s) | " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    run()
