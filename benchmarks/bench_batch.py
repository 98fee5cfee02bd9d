"""Many recordings on a local Dask cluster (evstream.batch): `--jobs 2` against `--jobs 1` on a folder of
recordings (the shipped three, each repeated in time to EVSTREAM_BENCH_BATCH_EVENTS / N events, default 50 M
in all), interleaved in one run (1, 2, 2, 1) so a load that
changes meanwhile hits both; on warm workers (a folder of near-empty recordings first: imports and numba's
cache loaded), which also gives the per-task overhead (that folder again), the cluster's start apart.
Archive with the paper's cascade, as `evstream archive DIR/ OUT/`.

One command: `python -m benchmarks batch`. Environment variables: EVSTREAM_BENCH_BATCH_N (recordings, default
20), EVSTREAM_BENCH_BATCH_EVENTS (events in all, default 50,000,000).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

from evstream.sources import native

from evstream import batch, synth
from evstream.cli import task_flags
from evstream.cli.archive import archive_file

ROOT = Path(__file__).resolve().parents[1]


def _recording(src: Path, dst: str, events: int) -> int:
    """`src` repeated one after the other in time (event times shifted) until it holds about `events`."""
    import dataclasses

    from evstream import api
    from evstream.events import concat

    base = api.read(src)
    times = max(1, round(events / len(base)))
    span = int(base.t[-1]) + 1
    native.save(dst, concat([dataclasses.replace(base, t=base.t + i * span, t_end=None) for i in range(times)],
                            base.geometry), {"repeated": times}, compress=False)
    return len(base) * times


def _job(folder: str, out: str, jobs: int, tiny: str) -> tuple[float, float, float, float, int]:
    """For the folder archived with `jobs` workers: (cluster start s, first use s: the tiny folder on the
    fresh workers (imports, numba's cache loaded), tiny again s: the per-task cost once warm, job s, events)."""
    flags = task_flags("archive")
    t0 = time.perf_counter()
    client, cluster = batch.start_client(jobs)
    t1 = time.perf_counter()
    try:
        marks = [t1]
        for src, dst in ((tiny, out + "-tiny1"), (tiny, out + "-tiny2"), (folder, out)):
            results = batch.run_many(batch.plan([src], dst, ".mcap"), archive_file, flags, client=client, force=True)
            bad = [r.error for r in results if r.status != "done"]
            if bad:
                raise RuntimeError(f"failed tasks: {bad[:3]}")
            marks.append(time.perf_counter())
    finally:
        client.close()
        cluster.close()
    first, again, job = (marks[i + 1] - marks[i] for i in range(3))
    return t1 - t0, first, again, job, sum(r.events for r in results)


def run() -> None:
    n = int(os.environ.get("EVSTREAM_BENCH_BATCH_N", "20"))
    total = int(float(os.environ.get("EVSTREAM_BENCH_BATCH_EVENTS", "50e6")))
    shipped = sorted((ROOT / "recordings").glob("*.npz"))
    with tempfile.TemporaryDirectory(prefix="evstream-bench-batch-") as tmp:
        folder = os.path.join(tmp, "data")
        os.mkdir(folder)
        made: dict[Path, str] = {}
        for i in range(n):
            dst = os.path.join(folder, f"rec{i:03d}.npz")
            src = shipped[i % len(shipped)]
            if src in made:
                shutil.copy(made[src], dst)
            else:
                _recording(src, dst, total // n)
                made[src] = dst
        tiny = os.path.join(tmp, "tiny")
        os.mkdir(tiny)
        for i in range(n):
            native.save(os.path.join(tiny, f"t{i:03d}.npz"), synth.scene("bar", duration_us=2_000, seed=i))
        batch.run_many(batch.plan([tiny], os.path.join(tmp, "warm"), ".mcap"), archive_file,
                       task_flags("archive"), jobs=1)  # numba's cache compiled before anything is timed
        times: dict[int, list[float]] = {1: [], 2: []}
        for jobs in (1, 2, 2, 1):
            start_s, first_s, again_s, job_s, events = _job(folder, os.path.join(tmp, f"out{jobs}"), jobs, tiny)
            times[jobs].append(job_s)
            print(f"  --jobs {jobs}: {n} recordings, {events:,} events: job {job_s:.2f} s "
                  f"({events / job_s / 1e3:.0f} k ev/s); cluster start {start_s:.2f} s, workers' first use "
                  f"{first_s:.2f} s ({n} near-empty recordings), per-task cost once warm "
                  f"{1e3 * again_s / n * jobs:.0f} ms of a worker", flush=True)
        one, two = min(times[1]), min(times[2])
        print(f"  speed-up --jobs 2 / --jobs 1 (best of two each, warm workers): {one / two:.2f}x; cores available "
              f"{len(os.sched_getaffinity(0))}, load average {os.getloadavg()[0]:.1f} (other work on the machine)")

if __name__ == "__main__":
    run()
