"""`evstream info` and `evstream convert`: describe a recording, convert it to another format."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .. import api
from ..batch import TaskStop
from ..writers import convert, not_a_file_format
from .batch import add_batch_flags, add_sources_and_out, many, run_batch
from .common import (
    Progress,
    UsageError,
    add_quiet_flag,
    add_source_flags,
    counted,
    create_folder,
    folder_note,
    not_the_input,
    reader_options,
)


def cmd_info(args) -> int:
    out = api.info(args.source, **reader_options(args))
    n, duration, t_first, t_last = out["events"], out["duration_us"], out["t_first_us"], out["t_last_us"]
    if args.json:
        print(json.dumps(out, default=str))
        return 0
    print(f"{out['path']}")
    print(f"  format     {out['format']}")
    where = out["source"].get("geometry_from")
    print(f"  geometry   {out['width']}x{out['height']}" + (f"  (from {where})" if where else ""))
    print(f"  events     {n:,}")
    print(f"  duration   {duration / 1e6:.6f} s  ({t_first} .. {t_last} µs)" if n else "  duration   -  (no events)")
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


def cmd_convert(args) -> int:
    """Convert a recording by the output's extension; several recordings, folders or globs into a folder
    (the format from --to) on a Dask cluster (evstream.batch)."""
    if many(args.source, args.out, OUT_KINDS):
        return run_batch(args, convert_file, "." + args.to)
    args.source = args.source[0]
    summary = convert_one(args)
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {summary['out']}{folder_note(summary['created_folder'] or '')} ({summary['format']}, "
              f"{summary['width']}x{summary['height']}): {counted(summary['events'], 'event')}")
    return 0


OUT_KINDS = (".npz", ".raw", ".h5", ".hdf5")


def convert_one(args, stop: TaskStop | None = None) -> dict:
    """Convert `args.source` to `args.out` (the one-file command without its printing): the flags checked,
    then `evstream.convert`; its summary, with the folder made for OUT. `stop` (a batch task's): once
    set, the conversion ends as after a Ctrl-C (TaskInterrupted; the temporary removed, OUT as it was)."""
    out = Path(args.out)
    if out.suffix.lower() not in OUT_KINDS:
        raise UsageError(not_a_file_format(out))
    not_the_input(args.source, out, "")  # by identity: `ln X.npz h.npz; convert X.npz h.npz` rewrote X
    options = reader_options(args)
    created = create_folder(out.parent)
    progress = Progress(quiet=args.quiet, desc="convert")

    def on_progress(events: int, fraction: float | None) -> None:
        if stop is not None:
            stop.check()
        if fraction is not None:
            progress.update(100 * fraction, 100, percent=True)
        else:
            progress.update(events, None)

    try:  # written beside OUT until whole, reading on a thread of its own: a failure leaves OUT as it was
        summary = convert(args.source, out, evt=args.evt, on_progress=on_progress, **options)
    finally:
        progress.done()
    return {**summary, "source": args.source, "created_folder": created or None}


def convert_file(source: str, out: str, stop: TaskStop | None = None, **flags) -> dict:
    """One task of a batch (on a Dask worker): convert `source` to `out` with the command's flags."""
    args = argparse.Namespace(**flags, source=source, out=out)
    args.quiet = True
    return convert_one(args, stop)


def add_info_parser(sub) -> None:
    p = sub.add_parser("info", help="describe a recording")
    p.add_argument("source", metavar="REC", help="a recording, any format evstream reads (docs/formats.md)")
    add_source_flags(p)
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.set_defaults(func=cmd_info)


def add_convert_parser(sub) -> None:
    p = sub.add_parser("convert", help="convert a recording: OUT.npz (native), OUT.raw (EVT3), OUT.h5")
    add_sources_and_out(p, "OUT|FOLDER")
    add_source_flags(p)
    p.add_argument("--to", choices=["npz", "raw", "h5"], default="npz",
                   help="many recordings: the output format (default npz; one file: OUT's extension)")
    p.add_argument("--evt", choices=["3", "2"], default="3", help="EVT version of a .raw output")
    p.add_argument("--json", action="store_true", help="print what was written as JSON")
    add_quiet_flag(p)
    add_batch_flags(p)
    p.set_defaults(func=cmd_convert)
