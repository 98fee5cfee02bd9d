"""`evstream ...` — the composition root: the only core module that imports sources and sinks.

Exit codes: 0 ok, 1 runtime failure (bad input, I/O), 2 usage error. Errors print as one line;
`--debug` shows the traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from . import noise, synth
from .events import EventError, Geometry, NoiseClass
from .framing import options as framer_options
from .framing.render import STYLES
from .pipeline import Pipeline, RunStats, build, kinds, paced


class UsageError(Exception):
    """A command line that cannot work (exit code 2)."""


# -- shared pieces ----------------------------------------------------------------------------------
def _open(path: str, args=None):
    from evstream.sources import open_source

    options = {}
    if getattr(args, "geometry", None):
        options["geometry"] = _geometry_flag(args.geometry)
    if getattr(args, "timestamps", None):
        options["timestamps"] = args.timestamps
    return open_source(path, **options)


def _geometry_flag(text: str):
    """`--geometry WxH` as a Geometry; a bad one is a usage error naming what was typed
    (`--geometry 0x0: Geometry.width must be ...`, not `--Geometry.width ...`)."""
    from evstream.sources._base import as_geometry

    try:
        return as_geometry(text)
    except ValueError as e:
        raise UsageError(f"--geometry {text}: {str(e).removeprefix(f'geometry {text!r}: ')}") from None


def _not_the_input(source: str, out, flag: str) -> None:
    """An output that is the input recording would destroy it before (or while) it is read."""
    if out and os.path.exists(out) and os.path.exists(source) and os.path.samefile(source, out):
        raise UsageError(f"{flag}{out}: that is the input recording; writing there would destroy it")


def _check_numbers(args, *, at_least_zero=(), positive=()) -> None:
    """Flag values that cannot work are usage errors (exit 2), named as typed: `--speed -1: must be >= 0`.
    NaN and infinity are refused too (`--speed nan` used to replay as fast as possible)."""
    for names, ok, rule in ((at_least_zero, lambda v: v >= 0, ">= 0"), (positive, lambda v: v > 0, "positive")):
        for name in names:
            v = getattr(args, name, None)
            if v is not None and not (math.isfinite(v) and ok(v)):
                raise UsageError(f"--{name.replace('_', '-')} {v:g}: must be {rule} (a finite number)")


def _add_source_flags(p) -> None:
    p.add_argument("--geometry", metavar="WxH", help="sensor size, overriding the file's")
    p.add_argument("--timestamps", choices=["error", "sort", "drop"],
                   help="what to do with timestamps that go back (default: the format's)")


def _pipeline(args, source) -> Pipeline:
    if getattr(args, "pipeline", None):
        return Pipeline.from_toml(args.pipeline)
    name = args.denoise or "paper"
    if name == "none":
        return Pipeline([])
    if name not in kinds("stage"):
        raise UsageError(f"--denoise {name}: unknown; choose from none, {', '.join(kinds('stage'))}")
    return Pipeline([build("stage", {"kind": name})])


def event_rate(hz: float) -> str:
    """An event rate with the digits that say something: '5.4 M ev/s', '147 k ev/s', '512 ev/s'
    (a fixed '{hz / 1e6:.1f} M' printed '0.0 M ev/s' for every run of a small recording)."""
    if hz >= 1e6:
        return f"{hz / 1e6:.1f} M ev/s"
    if hz >= 1e3:
        return f"{hz / 1e3:.0f} k ev/s"
    return f"{hz:.0f} ev/s"


class Progress:
    """One status line on a terminal (percent of the file where the reader knows it, events, events/s,
    noise fraction); silent when piped."""

    def __init__(self, source=None, stream=None):
        self.source = source
        self.stream = sys.stderr if stream is None else stream  # at call time: stderr may have been swapped
        self.enabled = self.stream.isatty()
        self._last = 0.0

    def __call__(self, batch) -> None:
        now = time.monotonic()
        if not self.enabled or now - self._last < 0.25:
            return
        self._last = now
        self.stream.write("\r" + self._line(batch.stats) + "\x1b[K")
        self.stream.flush()

    def _line(self, s: RunStats) -> str:
        noise = 1 - s.per_class[NoiseClass.SIGNAL] / s.events_in if s.events_in else 0.0
        fraction = getattr(self.source, "fraction_read", None)
        done = f"{100 * fraction:3.0f}%  " if fraction is not None else ""
        return f"{done}{s.events_in:,} events  {event_rate(s.throughput_hz)}  noise {100 * noise:.1f}%"

    def done(self) -> None:
        if self.enabled:
            self.stream.write("\r\x1b[K")
            self.stream.flush()


# -- commands ---------------------------------------------------------------------------------------
def cmd_info(args) -> int:
    source = _open(args.source, args)
    n = 0
    on = 0
    t_first = t_last = None
    labels = np.zeros(3, np.int64)
    has_labels = True
    for chunk in source:
        if not len(chunk):
            continue
        n += len(chunk)
        on += int(chunk.p.sum())
        t_first = int(chunk.t[0]) if t_first is None else t_first
        t_last = int(chunk.t[-1])
        if chunk.label is None:
            has_labels = False
        else:
            labels += chunk.class_counts("label")
    duration = (t_last - t_first) if n else 0
    out = {
        "path": args.source,
        "format": getattr(source, "format", type(source).__name__),
        "width": source.geometry.width,
        "height": source.geometry.height,
        "events": n,
        "t_first_us": t_first,
        "t_last_us": t_last,
        "duration_us": duration,
        "rate_hz": n / (duration * 1e-6) if duration > 0 else 0.0,
        "on_fraction": on / n if n else 0.0,
        "labels": {c.name.lower(): int(labels[c]) for c in NoiseClass} if has_labels and n else None,
        "source": source.info() if hasattr(source, "info") else {},  # reader details, after the read
    }
    if args.json:
        print(json.dumps(out, default=str))
        return 0
    print(f"{out['path']}")
    print(f"  format     {out['format']}")
    where = out["source"].get("geometry_from")
    print(f"  geometry   {out['width']}x{out['height']}" + (f"  (from {where})" if where else ""))
    print(f"  events     {n:,}")
    print(f"  duration   {duration / 1e6:.6f} s  ({t_first} .. {t_last} µs)")
    print(f"  rate       {out['rate_hz'] / 1e3:,.1f} k events/s")
    print(f"  ON         {100 * out['on_fraction']:.1f} %")
    if out["labels"]:
        print("  labels     " + ", ".join(f"{k} {v:,}" for k, v in out["labels"].items()))
    skipped = {k: v for k, v in out["source"].get("counters", {}).items() if v}
    if out["source"].get("dropped"):
        skipped["dropped (timestamps back)"] = out["source"]["dropped"]
    if skipped:
        print("  skipped    " + ", ".join(f"{k} {v:,}" for k, v in skipped.items()))
    return 0


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


def cmd_replay(args) -> int:
    import signal

    from evstream.sinks.rerun_sink import RerunSink
    from evstream.sinks.rerun_viewer import has_display, open_output

    outputs = [o for o in ("save", "spawn", "serve", "viewer") if getattr(args, o)]
    if len(outputs) > 1:
        raise UsageError(f"--{outputs[0]} and --{outputs[1]}: choose one place for the Rerun output")
    if args.point_budget < 0:
        raise UsageError(f"--point-budget {args.point_budget}: must be >= 0 (0 = every event)")
    _check_numbers(args, at_least_zero=("speed",), positive=("slab_ms",))
    _not_the_input(args.source, args.save, "--save ")
    source = _open(args.source, args)
    pipeline = _pipeline(args, source)
    _attach_framer(pipeline, args)
    save, spawn = args.save, args.spawn
    if not outputs:  # a desktop viewer where there is a display, else a file
        if has_display():
            spawn = True
        else:
            save = str(Path("out") / (Path(args.source).stem + ".rrd"))
    out = open_output(save=save, spawn=spawn, serve=args.serve, connect=args.viewer, bind=args.bind,
                      memory_limit=args.memory_limit)
    try:
        sink = RerunSink(out.rec, geometry=source.geometry, framer=getattr(pipeline.framer, "kind", None),
                         point_budget_hz=args.point_budget or None, slab_ms=args.slab_ms,
                         play_state=None if out.mode == "save" else "following")
        if out.web_url:
            print(f"web viewer: {out.web_url}", flush=True)
        lag = LagMeter(args.speed)
        progress = Progress(source)

        def on_batch(batch):
            lag(batch)
            progress(batch)

        with _StopOnSignal() as stop:  # Ctrl-C: stop after the chunk in progress, then the summary as usual
            stats = pipeline.run(stop.chunks(paced(lag.watch(source), args.speed)), [sink], on_batch=on_batch)
        progress.done()
        out.finish()
        stopped_by = signal.Signals(stop.signum).name if stop.signum else None
        summary = {**stats.as_dict(), "points_logged": sink.points_logged, "points_dropped": sink.points_dropped,
                   **lag.as_dict(), "output": out.mode, "rrd": save, "grpc_url": out.grpc_url,
                   "web_url": out.web_url, "stopped_by": stopped_by}
        if args.json:
            print(json.dumps(summary), flush=True)
        else:
            print(_summary_line(stats))
            shown = sink.points_logged + sink.points_dropped
            if sink.points_dropped:
                burst = int(sink.budget.capacity)  # saved-up points: a short recording draws more than rate x time
                print(f"3D view: {sink.points_logged:,} of {shown:,} events drawn, {sink.points_dropped:,} "
                      f"dropped by the point budget ({args.point_budget:,}/s of event time, bursts up to "
                      f"{burst:,}); frames and stats use all")
            if lag.lags_s:
                d = lag.as_dict()
                print(f"real-time lag: median {d['lag_median_ms']:.1f} ms, p99 {d['lag_p99_ms']:.1f} ms, "
                      f"max {d['lag_max_ms']:.1f} ms, at the end {d['lag_end_ms']:.1f} ms")
            if save:
                print(f"wrote {save} — open it with:  {_rerun_command()} {save}   "
                      "(or: evstream replay --spawn / --serve)")
        sys.stdout.flush()
        if stopped_by:
            where = f"; {save} holds the events up to there" if save else ""
            print(f"evstream: interrupted by {stopped_by}{where}", file=sys.stderr)
            return 128 + int(stop.signum)
        if out.mode == "serve":
            print(f"serving {out.web_url} until Ctrl-C", file=sys.stderr, flush=True)

            def _stop(signum, frame):
                raise KeyboardInterrupt

            signal.signal(signal.SIGTERM, _stop)  # a service manager's stop ends the server cleanly too
            try:
                out.process.wait()
            except KeyboardInterrupt:
                pass
    finally:
        out.stop()
    return 0


def _rerun_command() -> str:
    """How to start the Rerun viewer from this shell: `rerun` when it is on PATH, else the one installed
    beside this Python (after `make demo`, `.venv/bin/rerun`: the venv is not activated)."""
    import shutil

    if shutil.which("rerun"):
        return "rerun"
    beside = Path(sys.executable).parent / "rerun"
    if not beside.exists():
        return "rerun"
    try:
        return os.path.relpath(beside) if not os.path.relpath(beside).startswith("..") else str(beside)
    except ValueError:  # another drive (Windows)
        return str(beside)


class _StopOnSignal:
    """SIGINT/SIGTERM stop the stream after the chunk in progress, so sinks close their files properly;
    a second signal interrupts at once (sinks are still closed by `Pipeline.run`)."""

    def __init__(self):
        self.signum = None
        self._old = {}

    def __enter__(self):
        import signal

        for s in (signal.SIGINT, signal.SIGTERM):
            self._old[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc):
        import signal

        for s, handler in self._old.items():
            signal.signal(s, handler)

    def _handle(self, signum, frame):
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum

    def chunks(self, source):
        for chunk in source:
            yield chunk
            if self.signum is not None:
                return


def cmd_archive(args) -> int:
    """Clean a recording into an MCAP archive (EventPackets, noise per class, frames, provenance)."""
    import signal

    from evstream.sinks.mcap_sink import McapSink

    if not args.out.endswith(".mcap"):
        raise UsageError(f"{args.out}: the archive's name must end in .mcap")
    _check_numbers(args, at_least_zero=("speed",), positive=("packet_us", "flush_s"))
    _not_the_input(args.source, args.out, "")  # `archive A.mcap A.mcap` emptied A.mcap and exited 0
    source = _open(args.source, args)
    pipeline = _pipeline(args, source)
    _attach_framer(pipeline, args)
    if args.frames and pipeline.framer is None:
        pipeline.framer = build("framer", {"kind": "fw"})
    provenance = {"source": str(args.source), "source_format": getattr(source, "format", type(source).__name__),
                  "width": source.geometry.width, "height": source.geometry.height,
                  "pipeline": pipeline.describe(), "command": sys.argv[1:] or None, "evstream": _version()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    sink = McapSink(args.out, camera=args.camera, encoding=args.encoding, keep_noise=args.keep_noise,
                    frames=pipeline.framer is not None, frame_format=args.frame_format, points=args.points,
                    packet_us=args.packet_us,
                    flush_s=args.flush_s, metadata=provenance, geometry=source.geometry)
    progress = Progress(source)
    with _StopOnSignal() as stop:
        stats = pipeline.run(stop.chunks(paced(source, args.speed)), [sink], on_batch=progress)
    progress.done()
    summary = {**stats.as_dict(), "mcap": args.out, "packets": sink.packets, "frames_written": sink.frames_written,
               "stopped_by": signal.Signals(stop.signum).name if stop.signum else None}
    if args.json:
        print(json.dumps(summary), flush=True)
    else:
        print(_summary_line(stats))
        print(f"wrote {args.out}: {sink.packets:,} event packets, {sink.frames_written:,} frames")
    if stop.signum is not None:
        print(f"evstream: interrupted by {signal.Signals(stop.signum).name}; {args.out} is complete up to there",
              file=sys.stderr)
        return 128 + int(stop.signum)
    return 0


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("evstream")
    except Exception:  # not installed (running from a source tree)
        return "unknown"


def _attach_framer(pipeline: Pipeline, args) -> None:
    """Set the pipeline's framer from `--framer` and its parameter flags (a TOML framer stays otherwise)."""
    try:
        framers = framer_options.framers_from_args(args)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if len(framers) > 1:
        raise UsageError(f"--framer {args.framer}: this command takes one framer")
    if framers:
        pipeline.framer = framers[0]


def cmd_frames(args) -> int:
    """Frame a recording with one or more framers; print the paper's frame statistics, write PNGs."""
    from .framing.render import PngWriter
    from .framing.stats import FrameStats

    try:
        kinds_ = framer_options.framer_kinds(args)
        framer_options.framers_from_args(args)  # validate every parameter before reading anything
    except ValueError as e:
        raise UsageError(str(e)) from None
    if not kinds_:
        raise UsageError("--framer none: name a framer (fw, fn, oa, adaptive)")
    rows = []
    for kind in kinds_:
        source = _open(args.source, args)
        pipeline = _pipeline(args, source)
        pipeline.framer = build("framer", framer_options.framer_spec(kind, args))
        fstats = FrameStats()  # fed per chunk: frames the end of the stream cut short are left out
        sinks = []
        writer = None
        if args.out:
            out_dir = Path(args.out) / kind if len(kinds_) > 1 else Path(args.out)
            writer = PngWriter(out_dir, style=args.style)
            sinks.append(writer)
        progress = Progress(source)

        def on_batch(batch, fstats=fstats, progress=progress):
            fstats.add_frames(batch.frames)
            progress(batch)

        stats = pipeline.run(source, sinks, on_batch=on_batch)
        progress.done()
        fstats.duration_us = stats.duration_us
        rows.append({"framer": pipeline.describe()["framer"], **fstats.as_dict(),
                     "frames_at_end": stats.frames - fstats.frames,
                     "events_in": stats.events_in, "events_signal": int(stats.per_class[NoiseClass.SIGNAL]),
                     "denoise": [st["kind"] for st in pipeline.describe()["stages"]],
                     "png_dir": str(writer.out_dir) if writer else None,
                     "png_written": writer.written if writer else 0})
    if args.json:
        print(json.dumps({"source": args.source, "results": rows}))
        return 0
    print(f"{args.source}: {rows[0]['events_in']:,} events over {rows[0]['duration_us'] / 1e6:.3f} s, "
          f"denoise: {', '.join(rows[0]['denoise']) or 'none'}")
    print("frames closed by the end of the stream (cut short) are written but not counted")
    print(f"{'framer':<10} {'frames':>7} {'rate (fps)':>11} {'mean events':>12} {'variance':>16} {'empty':>6}")
    for r in rows:
        print(f"{r['framer']['kind']:<10} {r['frames']:>7,} {r['frame_rate_hz']:>11.2f} {r['mean_events']:>12,.2f} "
              f"{r['variance_events']:>16,.2f} {r['empty_frames']:>6,}")
        if r["png_dir"]:
            print(f"  wrote {r['png_written']:,} PNG frames to {r['png_dir']}")
    return 0


def _summary_line(s: RunStats) -> str:
    pc = s.per_class
    wall = f"{s.wall_s:.2f}" if s.wall_s >= 1 else f"{s.wall_s:.3g}"  # '0.01 s' and '1.2 M ev/s' disagreed
    return (f"{s.events_in:,} events in {wall} s ({event_rate(s.throughput_hz)}): "
            f"signal {pc[0]:,}, background {pc[1]:,}, hot pixel {pc[2]:,}")


def cmd_convert(args) -> int:
    from evstream.sources import hdf5, native, prophesee_raw

    out = Path(args.out)
    kind = out.suffix.lower()
    if kind not in (".npz", ".raw", ".h5", ".hdf5"):
        raise UsageError(f"{args.out}: output format from the extension: .npz (native), .raw (EVT3/EVT2), .h5")
    if out.resolve() == Path(args.source).resolve():
        raise UsageError("convert: the output would overwrite the input")
    source = _open(args.source, args)
    out.parent.mkdir(parents=True, exist_ok=True)
    if kind == ".raw":  # streamed: into a side file, renamed once whole, so a failure leaves no valid-looking
        part = out.with_name(out.name + ".part")  # half recording (nor clobbers an older OUT)
        try:
            n = prophesee_raw.save(part, source, source.geometry, version=f"evt{args.evt}")
            os.replace(part, out)
        finally:
            part.unlink(missing_ok=True)
        fmt = f"evt{args.evt}"
    else:
        from .events import concat

        events = concat(list(source), source.geometry)  # these writers take whole arrays
        n = len(events)
        if kind == ".npz":
            native.save(out, events, {"converted_from": str(args.source),
                                      "source_format": getattr(source, "format", "?")})
            fmt = "native"
        else:
            hdf5.save(out, events)
            fmt = "hdf5"
    summary = {"source": args.source, "out": str(out), "format": fmt, "events": n,
               "width": source.geometry.width, "height": source.geometry.height}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {out} ({fmt}, {source.geometry}): {n:,} events")
    return 0


def cmd_synth(args) -> int:
    from evstream.sources import native

    geometry = Geometry(args.width, args.height)
    events = synth.scene(args.scene, geometry, duration_us=int(args.duration_ms * 1000), seed=args.seed)
    meta = {"scene": args.scene, "seed": args.seed, "duration_ms": args.duration_ms,
            "generator": "evstream synth"}
    if args.noise_ratio is not None or args.ba_rate_hz is not None:
        spec = noise.NoiseSpec(noise_ratio=args.noise_ratio, ba_rate_hz=args.ba_rate_hz,
                               hot_pixels=args.hot_pixels, hot_share=args.hot_share)
        events = noise.inject(events, spec, seed=args.seed + 1, t_start_us=0,
                              t_stop_us=int(args.duration_ms * 1000))
        meta["noise"] = {k: v for k, v in vars(spec).items()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    native.save(args.out, events, meta)
    counts = events.class_counts("label")
    print(f"wrote {args.out}: {len(events):,} events ({counts[0]:,} signal, {counts[1]:,} background, "
          f"{counts[2]:,} hot pixel)")
    return 0


def cmd_eval(args) -> int:
    from . import evaluation

    _check_numbers(args, positive=("seeds",))  # --seeds 0 printed empty tables and exited 0
    for flag, out in (("--json", args.json), ("--roc", args.roc)):  # before minutes of work, not after
        if out:
            try:
                if not Path(out).parent.exists():
                    Path(out).parent.mkdir(parents=True)
                existed = Path(out).exists()
                with open(out, "a"):
                    pass
                if not existed:  # only a probe: no empty file left behind if the run fails
                    Path(out).unlink()
            except OSError as e:
                raise OSError(f"{flag} {out}: cannot write there: {e.strerror or e}") from None
    paths = list(args.recordings) or sorted(str(p) for p in Path("recordings").glob("*.npz"))
    if args.real:
        paths += sorted(str(p) for p in Path(args.real).iterdir() if p.is_file() and p.suffix != ".md")
    recordings = {}
    seen = set()  # (events, first t, last t): a converted twin of a file already read is skipped
    for path in paths:
        try:
            events = _read_all(path)
        except (EventError, OSError, ValueError) as e:
            print(f"evstream eval: skipping {path}: {e}", file=sys.stderr)
            continue
        duration_s = events.duration_us * 1e-6
        if duration_s < args.min_duration_s:
            print(f"evstream eval: skipping {path}: {duration_s:.3f} s is shorter than --min-duration-s",
                  file=sys.stderr)
            continue
        signature = (len(events), int(events.t[0]), int(events.t[-1]))
        if signature in seen:
            print(f"evstream eval: skipping {path}: same events as a recording already read", file=sys.stderr)
            continue
        seen.add(signature)
        recordings[Path(path).stem] = events
    if not recordings:
        raise UsageError("no recording to evaluate")
    methods = args.methods.split(",") if args.methods else list(evaluation.METHODS)
    conditions = [evaluation.Condition(noise_ratio=r) for r in args.ratios] + [
        evaluation.Condition(ba_rate_hz=r) for r in args.rates_hz]
    curves: dict = {}
    say = (lambda m: print(f"\r{m}\x1b[K", end="", file=sys.stderr)) if sys.stderr.isatty() else None
    rows = evaluation.run(recordings, conditions, range(args.seeds), methods, tune=args.tune,
                          progress=say, curves=curves)
    if say:
        print(file=sys.stderr)
    print(evaluation.report(rows, tune=args.tune))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(evaluation.as_json_rows(rows), indent=1))
        print(f"wrote {args.json} ({len(rows)} rows)")
    if args.roc:
        try:
            names = [c.name for c in conditions]
            condition = args.roc_condition or ("100%" if "100%" in names else names[0])
            evaluation.plot_roc(curves, condition, args.roc)
            print(f"wrote {args.roc}")
        except ImportError:
            print("evstream eval: matplotlib is not installed; no ROC plot (pip install matplotlib)",
                  file=sys.stderr)
    return 0


def _read_all(path: str):
    from .events import concat

    source = _open(path)
    return concat(list(source), source.geometry)


# -- argument parsing -------------------------------------------------------------------------------
def _add_pipeline_flags(p) -> None:
    p.add_argument("--denoise", metavar="NAME", help="denoise stage (none, truth, ...); default: the paper's")
    p.add_argument("--pipeline", metavar="FILE.toml", help="pipeline description (overrides --denoise)")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="evstream", description="Streaming event-camera pipeline.")
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("info", help="describe a recording")
    p.add_argument("source")
    _add_source_flags(p)
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="replay a recording through a pipeline into the Rerun viewer")
    p.add_argument("source")
    _add_source_flags(p)
    _add_pipeline_flags(p)
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
    framer_options.add_framer_flags(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("archive", help="clean a recording into an MCAP archive (ROS 2, Foxglove, Rerun open it)")
    p.add_argument("source")
    p.add_argument("out", metavar="OUT.mcap")
    _add_source_flags(p)
    _add_pipeline_flags(p)
    p.add_argument("--keep-noise", action="store_true",
                   help="also write the removed events, one topic per noise class (nothing is lost)")
    p.add_argument("--frames", action="store_true", help="write frames (foxglove.RawImage); --framer picks (fw)")
    p.add_argument("--frame-format", choices=["foxglove", "ros2"], default="foxglove",
                   help="frames as foxglove.RawImage (protobuf) or sensor_msgs/Image (an all-ROS 2 file)")
    p.add_argument("--points", action="store_true", help="write X-Y-T point clouds (foxglove.PointCloud)")
    p.add_argument("--camera", default="camera", help="topic prefix: /CAMERA/events ... (default camera)")
    p.add_argument("--encoding", choices=["evt3", "mono"], default="evt3", help="EventPacket encoding")
    p.add_argument("--packet-us", type=int, default=10_000, help="event time per packet (default 10000)")
    p.add_argument("--flush-s", type=float, default=1.0,
                   help="close a chunk at least this often: what a crash can lose (default 1 s)")
    p.add_argument("--speed", type=float, default=0.0, help="1 = real time, 0 = as fast as possible")
    p.add_argument("--json", action="store_true", help="print run statistics as JSON")
    framer_options.add_framer_flags(p)
    p.set_defaults(func=cmd_archive)

    p = sub.add_parser("frames", help="frame a recording; print frame rate and events per frame, write PNGs")
    p.add_argument("source")
    _add_pipeline_flags(p)
    framer_options.add_framer_flags(p, default="adaptive", several=True)
    p.add_argument("--out", metavar="DIR", help="write every frame as a PNG into DIR (DIR/<framer> for several)")
    p.add_argument("--style", default="paper", choices=STYLES,
                   help="PNG rendering: paper (gray, ON white, OFF black), signed, or a colour map")
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.set_defaults(func=cmd_frames)

    p = sub.add_parser("convert", help="convert a recording: OUT.npz (native), OUT.raw (EVT3), OUT.h5")
    p.add_argument("source")
    p.add_argument("out")
    _add_source_flags(p)
    p.add_argument("--evt", choices=["3", "2"], default="3", help="EVT version of a .raw output")
    p.add_argument("--json", action="store_true", help="print what was written as JSON")
    p.set_defaults(func=cmd_convert)

    p = sub.add_parser("synth", help="simulate a scene with ground-truth labels")
    p.add_argument("scene", choices=sorted(synth.SCENES))
    p.add_argument("out", help="output .npz (native format)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration-ms", type=float, default=1000.0)
    p.add_argument("--width", type=int, default=synth.DEFAULT_GEOMETRY.width)
    p.add_argument("--height", type=int, default=synth.DEFAULT_GEOMETRY.height)
    p.add_argument("--noise-ratio", type=float, help="noise events per signal event (0.5 = 50 %%)")
    p.add_argument("--ba-rate-hz", type=float, help="background activity per pixel (instead of a ratio)")
    p.add_argument("--hot-pixels", type=int, default=0, help="hot pixel count (with --ba-rate-hz)")
    p.add_argument("--hot-share", type=float, default=0.1, help="share of noise from hot pixels (ratio)")
    p.set_defaults(func=cmd_synth)

    p = sub.add_parser("eval", help="inject labelled noise, run every denoiser, print the paper's tables")
    p.add_argument("recordings", nargs="*", help="recordings (default: recordings/*.npz)")
    p.add_argument("--real", metavar="DIR", help="also every readable recording in DIR")
    p.add_argument("--methods", help="comma-separated (default: all)")
    p.add_argument("--ratios", type=float, nargs="*", default=[0.1, 0.2, 0.5, 1.0, 1.5, 2.0],
                   help="noise ratios (0.5 = 50 %%)")
    p.add_argument("--rates-hz", type=float, nargs="*", default=[1.0, 3.0, 5.0],
                   help="background activity rates, Hz/pixel")
    p.add_argument("--seeds", type=int, default=2, help="noise seeds per condition")
    p.add_argument("--tune", action="store_true", help="tune each threshold on the first half, report the second")
    p.add_argument("--min-duration-s", type=float, default=0.25, help="skip shorter recordings")
    p.add_argument("--json", metavar="FILE", help="write every result row as JSON")
    p.add_argument("--roc", metavar="FILE.png", help="plot ROC curves")
    p.add_argument("--roc-condition", help="noise condition of the ROC plot, e.g. 100%% or 3Hz (default 100%%)")
    p.set_defaults(func=cmd_eval)

    from . import cli_live  # publish, subscribe, router: live streams over Zenoh

    cli_live.add_parsers(sub, _add_source_flags, _add_pipeline_flags, framer_options.add_framer_flags)
    return ap


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning (a truncated file, dropped events) as one line for the user, not Python's
    `path.py:123: EventWarning: ...` plus a line of our source code."""
    print(f"evstream: warning: {message}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    ap = parser()
    args = ap.parse_args(argv)  # exits 2 on usage errors
    with warnings.catch_warnings():  # restores the caller's warning display afterwards
        if not args.debug:
            warnings.showwarning = _show_warning
        return _run(args)


def _run(args) -> int:
    try:
        return args.func(args)
    except UsageError as e:
        print(f"evstream: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("evstream: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `evstream info REC | head -3`: the reader left; not an error to print
        try:  # Python's own flush of stdout at exit must not raise it again
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):  # stdout is not a real file (captured)
            pass
        return 141  # 128 + SIGPIPE, as a tool killed by it
    except (EventError, OSError, ValueError) as e:
        if args.debug:
            raise
        print(f"evstream: error: {e}", file=sys.stderr)
        return 1
    except MemoryError as e:  # e.g. a --geometry far larger than the sensor: the state does not fit
        if args.debug:
            raise
        print(f"evstream: error: out of memory: {e or 'an allocation failed'}", file=sys.stderr)
        return 1
    except Exception as e:  # a bug of ours: still one line unless --debug
        if args.debug:
            raise
        print(f"evstream: internal error: {type(e).__name__}: {e} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    from evstream.cli import main as _main  # one copy of this module (cli_live imports evstream.cli)

    sys.exit(_main())
