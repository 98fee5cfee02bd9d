"""Many recordings in one command (`evstream archive DATASET/ OUT/`, `evstream convert 'rec/*.raw' OUT/`):
the flags, the plan, the run on a Dask cluster (evstream.batch), the progress and the summary table."""

from __future__ import annotations

import functools
import json
import os
import signal
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from .. import batch
from .common import Progress, StopOnSignal, UsageError, counted

# The parsed flags that are not the one-file function's (or are not plain values for the wire).
NOT_FORWARDED = {"source", "out", "jobs", "scheduler", "force", "command", "func", "debug"}


def add_sources_and_out(p, out_metavar: str) -> None:
    """The positionals of a command with a many-recordings form: SOURCE... then OUT (a file or a folder)."""
    p.add_argument("source", nargs="+", metavar="SOURCE",
                   help="a recording; or several, folders and globs (then OUT is a folder: evstream.batch)")
    p.add_argument("out", metavar=out_metavar, help="the output file (its extension: the format), or the folder of "
                   "many recordings' outputs")


def add_batch_flags(p) -> None:
    g = p.add_argument_group("many recordings (SOURCE... OUT/FOLDER)")
    g.add_argument("--jobs", "-j", type=int, metavar="N",
                   help="worker processes on this machine, one thread each (default: the cores available)")
    g.add_argument("--scheduler", metavar="tcp://HOST:8786", help="run on an existing Dask cluster instead")
    g.add_argument("--force", action="store_true", help="redo recordings whose outputs are already up to date")


def many(sources: list[str], out: str, one_file_suffixes: tuple[str, ...]) -> bool:
    """Whether the command line is the many-recordings form: OUT is a folder (it exists as one, ends in /
    or has no extension). Several sources into a file name is a usage error; one source into a file name
    is the one-file form, exactly as it always was (a folder there is its one-line error)."""
    folder = out.endswith(("/", os.sep)) or os.path.isdir(out) or not os.path.splitext(out.rstrip("/"))[1]
    if folder and len(sources) == 1 and out.lower().endswith(one_file_suffixes) and os.path.isdir(out):
        print(f"evstream: note: {out} is a folder: the output goes into it (the many-recordings form); to write "
              f"the file {out}, move the folder away", file=sys.stderr)
    if folder:
        return True
    if len(sources) > 1:  # one source into a file name keeps the one-file errors ("DIR: is a directory")
        raise UsageError(f"{out}: several recordings go to a folder: a name that exists as one, ends in / or "
                         "has no extension")
    return False


def flags_of(args) -> dict:
    """The one-file function's flags from parsed arguments, as plain values (what a task carries)."""
    return {k: v for k, v in vars(args).items() if k not in NOT_FORWARDED and _plain(v)}


def _plain(v) -> bool:
    """None, a str/int/float/bool, or a list of them (`--set` repeated): what a task may carry."""
    if isinstance(v, list | tuple):
        return all(_plain(x) and not isinstance(x, list | tuple) for x in v)
    return v is None or isinstance(v, str | int | float | bool)


def run_batch(args, work: Callable, suffix: str) -> int:
    """Plan and run the tasks; print failures as they come, then the table (or --json). Exit 1 when a
    recording failed."""
    if args.jobs is not None and args.jobs < 1:
        raise UsageError(f"--jobs {args.jobs}: must be at least 1")
    if args.jobs is not None and args.scheduler:
        raise UsageError("--jobs starts a cluster on this machine, --scheduler uses yours: one or the other")
    if os.path.isfile(args.out):
        raise UsageError(f"{args.out}: many recordings go to a folder, and this is a file")
    try:
        tasks = batch.plan(args.source, args.out, suffix)
    except ValueError as e:
        raise UsageError(str(e)) from None
    _read_once(args)
    params = flags_of(args)
    params["command_line"] = sys.argv[1:] or None
    progress = Progress(quiet=args.quiet, desc=f"{args.command} ", unit="recordings", delay_s=0.5)

    def on_result(r: batch.TaskResult, done: int, total: int) -> None:
        for said in r.warnings:
            print(f"evstream: warning: {said}", file=sys.stderr, flush=True)
        if r.status == "failed":
            print(f"evstream: {r.source}: {r.error}", file=sys.stderr, flush=True)
        progress.update(done, total)

    results, signum = run_tasks(args, tasks, work, params, on_result, functools.partial(_warm, work, suffix, params),
                                progress)
    failed = [r for r in results if r.status == "failed"]
    if args.json:
        print(json.dumps({"recordings": [r.as_dict() for r in results], "done": sum(r.status == "done" for r in
                                                                                   results),
                          "skipped": sum(r.status == "skipped" for r in results), "failed": len(failed),
                          "interrupted": sum(r.status == "interrupted" for r in results)}))
    else:
        print(table(results))
    return interrupted(signum, results) or (1 if failed else 0)


def writable_folder(out) -> None:
    """The output folder can be made and written into, else one error before the cluster starts (a read-only
    disk was Python's "[Errno 30] Read-only file system: 'OUT'" on every recording's row)."""
    if os.path.exists(out) and not os.path.isdir(out):  # a device or a pipe (a regular file: run_batch says so)
        raise OSError(f"{out}: not a folder, and many recordings go to one (one recording: an output file name "
                      "with its format's extension)")
    try:
        Path(out).mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=out).close()  # unnamed (O_TMPFILE): nothing is left in the folder
    except OSError as e:
        raise OSError(f"{out}: cannot write there: {e.strerror or e}") from None


def _read_once(args) -> None:
    """A --pipeline or --model file every task reads, read here first: one that cannot be (missing, not
    TOML, not a model) is one error before the cluster starts, not the same line on every recording's row."""
    if getattr(args, "pipeline", None):
        from ..pipeline import Pipeline

        Pipeline.from_toml(args.pipeline)
    if getattr(args, "model", None) and getattr(args, "denoise", None) == "learned":
        from ..denoise.learned.model import load

        load(args.model)


def run_tasks(args, tasks: list[batch.Task], work: Callable, params: dict, on_result, warm, progress):
    """batch.run_many with the command's --jobs/--scheduler/--force, and SIGINT/SIGTERM caught from before the
    cluster starts: a Ctrl-C at any moment stops the tasks (their outputs as after a one-file Ctrl-C).
    Returns (results, the signal that stopped the run or None)."""
    writable_folder(args.out)
    with StopOnSignal() as stop:
        try:
            results = batch.run_many(tasks, work, params, jobs=args.jobs, scheduler=args.scheduler, force=args.force,
                                     on_result=on_result, warm=warm, stop=lambda: stop.signum,
                                     reads=[getattr(args, f, None) for f in ("pipeline", "model")])
        finally:
            progress.done()
    return results, stop.signum


def interrupted(signum: int | None, results: list[batch.TaskResult]) -> int:
    """After a stop: one line saying what became of the unfinished recordings; 128 + the signal (else 0)."""
    if signum is None:
        return 0
    stopped = [r for r in results if r.status == "interrupted"]
    aside = [r.summary["mcap"] for r in stopped if r.summary.get("partial")]
    note = (f"{len(stopped)} recording(s) not finished (nothing written at their outputs; a re-run does them)"
            if stopped else "every recording had finished")
    if aside:
        note += f"; the archives so far set aside: {', '.join(aside)}"
    print(f"evstream: interrupted by {signal.Signals(signum).name}; {note}", file=sys.stderr)
    return 128 + int(signum)


def _warm(work: Callable, suffix: str, params: dict) -> None:
    """The work function once on a tiny synthetic recording (its numba kernels compiled and cached on
    disk). A failure here is not the job's: the real tasks say what is wrong."""
    from evstream import synth
    from evstream.sources import native

    with tempfile.TemporaryDirectory(prefix="evstream-warm-") as tmp:
        try:
            rec = os.path.join(tmp, "warm.npz")
            native.save(rec, synth.scene("bar", duration_us=20_000, seed=0))
            work(rec, os.path.join(tmp, "warm" + suffix), **{**params, "quiet": True})
        except Exception:  # noqa: BLE001 - see the docstring
            pass


def table(results: list[batch.TaskResult]) -> str:
    """One line per recording (events, classes, seconds, or the error), then the totals; a recording made
    again over an earlier output ("redone") says why below."""
    rows = [("recording", "status", "events", "signal", "background", "hot pixel", "s")]
    for r in results:
        c = r.classes or {}
        status = "redone" if r.status == "done" and r.redone else r.status
        rows.append((r.source, status, _n(r.events), _n(c.get("signal")), _n(c.get("background")),
                     _n(c.get("hot_pixel")), f"{r.seconds:.2f}" if r.status == "done" else ""))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(v.ljust(w) if i < 2 else v.rjust(w) for i, (v, w) in enumerate(zip(row, widths)))
             for row in rows]
    for r in results:
        if r.status == "failed" or (r.status == "interrupted" and r.error not in ("not started", "interrupted")
                                    and not r.error.startswith("stopped by")):  # ones that left a file aside
            lines.append(f"{r.status}: {r.source}: {r.error}")
        elif r.status == "done" and r.redone:
            lines.append(f"redone: {r.source}: {why_redone(r)}")
        elif r.status == "skipped" and r.note:
            lines.append(f"skipped: {r.source}: {r.note}")
    done = [r for r in results if r.status == "done"]
    kept = [r for r in done if Path(r.out).name.startswith(Path(r.source).name + ".")]  # batch.out_name
    if kept:
        lines.append(f"named: {kept[0].source} -> {kept[0].out}{f' and {len(kept) - 1} more' if len(kept) > 1 else ''}"
                     ": a recording beside another of the same name keeps its extension in its output's name")
    stopped = sum(r.status == "interrupted" for r in results)
    redone = sum(bool(r.redone) for r in done)
    lines.append(f"{len(done)} done{f' ({redone} redone)' if redone else ''}, "
                 f"{sum(r.status == 'skipped' for r in results)} skipped (up to date, same settings; --force "
                 f"redoes them), {sum(r.status == 'failed' for r in results)} failed"
                 + (f", {stopped} interrupted" if stopped else "") + "; "
                 f"{counted(sum(r.events or 0 for r in done), 'event')} in "
                 f"{sum(r.seconds for r in done):.2f} task-seconds")
    return "\n".join(lines)


def why_redone(r: batch.TaskResult) -> str:
    """Why a recording was made again, its changed settings named as the flags that set them."""
    if not r.changed:
        return r.redone
    said = []
    for key, (before, now) in r.changed.items():
        if key.startswith("contents of "):
            said.append(f"{key[len('contents of '):]} was edited")
            continue
        flag = "the task's function" if key == "work" else "--set" if key == "settings" else \
            "--" + key.replace("_", "-")
        said.append(f"{flag} {_value(before)} -> {_value(now)}")
    return "settings changed: " + ", ".join(said)


def _value(v) -> str:
    if v is None:
        return "(not given)"
    if isinstance(v, list):
        return " ".join(map(str, v)) if v else "(none)"
    return str(v)


def _n(v) -> str:
    return "" if v is None else f"{v:,}"
