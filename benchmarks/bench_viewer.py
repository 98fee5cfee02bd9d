"""Rerun sink: logging throughput (events/s into an .rrd and into a local gRPC server, with and without
the 3D point budget) and the real-time lag of `replay --speed 1` on a 1 M events/s recording.

The recording: the turntable scene on a DAVIS346 with background activity and hot pixels injected up
to about 1 M events/s (`evstream.synth` + `evstream.noise`), classified by the ground-truth stage.
"""

from __future__ import annotations

import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from evstream.sinks.rerun_sink import RerunSink
from evstream.sinks.rerun_viewer import free_port, open_output, rerun_binary, wait_listening
from evstream.sources import native

from evstream.cli import LagMeter
from evstream.events import Geometry
from evstream.noise import NoiseSpec, inject
from evstream.pipeline import Pipeline, build, paced
from evstream.synth import scene

from .common import peak_rss_mb, report

DURATION_US = 4_000_000
RATE_HZ = 1_000_000


def make_recording(path: Path, rate_hz: float = RATE_HZ, duration_us: int = DURATION_US) -> int:
    """Turntable + injected noise at about `rate_hz` events/s in total; returns the event count."""
    g = Geometry(346, 260)
    signal = scene("turntable", g, duration_us=duration_us, seed=1)
    signal_hz = len(signal) / (duration_us * 1e-6)
    ba_rate_hz = max(rate_hz - signal_hz, 0) * 0.95 / g.n_pixels  # 5 % left for the hot pixels
    hot = NoiseSpec(ba_rate_hz=ba_rate_hz, hot_pixels=40)
    events = inject(signal, hot, seed=2, t_start_us=0, t_stop_us=duration_us)
    native.save(path, events, {"scene": "turntable", "rate_hz": rate_hz}, compress=False)
    return len(events)


def _replay(path: Path, out, speed: float, chunk_events: int, **sink_options):
    src = native.open(path, chunk_events=chunk_events)
    sink = RerunSink(out.rec, geometry=src.geometry, **sink_options)
    lag = LagMeter(speed)
    t0 = time.perf_counter()
    stats = Pipeline([build("stage", {"kind": "truth"})]).run(paced(lag.watch(src), speed), [sink], on_batch=lag)
    out.finish()
    return stats, sink, lag, time.perf_counter() - t0


def run() -> None:
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        rec = d / "fast.npz"
        n = make_recording(rec)
        rate = n / (DURATION_US * 1e-6)
        print(f"recording: {n:,} events over {DURATION_US / 1e6:g} s = {rate / 1e6:.2f} M events/s "
              f"(turntable + background activity + 40 hot pixels, 346x260)")
        # logging throughput, as fast as possible, into a file
        for budget in (None, 1e6, 2e5):
            stats, sink, _, wall = _replay(rec, open_output(save=str(d / "a.rrd")), 0, 50_000,
                                           point_budget_hz=budget)
            label = "all points" if budget is None else f"budget {budget / 1e6:g} M points/s"
            report(f"sink -> .rrd, {label}", n / wall, points_drawn=f"{sink.points_logged:,}",
                   dropped=f"{sink.points_dropped:,}", rrd_MB=f"{(d / 'a.rrd').stat().st_size / 1e6:.0f}")
        # into a local gRPC server (what --serve and --spawn talk to), bound to 127.0.0.1
        port = free_port()
        log = Path(d) / "rerun-server.log"
        with open(log, "wb") as out:
            server = subprocess.Popen([rerun_binary(), "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port),
                                       "--server-memory-limit", "2GiB"], stdout=out, stderr=subprocess.STDOUT)
        try:
            wait_listening(server, "127.0.0.1", [port], 20.0, log)
            url = f"rerun+http://127.0.0.1:{port}/proxy"
            stats, sink, _, wall = _replay(rec, open_output(connect=url), 0, 50_000, point_budget_hz=1e6)
            report("sink -> gRPC server, budget 1 M points/s", n / wall,
                   dropped=f"{sink.points_dropped:,}")
            # real time: --speed 1, with a live source's chunk size (10 ms) and the default budget
            for chunk_events in (10_000, 50_000):
                stats, sink, lag, wall = _replay(rec, open_output(connect=url), 1.0, chunk_events,
                                                 point_budget_hz=1e6)
                lags = np.asarray(lag.lags_s) * 1e3
                report(f"--speed 1 -> gRPC, {chunk_events // 1000}k-event chunks", n / wall,
                       lag_median_ms=f"{np.median(lags):.1f}", lag_p99_ms=f"{np.percentile(lags, 99):.1f}",
                       lag_max_ms=f"{lags.max():.1f}", lag_end_ms=f"{lags[-1]:.1f}")
        finally:
            server.terminate()
            server.wait(timeout=10)
        print(f"peak RSS so far {peak_rss_mb():.0f} MB")


if __name__ == "__main__":
    run()
