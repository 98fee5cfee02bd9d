"""`evstream ...` — the composition root: the only core module that imports sources and sinks.

Exit codes: 0 ok, 1 runtime failure (bad input, I/O), 2 usage error. Errors print as one line;
`--debug` shows the traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from . import noise, synth
from .events import EventError, Geometry, NoiseClass
from .pipeline import Pipeline, RunStats, build, kinds, paced


class UsageError(Exception):
    """A command line that cannot work (exit code 2)."""


# -- shared pieces ----------------------------------------------------------------------------------
def _open(path: str, args=None):
    from sources import open_source

    return open_source(path)


def _default_denoise(has_labels: bool) -> str:
    stage_kinds = kinds("stage")
    if "paper" in stage_kinds:
        return "paper"
    return "truth" if has_labels else "none"


def _pipeline(args, source) -> Pipeline:
    if getattr(args, "pipeline", None):
        return Pipeline.from_toml(args.pipeline)
    name = args.denoise or _default_denoise(getattr(source, "has_labels", False))
    if name == "none":
        return Pipeline([])
    if name not in kinds("stage"):
        raise UsageError(f"--denoise {name}: unknown; choose from none, {', '.join(kinds('stage'))}")
    return Pipeline([build("stage", {"kind": name})])


class Progress:
    """One status line on a terminal (events, events/s, percent, noise fraction); silent when piped."""

    def __init__(self, total: int | None, stream=sys.stderr):
        self.total = total
        self.stream = stream
        self.enabled = stream.isatty()
        self._last = 0.0

    def __call__(self, batch) -> None:
        now = time.monotonic()
        if not self.enabled or now - self._last < 0.25:
            return
        self._last = now
        self.stream.write("\r" + self._line(batch.stats) + "\x1b[K")
        self.stream.flush()

    def _line(self, s: RunStats) -> str:
        pct = f" {100 * s.events_in / self.total:5.1f}%" if self.total else ""
        noise = 1 - s.per_class[NoiseClass.SIGNAL] / s.events_in if s.events_in else 0.0
        return f"{s.events_in:,} events{pct}  {s.throughput_hz / 1e6:.1f} M ev/s  noise {100 * noise:.1f}%"

    def done(self) -> None:
        if self.enabled:
            self.stream.write("\r\x1b[K")
            self.stream.flush()


# -- commands ---------------------------------------------------------------------------------------
def cmd_info(args) -> int:
    source = _open(args.source)
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
    }
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{out['path']}")
    print(f"  format     {out['format']}")
    print(f"  geometry   {out['width']}x{out['height']}")
    print(f"  events     {n:,}")
    print(f"  duration   {duration / 1e6:.6f} s  ({t_first} .. {t_last} µs)")
    print(f"  rate       {out['rate_hz'] / 1e3:,.1f} k events/s")
    print(f"  ON         {100 * out['on_fraction']:.1f} %")
    if out["labels"]:
        print("  labels     " + ", ".join(f"{k} {v:,}" for k, v in out["labels"].items()))
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
        return {"lag_mean_ms": float(lags.mean()), "lag_p99_ms": float(np.percentile(lags, 99)),
                "lag_max_ms": float(lags.max()), "lag_end_ms": float(lags[-1])}


def cmd_replay(args) -> int:
    from sinks.rerun_sink import RerunSink
    from sinks.rerun_viewer import has_display, open_output

    outputs = [o for o in ("save", "spawn", "serve", "connect") if getattr(args, o)]
    if len(outputs) > 1:
        raise UsageError(f"--{outputs[0]} and --{outputs[1]}: choose one place for the Rerun output")
    if args.point_budget < 0:
        raise UsageError(f"--point-budget {args.point_budget}: must be >= 0 (0 = every event)")
    source = _open(args.source)
    pipeline = _pipeline(args, source)
    save, spawn = args.save, args.spawn
    if not outputs:  # a desktop viewer where there is a display, else a file
        if has_display():
            spawn = True
        else:
            save = str(Path("out") / (Path(args.source).stem + ".rrd"))
    out = open_output(save=save, spawn=spawn, serve=args.serve, connect=args.connect, bind=args.bind,
                      memory_limit=args.memory_limit)
    try:
        sink = RerunSink(out.rec, geometry=source.geometry, framer=getattr(pipeline.framer, "kind", None),
                         point_budget_hz=args.point_budget or None, slab_ms=args.slab_ms,
                         play_state=None if out.mode == "save" else "following")
        if out.web_url:
            print(f"web viewer: {out.web_url}", flush=True)
        lag = LagMeter(args.speed)
        progress = Progress(total=None)

        def on_batch(batch):
            lag(batch)
            progress(batch)

        stats = pipeline.run(paced(lag.watch(source), args.speed), [sink], on_batch=on_batch)
        progress.done()
        out.finish()
        summary = {**stats.as_dict(), "points_logged": sink.points_logged, "points_dropped": sink.points_dropped,
                   **lag.as_dict(), "output": out.mode, "rrd": save, "web_url": out.web_url}
        if args.json:
            print(json.dumps(summary), flush=True)
        else:
            print(_summary_line(stats))
            shown = sink.points_logged + sink.points_dropped
            if sink.points_dropped:
                print(f"3D view: {sink.points_logged:,} of {shown:,} events drawn, {sink.points_dropped:,} "
                      f"dropped by the point budget ({args.point_budget:,}/s); frames and stats use all")
            if lag.lags_s:
                d = lag.as_dict()
                print(f"real-time lag: mean {d['lag_mean_ms']:.1f} ms, p99 {d['lag_p99_ms']:.1f} ms, "
                      f"max {d['lag_max_ms']:.1f} ms")
            if save:
                print(f"wrote {save} — open it with:  rerun {save}   (or: evstream replay --spawn / --serve)")
        sys.stdout.flush()
        if out.mode == "serve":
            print(f"serving {out.web_url} until Ctrl-C", file=sys.stderr, flush=True)
            try:
                out.process.wait()
            except KeyboardInterrupt:
                pass
    finally:
        out.stop()
    return 0


def _summary_line(s: RunStats) -> str:
    pc = s.per_class
    return (f"{s.events_in:,} events in {s.wall_s:.2f} s ({s.throughput_hz / 1e6:.1f} M ev/s): "
            f"signal {pc[0]:,}, background {pc[1]:,}, hot pixel {pc[2]:,}")


def cmd_synth(args) -> int:
    from sources import native

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
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="replay a recording through a pipeline into the Rerun viewer")
    p.add_argument("source")
    _add_pipeline_flags(p)
    p.add_argument("--speed", type=float, default=0.0, help="1 = real time, 0 = as fast as possible")
    p.add_argument("--save", metavar="OUT.rrd", help="write a Rerun recording")
    p.add_argument("--spawn", action="store_true", help="open the desktop viewer (default with a display)")
    p.add_argument("--serve", action="store_true",
                   help="serve the web viewer (for a remote or headless machine) until Ctrl-C")
    p.add_argument("--connect", metavar="URL", help="log to a running viewer (rerun+http://HOST:PORT/proxy)")
    p.add_argument("--bind", metavar="ADDR", default="127.0.0.1",
                   help="address --serve and --spawn listen on (default 127.0.0.1; 0.0.0.0 = all interfaces)")
    p.add_argument("--memory-limit", metavar="SIZE", default="25%",
                   help="viewer memory (--spawn) or server buffer (--serve), e.g. 2GiB or 25%% (default)")
    p.add_argument("--point-budget", type=int, default=1_000_000, metavar="N",
                   help="most 3D points per second of event time (0 = every event); frames and stats use all")
    p.add_argument("--slab-ms", type=float, default=100.0, help="depth of the 3D view's time slab")
    p.add_argument("--json", action="store_true", help="print run statistics as JSON")
    p.set_defaults(func=cmd_replay)

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
    return ap


def main(argv=None) -> int:
    ap = parser()
    args = ap.parse_args(argv)  # exits 2 on usage errors
    try:
        return args.func(args)
    except UsageError as e:
        print(f"evstream: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("evstream: interrupted", file=sys.stderr)
        return 130
    except (EventError, OSError, ValueError) as e:
        if args.debug:
            raise
        print(f"evstream: error: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # a bug of ours: still one line unless --debug
        if args.debug:
            raise
        print(f"evstream: internal error: {type(e).__name__}: {e} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
