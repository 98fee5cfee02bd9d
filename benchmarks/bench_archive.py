"""Archiving throughput: the EVT3 encoder alone, the MCAP sink alone, and end to end
(native file -> paper cascade -> EVT3 EventPackets -> zstd MCAP) at 346×260, on one core and threaded
(reading and writing beside the stages, as `evstream archive` runs; whole processes: bench_commands.py).

Stream: the turntable scene (2 s) with 3 Hz/pixel background activity and 0.1 % hot pixels, saved as a
native .npz (plain, and zipped as `evstream synth` writes it) and read back in the source's 50k-event
chunks, as `evstream archive` does.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
from evstream.sinks.mcap_sink import McapSink
from evstream.sources import native, open_source

from evstream.codecs import evt3
from evstream.codecs.packets import evt3_sensor_clock
from evstream.events import Geometry, concat
from evstream.noise import NoiseSpec, inject
from evstream.pipeline import Pipeline, build
from evstream.synth import scene

from .common import events_per_s, peak_alloc_bytes, report

G = Geometry(346, 260)
DURATION_US = 2_000_000


def recording(folder: str, compress: bool) -> str:
    path = os.path.join(folder, f"turntable{'-zip' if compress else ''}.npz")
    sig = scene("turntable", G, duration_us=DURATION_US, seed=0)
    spec = NoiseSpec(ba_rate_hz=3.0, hot_pixels=G.n_pixels // 1000, hot_rate_hz=(500.0, 2000.0))
    native.save(path, inject(sig, spec, seed=1, t_start_us=0, t_stop_us=DURATION_US), compress=compress)
    return path


def run() -> None:
    with tempfile.TemporaryDirectory() as folder:
        src_path = recording(folder, compress=False)
        zip_path = recording(folder, compress=True)
        out = os.path.join(folder, "out.mcap")
        chunks = list(open_source(src_path))
        s = concat(chunks)
        n = len(s)
        print(f"-- turntable {G}: {n:,} events, {n / DURATION_US:.2f} M events/s of sensor time")

        # the EVT3 encoder alone: one call, and 10 ms packets on the sensor clock (what the sink writes)
        eps = events_per_s(lambda: evt3.encode(s.t, s.x, s.y, s.p), n)
        report("evt3 encode, one call", eps, bytes_per_event=f"{len(evt3.encode(s.t, s.x, s.y, s.p)) / n:.2f}")
        cuts = np.searchsorted(s.t, np.arange(0, DURATION_US + 10_000, 10_000))

        def packets():
            for a, b in zip(cuts[:-1], cuts[1:]):
                if b > a:
                    evt3_sensor_clock(s.t[a:b], s.x[a:b], s.y[a:b], s.p[a:b])

        report("evt3 encode, 10 ms packets", events_per_s(packets, n))

        # the sink alone: events already classified (ground truth as cls)
        truth = [c.replace(cls=c.label) for c in chunks]
        for keep_noise in (False, True):
            def sink_only(keep_noise=keep_noise):
                Pipeline([]).run(truth, [McapSink(out, frames=False, keep_noise=keep_noise)])

            eps = events_per_s(sink_only, n, repeat=3)
            report(f"MCAP sink alone, keep_noise={keep_noise}", eps, file_MB=f"{os.path.getsize(out) / 1e6:.1f}")

        # end to end, as `evstream archive --denoise paper` runs: read the file, clean, encode, write; on one
        # thread, and with reading and writing on threads of their own (evstream.threads, what the command does)
        for path, keep_noise, frames in ((zip_path, False, False), (src_path, False, False),
                                         (src_path, True, False), (src_path, True, True)):
            for threads in (False, True):
                def end_to_end(path=path, keep_noise=keep_noise, frames=frames, threads=threads):
                    pipe = Pipeline([build("stage", {"kind": "paper"})],
                                    build("framer", {"kind": "fw"}) if frames else None)
                    pipe.run(open_source(path), [McapSink(out, keep_noise=keep_noise, frames=frames)], threads=threads)

                eps = events_per_s(end_to_end, n, repeat=7)
                kind = "zipped" if path == zip_path else "plain"
                report(f"native ({kind}) -> paper -> MCAP, noise={keep_noise:d}, frames={frames:d}"
                       f"{', threads' if threads else ''}", eps,
                       peak_alloc_MB=f"{peak_alloc_bytes(end_to_end) / 1e6:.1f}")

        def cascade_only():
            stage = build("stage", {"kind": "paper"})
            for c in chunks:
                stage(c)

        report("(for scale) paper cascade alone", events_per_s(cascade_only, n, repeat=3))
        for path in (zip_path, src_path):
            def read(path=path):
                for _ in open_source(path):
                    pass

            report(f"(for scale) reading the native file, {'zipped' if path == zip_path else 'plain'}",
                   events_per_s(read, n, repeat=3))


if __name__ == "__main__":
    run()
