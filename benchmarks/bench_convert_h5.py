"""`evstream convert REC OUT.h5`: peak memory and events/s as the recording grows.

A recording of N events (the shipped turntable's events repeated, later in time) written as EVT3 RAW (read
in chunks), converted to HDF5 by `evstream convert` in a fresh process per size; the process's peak
resident memory (ru_maxrss) with the memory after importing evstream subtracted. A writer that streams
keeps this flat as N grows; one that builds the file in memory grows by the file's size and more.
Wall time (the machine is shared: compare sizes within a run, not across runs).

    .venv/bin/python -m benchmarks convert_h5
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from evstream.events import EventChunk

from .common import ROOT

SIZES = (2_000_000, 8_000_000)

CHILD = """
import json, resource, sys, time
rss = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
from evstream.cli import main
import evstream.sources.hdf5, h5py
base = rss()
t0 = time.perf_counter()
rc = main(["convert", sys.argv[1], sys.argv[2], "--quiet"])
print(json.dumps({"rc": rc, "s": time.perf_counter() - t0, "base_mb": base, "peak_mb": rss()}))
"""


def repeated(source: EventChunk, n_events: int, chunk: int = 200_000):
    """`source`'s events over and over, each pass later by its span, as chunks; `n_events` in all."""
    span = int(source.t[-1] - source.t[0]) + 1
    done = k = 0
    while done < n_events:
        take = min(len(source), n_events - done)
        for a in range(0, take, chunk):
            part = source[a:min(a + chunk, take)]
            yield EventChunk.from_arrays(part.t + k * span, part.x, part.y, part.p, source.geometry)
        done += take
        k += 1


def run(sizes=SIZES) -> None:
    from evstream.sources import prophesee_raw

    import evstream

    turntable = evstream.read(ROOT / "recordings" / "turntable.npz")
    print(f"{'events':>11} {'RAW MB':>8} {'HDF5 MB':>8} {'peak MB over imports':>21} {'events/s':>11}")
    with tempfile.TemporaryDirectory() as d:
        for n in sizes:
            raw, out = Path(d) / f"in{n}.raw", Path(d) / f"out{n}.h5"
            prophesee_raw.save(raw, repeated(turntable, n), turntable.geometry)
            r = subprocess.run([sys.executable, "-c", CHILD, str(raw), str(out)], capture_output=True, text=True,
                               cwd=ROOT)
            if r.returncode != 0:
                print(f"{n:>11,} failed: {r.stderr.strip().splitlines()[-1:]}")
                continue
            m = json.loads(r.stdout.strip().splitlines()[-1])
            ok = evstream.info(out)["events"] == n
            print(f"{n:>11,} {raw.stat().st_size / 1e6:8.1f} {out.stat().st_size / 1e6:8.1f} "
                  f"{m['peak_mb'] - m['base_mb']:21.0f} {n / m['s']:11,.0f}{'' if ok else '  (event count differs!)'}",
                  flush=True)
            raw.unlink()
            out.unlink()


if __name__ == "__main__":
    run()
