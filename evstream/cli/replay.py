"""`evstream replay`: a recording through a pipeline into the Rerun viewer (or an .rrd file), paced."""

from __future__ import annotations

import gc
import json
import shlex
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from .. import threads
from ..framing import options as framer_options
from ..pipeline import paced
from .common import (
    FAST_CHUNK_EVENTS,
    STORED_CLASSES_NOTE,
    Progress,
    StopOnSignal,
    UsageError,
    add_pipeline_flags,
    add_quiet_flag,
    add_source_flags,
    attach_framer,
    check_numbers,
    counted,
    create_folder,
    folder_note,
    not_the_input,
    open_recording,
    pipeline_from_args,
    summary_line,
)
from .rerun_file import check_rrd_name, rerun_command


class LagMeter:
    """Real-time lag of a paced replay: wall-clock time from when a chunk was due (its last event's
    time at `speed`, counted from when the first chunk left the source) until every sink had it."""

    def __init__(self, speed: float):
        self.speed = speed
        self.t0_event: int | None = None
        self.t0_wall = 0.0
        self.lags_s: list[float] = []

    def watch(self, chunks):
        for chunk in chunks:
            if self.t0_event is None and len(chunk):
                self.t0_event, self.t0_wall = int(chunk.t[0]), time.monotonic()
            yield chunk

    def __call__(self, batch) -> None:
        if self.speed > 0 and len(batch.events) and self.t0_event is not None:
            due = self.t0_wall + (int(batch.events.t[-1]) - self.t0_event) * 1e-6 / self.speed
            self.lags_s.append(time.monotonic() - due)

    def as_dict(self) -> dict:
        if not self.lags_s:
            return {}
        lags = np.asarray(self.lags_s) * 1e3
        return {"lag_median_ms": float(np.median(lags)), "lag_mean_ms": float(lags.mean()),
                "lag_p99_ms": float(np.percentile(lags, 99)),
                "lag_max_ms": float(lags.max()), "lag_end_ms": float(lags[-1])}


def _load_rerun():
    """The Rerun sink's modules (the SDK, pyarrow), imported with the garbage collector paused and then
    frozen: they make some 60,000 objects that live as long as the process, which each later full
    collection would walk again — the interpreter's own at exit took ~0.07 s of a 10 M-event replay."""
    paused = gc.isenabled()
    gc.disable()
    try:
        from evstream.sinks import rerun_sink, rerun_viewer
    finally:
        if paused:
            gc.enable()
    gc.freeze()
    return rerun_sink, rerun_viewer


def cmd_replay(args) -> int:
    rerun_sink, rerun_viewer = _load_rerun()

    outputs = [o for o in ("save", "spawn", "serve", "viewer") if getattr(args, o)]
    if len(outputs) > 1:
        raise UsageError(f"--{outputs[0]} and --{outputs[1]}: choose one place for the Rerun output")
    if args.point_budget < 0:
        raise UsageError(f"--point-budget {args.point_budget}: must be >= 0 (0 = every event)")
    check_numbers(args, at_least_zero=("speed",), positive=("slab_ms",))
    not_the_input(args.source, args.save, "--save ")
    check_rrd_name(args.save)
    source = open_recording(args.source, args, FAST_CHUNK_EVENTS if args.speed == 0 else None)
    pipeline = pipeline_from_args(args, source)
    attach_framer(pipeline, args)
    save, spawn, chosen = args.save, args.spawn, False
    if not outputs:  # a desktop viewer where there is a display, else a file
        if rerun_viewer.has_display():
            spawn = True
        else:  # a name the user did not give: an earlier file of that name is kept (out/STEM.1.rrd, ...)
            save, chosen = str(Path("out") / (Path(args.source).stem + ".rrd")), True
    created = create_folder(Path(save).parent) if save else ""
    out = rerun_viewer.open_output(save=save, spawn=spawn, serve=args.serve, connect=args.viewer, bind=args.bind,
                                   memory_limit=args.memory_limit, inputs=[args.source], keep_existing=chosen)
    try:
        geometry = pipeline.out_geometry(source.geometry)  # after the transforms (crop, rotate, downsample)
        pace = rerun_sink.FILE_SENDS if out.mode == "save" else {}  # a file: Rerun's writer kept busy
        sink = rerun_sink.RerunSink(out.rec, geometry=geometry, framer=getattr(pipeline.framer, "kind", None),
                                    point_budget_hz=args.point_budget or None, slab_ms=args.slab_ms,
                                    play_state=None if out.mode == "save" else "following", **pace)
        if out.web_url:
            print(f"web viewer: {out.web_url}", flush=True)
        lag = LagMeter(args.speed)
        progress = Progress(source, quiet=args.quiet)

        def on_batch(batch):
            lag(batch)
            progress(batch)

        served = _ServeUntilStopped() if out.mode == "serve" else None  # before the run: no window without it
        with StopOnSignal() as stop, out.guard():  # Ctrl-C: stop after the chunk in progress, then the summary
            stats = pipeline.run(paced(lag.watch(source), args.speed), [sink], on_batch=on_batch,
                                 threads=threads.enabled(default=False), stop=lambda: stop.signum is not None)
        progress.done()
        stopped_by = signal.Signals(stop.signum).name if stop.signum else None
        existed = bool(save) and Path(save).exists()
        written = out.finish(interrupted=bool(stopped_by))  # cut short: set aside, an older SAVE left as it was
        summary = {**stats.as_dict(), "points_logged": sink.points_logged, "points_dropped": sink.points_dropped,
                   **lag.as_dict(), "output": out.mode, "rrd": written, "partial": bool(save and stopped_by),
                   "kept": str(out.file.output.taken) if out.file is not None and out.file.output.taken else None,
                   "grpc_url": out.grpc_url,
                   "web_url": out.web_url, "stopped_by": stopped_by, "created_folder": created or None}
        if args.json:
            print(json.dumps(summary), flush=True)
        else:
            print(summary_line(stats))
            for line in pipeline.reports():  # what a transform dropped (the rate limiter)
                print(line)
            if getattr(args, "stored_classes", False):
                print(STORED_CLASSES_NOTE)
            shown = sink.points_logged + sink.points_dropped
            if sink.points_dropped:
                burst = int(sink.budget.capacity)  # saved-up points: a short recording draws more than rate x time
                print(f"3D view: {sink.points_logged:,} of {counted(shown, 'event')} drawn, {sink.points_dropped:,} "
                      f"dropped by the point budget ({args.point_budget:,}/s of event time, bursts up to "
                      f"{burst:,}); frames and stats use all")
            if lag.lags_s:
                d = lag.as_dict()
                print(f"real-time lag: median {d['lag_median_ms']:.1f} ms, p99 {d['lag_p99_ms']:.1f} ms, "
                      f"max {d['lag_max_ms']:.1f} ms, at the end {d['lag_end_ms']:.1f} ms")
            if save:
                print(f"wrote {written}{folder_note(created)} — open it with:  {rerun_command()} "
                      f"{shlex.quote(written)}   (or: evstream replay {shlex.quote(args.source)} --spawn / --serve; "
                      "the .rrd is the viewer's)")
                if summary["kept"]:
                    print(f"  {save} (an earlier file) is left as it was; --save {shlex.quote(save)} would "
                          "replace it")
        sys.stdout.flush()
        if stopped_by:
            where = (f"; {save} {'left as it was' if existed else 'not written'}; the recording of the events up "
                     f"to there is {written}") if save else ""
            print(f"evstream: interrupted by {stopped_by}{where}", file=sys.stderr)
            return 128 + int(stop.signum)
        if served is not None:
            print(f"serving {out.web_url} until Ctrl-C", file=sys.stderr, flush=True)
            served.wait(out.process)
    finally:
        out.stop()
    return 0


class _ServeUntilStopped:
    """`replay --serve` after the run: Ctrl-C or SIGTERM (a service manager's stop) ends the server cleanly,
    exit 0. Installed before the run, so `StopOnSignal` puts these handlers back when the run ends: a signal
    that comes while the summary prints is kept, not a traceback or a death by SIGTERM."""

    def __init__(self):
        self.stopped = threading.Event()
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, self._handle)

    def _handle(self, signum, frame):
        self.stopped.set()

    def wait(self, server) -> None:
        """Until a stop signal, or until the server process ends by itself."""
        while not self.stopped.wait(0.2) and server.poll() is None:
            pass


def add_parser(sub) -> None:
    p = sub.add_parser("replay", help="replay a recording through a pipeline into the Rerun viewer")
    p.add_argument("source", metavar="REC", help="a recording, any format evstream reads (docs/formats.md)")
    add_source_flags(p)
    add_pipeline_flags(p)
    p.add_argument("--speed", type=float, default=0.0, help="1 = real time, 0 = as fast as possible")
    p.add_argument("--save", metavar="OUT.rrd", help="write a Rerun recording")
    p.add_argument("--spawn", action="store_true", help="open the desktop viewer (default with a display)")
    p.add_argument("--serve", action="store_true",
                   help="serve the web viewer (for a remote or headless machine) until Ctrl-C")
    p.add_argument("--viewer", "--connect", dest="viewer", metavar="URL",
                   help="log to a running Rerun viewer (rerun+http://HOST:PORT/proxy)")
    p.add_argument("--bind", metavar="ADDR", default="127.0.0.1",
                   help="address --serve and --spawn listen on (default 127.0.0.1; 0.0.0.0 = all interfaces)")
    p.add_argument("--memory-limit", metavar="SIZE", default="25%",
                   help="viewer memory (--spawn) or server buffer (--serve), e.g. 2GiB or 25%% (default)")
    p.add_argument("--point-budget", type=int, default=1_000_000, metavar="N",
                   help="most 3D points per second of event time (0 = every event); frames and stats use all")
    p.add_argument("--slab-ms", type=float, default=100.0, help="depth of the 3D view's time slab")
    p.add_argument("--json", action="store_true", help="print run statistics as JSON")
    add_quiet_flag(p)
    framer_options.add_framer_flags(p)
    p.set_defaults(func=cmd_replay)
