"""Many recordings on a local Dask cluster (evstream.batch): `--jobs 2` against `--jobs 1` on a folder of
recordings (the shipped three, copied to N files), interleaved in one run (1, 2, 2, 1) so a load that
changes meanwhile hits both; and the per-task overhead (a folder of near-empty recordings: the job's time
per task, the cluster's start apart). Archive with the paper's cascade, as `evstream archive DIR/ OUT/`.

Environment variables: EVSTREAM_BENCH_BATCH_N (recordings, default 20).
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


def _job(folder: str, out: str, jobs: int) -> tuple[float, float, int]:
    """(cluster start s, job s, events) for the folder archived with `jobs` workers."""
    t0 = time.perf_counter()
    client, cluster = batch.start_client(jobs)
    t1 = time.perf_counter()
    try:
        tasks = batch.plan([folder], out, ".mcap")
        results = batch.run_many(tasks, archive_file, task_flags("archive"), client=client, force=True)
    finally:
        client.close()
        cluster.close()
    t2 = time.perf_counter()
    bad = [r.error for r in results if r.status != "done"]
    if bad:
        raise RuntimeError(f"failed tasks: {bad[:3]}")
    return t1 - t0, t2 - t1, sum(r.events for r in results)


def run() -> None:
    n = int(os.environ.get("EVSTREAM_BENCH_BATCH_N", "20"))
    shipped = sorted((ROOT / "recordings").glob("*.npz"))
    with tempfile.TemporaryDirectory(prefix="evstream-bench-batch-") as tmp:
        folder = os.path.join(tmp, "data")
        os.mkdir(folder)
        for i in range(n):
            shutil.copy(shipped[i % len(shipped)], os.path.join(folder, f"rec{i:03d}.npz"))
        tiny = os.path.join(tmp, "tiny")
        os.mkdir(tiny)
        for i in range(n):
            native.save(os.path.join(tiny, f"t{i:03d}.npz"), synth.scene("bar", duration_us=2_000, seed=i))
        batch.run_many(batch.plan([tiny], os.path.join(tmp, "warm"), ".mcap"), archive_file,
                       task_flags("archive"), jobs=1)  # numba's cache compiled before anything is timed
        times: dict[int, list[float]] = {1: [], 2: []}
        events = 0
        for jobs in (1, 2, 2, 1):
            start_s, job_s, events = _job(folder, os.path.join(tmp, f"out{jobs}"), jobs)
            times[jobs].append(job_s)
            print(f"  --jobs {jobs}: {n} recordings, {events:,} events: cluster start {start_s:.2f} s, "
                  f"job {job_s:.2f} s ({events / job_s / 1e3:.0f} k ev/s)", flush=True)
        one, two = min(times[1]), min(times[2])
        print(f"  speed-up --jobs 2 / --jobs 1 (best of two each): {one / two:.2f}x; "
              f"cores available {len(os.sched_getaffinity(0))}, load average {os.getloadavg()[0]:.1f}")
        for jobs in (1, 2):
            start_s, job_s, tiny_events = _job(tiny, os.path.join(tmp, f"tiny{jobs}"), jobs)
            print(f"  per-task overhead, --jobs {jobs}: {1e3 * job_s / n * jobs:.0f} ms of a worker per "
                  f"near-empty recording ({tiny_events // n} events each; job {job_s:.2f} s for {n})", flush=True)


if __name__ == "__main__":
    run()
