"""File replay: decode throughput per format (events/s through `open_source`, validated chunks), beside
faery on the same file where faery reads it; the EVT2/EVT3 codecs alone; resident memory while a
large EVT3 file replays (a child process, so generation does not count).

Synthetic streams are uniform random events, the worst case for EVT3 (about 3 words per event, no
vectors); the real Gen4.1 recording shows a camera's stream (1.4 words per event, vectors).
Set EVSTREAM_BENCH_BIG_MB (default 1024) for the size of the memory test's file; 0 skips it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from evstream.sources import aedat2, hdf5, native, open_source, prophesee_raw

from evstream.codecs import evt2, evt3
from evstream.events import Geometry
from evstream.testing import random_stream

from .common import events_per_s, report

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


def _replay(path, **options) -> int:
    return sum(len(c) for c in open_source(path, **options))


def _faery(path, **kw) -> int | None:
    try:
        import faery
    except ImportError:
        return None
    return sum(len(c) for c in faery.events_stream_from_file(path, **kw))


def _faery_rate(path, n, **kw) -> str:
    try:
        import faery  # noqa: F401
    except ImportError:
        return "faery not installed"
    try:
        return f"faery {events_per_s(lambda: _faery(path, **kw), n, repeat=3) / 1e6:.1f} M/s"
    except Exception as e:  # faery refuses some files (DAT 'Event2d'): say so
        return f"faery: {type(e).__name__}"


def _write_dat(path, s):
    rec = np.empty((len(s), 2), "<u4")
    rec[:, 0] = s.t & 0xFFFFFFFF
    rec[:, 1] = s.x.astype(np.uint32) | (s.y.astype(np.uint32) << 14) | (s.p.astype(np.uint32) << 28)
    Path(path).write_bytes(b"% Data file containing Event2d events.\n% Version 2\n% Width 1280\n"
                           b"% Height 720\n" + bytes([0, 8]) + rec.tobytes())


def _write_nmnist(path, s):
    r = np.zeros((len(s), 5), np.uint8)
    t = s.t.astype(np.uint32) & 0x7FFFFF
    r[:, 0], r[:, 1], r[:, 2] = s.x, s.y, (s.p << 7) | (t >> 16)
    r[:, 3], r[:, 4] = (t >> 8) & 0xFF, t & 0xFF
    Path(path).write_bytes(r.tobytes())


def _write_aedat4(path, s) -> bool:
    try:
        import faery
    except ImportError:
        return False
    ev = np.zeros(len(s), faery.events_stream.EVENTS_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["on"] = s.t, s.x, s.y, s.p.astype(bool)
    faery.events_stream_from_array(ev, (s.geometry.width, s.geometry.height)).to_file(str(path))
    return True


def codecs(n: int = 3_000_000) -> None:
    s = random_stream(0, n, Geometry(1280, 720))
    for name, mod in (("evt3", evt3), ("evt2", evt2)):
        data = mod.encode(s.t, s.x, s.y, s.p)
        report(f"{name} codec decode (random, {len(data) / n:.1f} B/ev)",
               events_per_s(lambda d=data, m=mod: m.decode(d), n))
        report(f"{name} codec encode (random)", events_per_s(lambda m=mod: m.encode(s.t, s.x, s.y, s.p), n))
    path = REAL / "prophesee_gen41_hd_evt3_expelliarmus.raw"
    if path.exists():
        body = path.read_bytes()[open_source(path).body_offset:]
        t, x, y, p = evt3.decode(body)
        body = body * 10  # the same burst ten times (time steps back between copies, which is fine here)
        report("evt3 codec decode (real Gen4.1, x10)", events_per_s(lambda: evt3.decode(body), 10 * len(t)))
        ts = np.maximum.accumulate(t)
        report("evt3 codec encode (real Gen4.1)", events_per_s(lambda: evt3.encode(ts, x, y, p), len(t), repeat=10))

        def streaming():
            enc = evt3.Evt3Encoder()
            for i in range(0, len(ts), 20_000):
                enc.encode(ts[i : i + 20_000], x[i : i + 20_000], y[i : i + 20_000], p[i : i + 20_000])

        report("evt3 Evt3Encoder, 20k-event chunks (real)", events_per_s(streaming, len(t), repeat=10))


def formats(n: int = 2_000_000) -> None:
    g = Geometry(1280, 720)
    s = random_stream(1, n, g).replace(label=None)
    small = random_stream(2, n, Geometry(128, 128)).replace(label=None)
    small = small.replace(t=small.t % (1 << 23)).replace(t=np.sort(small.t % (1 << 23)))
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        files = {}
        prophesee_raw.save(d / "a.raw", s)
        files["evt3"] = (d / "a.raw", n, {})
        prophesee_raw.save(d / "b.raw", s, version="evt2")
        files["evt2"] = (d / "b.raw", n, {})
        native.save(d / "c.npz", s, compress=False)
        files["native (.npz, stored)"] = (d / "c.npz", n, None)
        np.save(d / "d.npy", s.to_structured())
        files["npy (structured, mmap)"] = (d / "d.npy", n, None)
        hdf5.save(d / "e.h5", s, compression=None)
        files["hdf5 (uncompressed)"] = (d / "e.h5", n, None)
        _write_dat(d / "f.dat", s)
        files["dat"] = (d / "f.dat", n, {})
        _write_nmnist(d / "g.bin", small)
        files["nmnist"] = (d / "g.bin", n, None)
        aedat2.save(d / "h.aedat", small.t, small.x, small.y, small.p)
        files["aedat2"] = (d / "h.aedat", n, None)
        if _write_aedat4(d / "i.aedat4", s):
            files["aedat4"] = (d / "i.aedat4", n, {})
        m = 300_000
        with open(d / "j.txt", "w") as f:
            for t, x, y, p in zip(s.t[:m] / 1e6, s.x[:m], s.y[:m], s.p[:m]):
                f.write(f"{t:.6f} {x} {y} {p}\n")
        files["text"] = (d / "j.txt", m, None)
        for name, (path, count, faery_kw) in files.items():
            rate = events_per_s(lambda p=path: _replay(p), count, repeat=3)
            vs = _faery_rate(path, count, **faery_kw) if faery_kw is not None else ""
            report(f"replay {name}", rate, **({"vs": vs} if vs else {}))


def real_files() -> None:
    if not REAL.is_dir():
        print("(real recordings absent: skipped)")
        return
    for path in sorted(REAL.iterdir()):
        if path.suffix == ".md":
            continue
        n = _replay(path)
        rate = events_per_s(lambda p=path: _replay(p), n, repeat=3)
        extra = {}
        if path.suffix in (".raw", ".aedat4"):
            kw = {"dimensions_fallback": (640, 480)} if "gen3" in path.name else {}
            extra["vs"] = _faery_rate(path, n, **kw)
        report(f"replay real {path.name[:36]} ({n / 1e3:.0f} k)", rate, **extra)


# VmHWM, not ru_maxrss: Linux carries the parent's high-water mark across fork+exec into ru_maxrss
_CHILD = """
import json, sys, time
from evstream.sources import open_source
t0 = time.perf_counter()
n = sum(len(c) for c in open_source(sys.argv[1]))
hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))
print(json.dumps({"events": n, "s": time.perf_counter() - t0, "rss_mb": hwm / 1024}))
"""


def big_file_memory() -> None:
    size_mb = int(os.environ.get("EVSTREAM_BENCH_BIG_MB", "1024"))
    if size_mb <= 0:
        return
    base = random_stream(3, 1_000_000, Geometry(1280, 720))
    span = int(base.t[-1]) + 1
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "big.raw"
        enc = evt3.Evt3Encoder()
        with open(path, "wb") as f:
            f.write(b"% evt 3.0\n% format EVT3;height=720;width=1280\n% end\n")
            k = 0
            while f.tell() < size_mb << 20:
                f.write(enc.encode(base.t + k * span, base.x, base.y, base.p))
                k += 1
        out = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True,
                             check=True, cwd=Path(__file__).resolve().parents[1])
        r = json.loads(out.stdout)
        gb = path.stat().st_size / 2**30
        report(f"replay {gb:.2f} GB EVT3 file (child process)", r["events"] / r["s"],
               events=f"{r['events'] / 1e6:.0f}M", peak_rss_mb=f"{r['rss_mb']:.0f}")


def run() -> None:
    codecs()
    formats()
    real_files()
    big_file_memory()


if __name__ == "__main__":
    run()
