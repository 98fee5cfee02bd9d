"""`evstream info` and `evstream convert`: describe a recording, convert it to another format."""

from __future__ import annotations

import argparse
import contextlib
import json
from pathlib import Path

from .. import api, threads
from ..safe_write import AtomicOutput
from .batch import add_batch_flags, add_sources_and_out, many, run_batch
from .common import (
    Progress,
    UsageError,
    add_quiet_flag,
    add_source_flags,
    create_folder,
    folder_note,
    not_the_input,
    open_recording,
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
              f"{summary['width']}x{summary['height']}): {summary['events']:,} events")
    return 0


OUT_KINDS = (".npz", ".raw", ".h5", ".hdf5")


def convert_one(args) -> dict:
    """Convert `args.source` to `args.out` (the one-file command without its printing); the summary."""
    from evstream.sources import hdf5, native, prophesee_raw

    out = Path(args.out)
    kind = out.suffix.lower()
    if kind not in OUT_KINDS:
        raise UsageError(f"{args.out}: output format from the extension: .npz (native), .raw (EVT3/EVT2), .h5")
    not_the_input(args.source, out, "")  # by identity: `ln X.npz h.npz; convert X.npz h.npz` rewrote X
    source = open_recording(args.source, args)
    created = create_folder(out.parent)
    progress = Progress(source, quiet=args.quiet, desc="convert")
    reader = threads.ReadAhead(source) if threads.enabled() else contextlib.nullcontext(source)
    with reader as read, AtomicOutput(out, [args.source]) as part:  # beside OUT until whole: a failure
        chunks = _reported(read, progress)  # leaves OUT as it was; reading on a thread of its own
        if kind == ".raw":  # streamed
            n = prophesee_raw.save(part, chunks, source.geometry, version=f"evt{args.evt}")
            fmt = f"evt{args.evt}"
        elif kind == ".npz":
            from ..events import concat

            events = concat(list(chunks), source.geometry)  # the native writer takes whole arrays
            n = len(events)
            native.save(part, events, {"converted_from": str(args.source),
                                       "source_format": getattr(source, "format", "?")})
            fmt = "native"
        else:  # streamed
            with hdf5.Writer(part, source.geometry) as writer:
                for chunk in chunks:
                    writer.append(chunk)
            n, fmt = writer.events, "hdf5"
    progress.done()
    return {"source": args.source, "out": str(out), "format": fmt, "events": n,
            "width": source.geometry.width, "height": source.geometry.height, "created_folder": created or None}


def convert_file(source: str, out: str, **flags) -> dict:
    """One task of a batch (on a Dask worker): convert `source` to `out` with the command's flags."""
    args = argparse.Namespace(**flags, source=source, out=out)
    args.quiet = True
    return convert_one(args)


def _reported(source, progress):
    """The source's chunks, telling the progress bar how far into the file they are."""
    events = 0
    for chunk in source:
        events += len(chunk)
        fraction = getattr(source, "fraction_read", None)
        if fraction is not None:
            progress.update(100 * fraction, 100, percent=True)
        else:
            progress.update(events, None)
        yield chunk


def add_info_parser(sub) -> None:
    p = sub.add_parser("info", help="describe a recording")
    p.add_argument("source")
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
