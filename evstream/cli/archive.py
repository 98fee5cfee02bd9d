"""`evstream archive`: clean a recording into an MCAP archive (ROS 2, Foxglove and Rerun open it)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..batch import TaskStop
from ..framing import options as framer_options
from ..writers import archive
from .batch import add_batch_flags, add_sources_and_out, many, run_batch
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


def cmd_archive(args) -> int:
    """Clean a recording into an MCAP archive (EventPackets, noise per class, frames, provenance); several
    recordings, folders or globs into an output folder on a Dask cluster (evstream.batch)."""
    import signal

    if many(args.source, args.out, (".mcap",)):
        return run_batch(args, archive_file, ".mcap")
    args.source = args.source[0]
    if not args.out.endswith(".mcap"):
        raise UsageError(f"{args.out}: the archive's name must end in .mcap")
    with StopOnSignal() as stop:
        summary, stats, created = archive_one(args, stop)
    if args.json:
        print(json.dumps(summary), flush=True)
    else:
        print(summary_line(stats))
        if getattr(args, "stored_classes", False):
            print(STORED_CLASSES_NOTE)
        print(f"wrote {summary['mcap']}{folder_note(created)}: {counted(summary['packets'], 'event packet')}, "
              f"{counted(summary['frames_written'], 'frame')}")
    if stop.signum is not None:
        print(f"evstream: interrupted by {signal.Signals(stop.signum).name}; {interrupted_note(args.out, summary)}",
              file=sys.stderr)
        return 128 + int(stop.signum)
    return 0


def interrupted_note(out: str, summary: dict) -> str:
    """What an interrupted file archive left: the target as it was (or not there), the events so far aside."""
    target = f"{out} left as it was" if Path(out).exists() else f"{out} not written"
    if not summary.get("partial"):  # stopped after the last chunk: nothing was cut short
        return f"{out} is complete"
    return f"{target}; the archive of the events up to there is {summary['mcap']}"


def archive_one(args, stop: StopOnSignal | TaskStop | None = None):
    """Archive `args.source` to `args.out` (the one-file command without its printing): the flags checked
    and turned into a pipeline, then `evstream.archive`; returns (summary dict, RunStats, the folder it
    created or '')."""
    import signal

    check_numbers(args, at_least_zero=("speed",), positive=("packet_us", "flush_s"))
    not_the_input(args.source, args.out, "")  # `archive A.mcap A.mcap` emptied A.mcap and exited 0
    source = open_recording(args.source, args, FAST_CHUNK_EVENTS if args.speed == 0 else None)
    pipeline = pipeline_from_args(args, source)
    if args.frames and (args.framer or "none") == "none" and pipeline.framer is None:
        args.framer = "fw"  # what --frames alone writes: --window-us and the like apply to it
    attach_framer(pipeline, args)
    created = create_folder(Path(args.out).parent)
    progress = Progress(source, quiet=args.quiet)
    try:
        summary = archive(source, args.out, pipeline=pipeline, keep_noise=args.keep_noise, frames=args.frames,
                          frame_format=args.frame_format, points=args.points, camera=args.camera,
                          encoding=args.encoding, packet_us=args.packet_us, flush_s=args.flush_s, speed=args.speed,
                          command=getattr(args, "command_line", None) or sys.argv[1:] or None, on_batch=progress,
                          stop=(lambda: stop.signum is not None) if stop else None, path=args.source)
    finally:
        progress.done()
    signum = stop.signum if stop else None
    summary.update(created_folder=created or None,
                   stopped_by=signal.Signals(signum).name if signum else None)
    return summary, pipeline.stats, created


def archive_file(source: str, out: str, stop=None, **flags) -> dict:
    """One task of a batch (on a Dask worker): archive `source` to `out` with the command's flags (plain
    values); returns the summary. `stop` (evstream.batch.TaskStop): the run stopped, the archive so far is
    set aside as after a Ctrl-C (the summary's `partial`)."""
    args = argparse.Namespace(**flags, source=source, out=out)
    args.quiet = True
    return archive_one(args, stop)[0]


def add_parser(sub) -> None:
    p = sub.add_parser("archive", help="clean a recording into an MCAP archive (ROS 2, Foxglove, Rerun open it)")
    add_sources_and_out(p, "OUT.mcap|FOLDER")
    add_source_flags(p)
    add_pipeline_flags(p)
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
    add_quiet_flag(p)
    framer_options.add_framer_flags(p)
    add_batch_flags(p)
    p.set_defaults(func=cmd_archive)
