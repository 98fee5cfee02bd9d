"""`evstream frames`: frame a recording with one or more framers; frame statistics, PNGs."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from ..batch import GLOB_MAGIC, TaskStop
from ..events import NoiseClass
from ..framing import options as framer_options
from ..framing.render import STYLES
from ..pipeline import build
from ..safe_write import AtomicFolder, AtomicOutput
from .batch import add_batch_flags, run_batch
from .common import (
    STORED_CLASSES_NOTE,
    Progress,
    UsageError,
    add_pipeline_flags,
    add_quiet_flag,
    add_source_flags,
    counted,
    first_missing,
    folder_note,
    open_recording,
    pipeline_from_args,
)


def frames_one(args, stop: TaskStop | None = None) -> list[dict]:
    """The one-file command without its printing: one row of statistics per framer. `stop` (a batch
    task's): once set, the run ends as after a Ctrl-C (TaskInterrupted; OUT as it was, OUT.part removed)."""
    try:
        kinds_ = framer_options.framer_kinds(args)
        framer_options.framers_from_args(args)  # validate every parameter before reading anything
    except ValueError as e:
        raise UsageError(str(e)) from None
    if not kinds_:
        raise UsageError("--framer none: name a framer (fw, fn, oa, adaptive)")
    rows = []
    created = first_missing(args.out) if args.out else ""
    # every file goes to OUT.part/ first and into OUT once every framer ran: a failed run leaves OUT as it was
    staging = AtomicFolder(args.out, replaces=("frame_*.png", "frame_*.npz")) if args.out else None
    try:
        for kind in kinds_:
            rows.append(_frame_with(kind, args, staging.part if staging else None, len(kinds_) > 1, stop))
    except BaseException as e:
        raised = staging.failed(e) if staging is not None else e  # a full disk: said of OUT, not OUT.part/...
        if raised is e:
            raise
        raise raised from None
    if staging is not None:
        staging.commit()
        rows[0]["created_folder"] = created or None  # said once, with the first framer's files
    return rows


def _frame_with(kind: str, args, staging: Path | None, several: bool, stop: TaskStop | None = None) -> dict:
    """One framer's run over the recording: its row of statistics; its files into `staging` (/KIND)."""
    from ..framing.arrays import ArrayWriter
    from ..framing.render import PngWriter
    from ..framing.represent import REPRESENTATIONS
    from ..framing.stats import FrameStats

    source = open_recording(args.source, args)
    pipeline = pipeline_from_args(args, source)
    pipeline.framer = build("framer", framer_options.framer_spec(kind, args))
    fstats = FrameStats()  # fed per chunk: frames the end of the stream cut short are left out
    sinks = []
    writer = None
    if staging is not None:
        # a representation's arrays as .npz (one per window); frames as PNG pictures
        folder = staging / kind if several else staging
        writer = ArrayWriter(folder) if kind in REPRESENTATIONS else PngWriter(folder, style=args.style)
        sinks.append(writer)
    progress = Progress(source, quiet=args.quiet, desc=kind)

    def on_batch(batch):
        fstats.add_frames(batch.frames)
        progress(batch)
        if stop is not None:
            stop.check()

    stats = pipeline.run(source, sinks, on_batch=on_batch)  # frames in batches of bounded size (Pipeline.feed)
    progress.done()
    fstats.duration_us = stats.duration_us
    return {"framer": pipeline.describe()["framer"], **fstats.as_dict(),
            "frames_at_end": stats.frames - fstats.frames,
            "events_in": stats.events_in, "events_signal": int(stats.per_class[NoiseClass.SIGNAL]),
            "denoise": [st["kind"] for st in pipeline.describe()["stages"]],
            "png_dir": str(Path(args.out) / kind if several else Path(args.out)) if writer else None,
            "png_written": writer.written if writer else 0,
            "files": "npz" if kind in REPRESENTATIONS else "png",
            "events_dropped": stats.events_dropped, "reports": pipeline.reports(),
            "created_folder": None}


SUMMARY_SUFFIX = ".frames.json"  # a recording's statistics, written last: its frames are complete


def cmd_frames(args) -> int:
    """Frame a recording with one or more framers; print the paper's frame statistics, write PNGs. Several
    recordings, folders or globs with --out FOLDER: one task each on a Dask cluster (evstream.batch), each
    recording's frames in OUT/ITS-PATH/ and its statistics in OUT/ITS-PATH.frames.json."""
    # a folder alone without --out keeps the one-file form's error ("DIR: is a directory, not a recording")
    if len(args.source) > 1 or any(GLOB_MAGIC & set(s) or (args.out and os.path.isdir(s)) for s in args.source):
        if not args.out:
            raise UsageError("several recordings: --out FOLDER (each recording's frames in a folder of its own)")
        return run_batch(args, frames_file, SUMMARY_SUFFIX)
    args.source = args.source[0]
    rows = frames_one(args)
    if args.json:
        print(json.dumps({"source": args.source, "results": rows}))
        return 0
    print(f"{args.source}: {rows[0]['events_in']:,} events over {rows[0]['duration_us'] / 1e6:.3f} s, "
          f"denoise: {', '.join(rows[0]['denoise']) or 'none'}")
    if getattr(args, "stored_classes", False):
        print(STORED_CLASSES_NOTE)
    print("frames closed by the end of the stream (cut short) are written but not counted")
    print(f"{'framer':<10} {'frames':>7} {'rate (fps)':>11} {'mean events':>12} {'variance':>16} {'empty':>6}")
    for r in rows:
        print(f"{r['framer']['kind']:<10} {r['frames']:>7,} {r['frame_rate_hz']:>11.2f} {r['mean_events']:>12,.2f} "
              f"{r['variance_events']:>16,.2f} {r['empty_frames']:>6,}")
        if r["png_dir"]:
            n = r["png_written"]
            what = f"{counted(n, 'array')} (.npz)" if r["files"] == "npz" else counted(n, "PNG frame")
            print(f"  wrote {what} to {r['png_dir']}{folder_note(r['created_folder'])}")
        for line in r["reports"]:
            print(f"  {line}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("frames", help="frame a recording; print frame rate and events per frame, write PNGs")
    p.add_argument("source", nargs="+", metavar="SOURCE",
                   help="a recording; or several, folders and globs (with --out FOLDER: evstream.batch)")
    add_source_flags(p)
    add_pipeline_flags(p)
    framer_options.add_framer_flags(p, default="adaptive", several=True)
    p.add_argument("--out", metavar="DIR", help="write every frame as a PNG into DIR (DIR/<framer> for several); "
                                                 "a representation's arrays as .npz, one per window")
    p.add_argument("--style", default="paper", choices=STYLES,
                   help="PNG rendering: paper (gray, ON white, OFF black), signed, or a colour map")
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    add_quiet_flag(p)
    add_batch_flags(p)
    p.set_defaults(func=cmd_frames)


def frames_file(source: str, out: str, stop: TaskStop | None = None, **flags) -> dict:
    """One task of a batch (on a Dask worker): `source`'s frames into OUT's folder (OUT without
    .frames.json), then its statistics into OUT, whole or not at all: OUT exists only once every frame
    was written, which is what makes a re-run skip the recording."""
    folder = out[: -len(SUMMARY_SUFFIX)]
    args = argparse.Namespace(**{**flags, "source": source, "out": folder, "quiet": True})
    rows = frames_one(args, stop)
    summary = {"source": source, "out": folder, "results": rows, "events_in": rows[0]["events_in"],
               "events_signal": rows[0]["events_signal"], "frames": sum(r["frames"] for r in rows)}
    with AtomicOutput(Path(out), [source]) as part:
        Path(part).write_text(json.dumps(summary))
    return summary
