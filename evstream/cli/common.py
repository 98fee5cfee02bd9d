"""What the commands share: the usage error, flags, reading a recording, progress and signal handling.

Nothing here imports a command module; every command module imports from here.
"""

from __future__ import annotations

import math
import shutil
import signal
import sys
from pathlib import Path

from .. import api
from ..events import NoiseClass, counted  # noqa: F401 - counted: the commands import it from here
from ..framing import options as framer_options
from ..pipeline import Pipeline, RunStats, kinds


class UsageError(Exception):
    """A command line that cannot work (exit code 2)."""


def reader_options(args) -> dict:
    """The keyword options of `api.open` from the reader flags (`--geometry`, `--timestamps`,
    `--start-us`/`--end-us`), each checked here: a bad one is a usage error naming what was typed."""
    options = {"geometry": geometry_flag(args.geometry) if getattr(args, "geometry", None) else None,
               "timestamps": getattr(args, "timestamps", None)}
    start, end = getattr(args, "start_us", None), getattr(args, "end_us", None)
    if start is not None or end is not None:
        from ..transforms import TimeRange

        try:
            TimeRange(start, end)
        except ValueError as e:
            raise UsageError(f"--start-us {start} --end-us {end}: {str(e).removeprefix('time_range: ')}") from None
        options.update(start_us=start, end_us=end)
    return options


# Chunks of a file `archive` reads as fast as possible (--speed 0): each costs its threads a hand-off and a GIL wait
# (50,000 ran no faster threaded than serial; 200,000 did, docs/archive.md). Paced runs keep the readers' chunks.
FAST_CHUNK_EVENTS = 200_000


def open_recording(path: str, args=None, chunk_events: int | None = None):
    """`api.open` with the reader flags (and `chunk_events` per chunk, when given)."""
    return api.open(path, **reader_options(args), chunk_events=chunk_events)


def geometry_flag(text: str):
    """`--geometry WxH` as a Geometry; a bad one is a usage error naming what was typed
    (`--geometry 0x0: Geometry.width must be ...`, not `--Geometry.width ...`)."""
    from evstream.sources._base import as_geometry

    try:
        return as_geometry(text)
    except ValueError as e:
        raise UsageError(f"--geometry {text}: {str(e).removeprefix(f'geometry {text!r}: ')}") from None


def not_the_input(source: str, out, flag: str, what: str = "the input recording") -> None:
    """An output that is the input recording (by file identity: links too) would destroy it before (or
    while) it is read."""
    from evstream.safe_write import OutputIsInput, check_not_input

    try:
        check_not_input(out, [source], flag, what) if out else None
    except OutputIsInput as e:
        raise UsageError(str(e)) from None


def native_output(out: str, command: str) -> None:
    """A command that writes a native .npz (labels and all) refuses another name: a zip under a .raw name."""
    if Path(out).suffix.lower() != ".npz":
        raise UsageError(f"{out}: {command} writes a native .npz (with its labels); then `evstream convert` it")


def check_numbers(args, *, at_least_zero=(), positive=()) -> None:
    """Flag values that cannot work are usage errors (exit 2), named as typed: `--speed -1: must be >= 0`.
    NaN and infinity are refused too (`--speed nan` used to replay as fast as possible); a list flag, each value."""
    for names, ok, rule in ((at_least_zero, lambda v: v >= 0, ">= 0"), (positive, lambda v: v > 0, "positive")):
        for name in names:
            value = getattr(args, name, None)
            for v in value if isinstance(value, list) else [value]:
                if v is not None and not (math.isfinite(v) and ok(v)):
                    raise UsageError(f"--{name.replace('_', '-')} {v:g}: must be {rule} (a finite number)")


def add_source_flags(p) -> None:
    p.add_argument("--geometry", metavar="WxH", help="sensor size, overriding the file's")
    p.add_argument("--timestamps", choices=["error", "sort", "drop"],
                   help="what to do with timestamps that go back (default: the format's)")
    p.add_argument("--start-us", type=int, metavar="US", help="read only events at or after this time (µs)")
    p.add_argument("--end-us", type=int, metavar="US",
                   help="read only events before this time (µs); reading stops there")


def add_pipeline_flags(p) -> None:
    p.add_argument("--denoise", metavar="NAME",
                   help="denoise stage (none, truth, ...; `evstream stages` lists them); default: the paper's, "
                        "or an archive's stored classes")
    p.add_argument("--set", metavar="PARAM=VALUE", action="append", default=[], dest="settings", help="a"
                   " --denoise parameter (repeatable): --set coarse.window_us=10000 --set fine.lam=0.2; see stages")
    p.add_argument("--pipeline", metavar="FILE.toml", help="pipeline description (overrides --denoise)")
    p.add_argument("--model", metavar="MODEL.npz", help="--denoise learned: a model from `evstream train` "
                   "(default: the shipped one)")
    p.add_argument("--keep", type=float, metavar="FRACTION",
                   help="--denoise learned: the fraction of the signal to keep (default: the model's)")


STORED_CLASSES_NOTE = "noise classes as stored in the archive (--denoise NAME classifies again)"


def pipeline_from_args(args, source) -> Pipeline:
    """The pipeline the flags name; with neither flag the paper's cascade, except on an evstream archive,
    whose events keep the classes stored with them (classifying them again would stack a second filter
    on the first): then no stage, and `args.stored_classes` is set for the summary to say so."""
    settings = getattr(args, "settings", None) or []
    if getattr(args, "pipeline", None):
        if settings:
            raise UsageError(f"--set {settings[0]}: --set applies to --denoise; with --pipeline, set parameters "
                             f"in {args.pipeline}")
        return Pipeline.from_toml(args.pipeline)
    if args.denoise is None and not settings and getattr(source, "archive", False):
        args.stored_classes = True
        return Pipeline([])
    name = args.denoise or "paper"
    if name == "none":
        if settings:
            raise UsageError(f"--set {settings[0]}: --denoise none has no parameters")
        return Pipeline([])
    if name not in kinds("stage"):
        raise UsageError(f"--denoise {name}: unknown; choose from none, {', '.join(kinds('stage'))}")
    params = {}
    if getattr(args, "model", None) or getattr(args, "keep", None) is not None:
        if name != "learned":
            raise UsageError("--model and --keep go with --denoise learned")
        params = {k: v for k, v in (("model", args.model), ("keep", args.keep)) if v is not None}
    try:
        spec = api.set_params({"kind": name, **params}, settings)
    except ValueError as e:
        raise UsageError(f"--set {e}") from None
    try:  # a value the stage refuses: in the stage's words (as from a TOML file)
        return api.build_pipeline(spec)
    except ValueError as e:
        if not settings and not params:  # a stage that needs parameters (undistort): the flag was the mistake
            raise UsageError(f"--denoise {name}: {str(e).removeprefix(f'{name}: ')}") from None
        if not settings:  # --model or --keep: the file or the model's operating point, in its words
            raise
        raise UsageError(f"--set {' --set '.join(settings)}: {e}") from None


def attach_framer(pipeline: Pipeline, args) -> None:
    """Set the pipeline's framer from `--framer` and its parameter flags (a TOML framer stays otherwise)."""
    try:
        framers = framer_options.framers_from_args(args)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if len(framers) > 1:
        raise UsageError(f"--framer {args.framer}: this command takes one framer")
    if framers:
        pipeline.framer = framers[0]


def event_rate(hz: float) -> str:
    """An event rate with the digits that say something: '5.4 M ev/s', '147 k ev/s', '512 ev/s'
    (a fixed '{hz / 1e6:.1f} M' printed '0.0 M ev/s' for every run of a small recording)."""
    if hz >= 1e6:
        return f"{hz / 1e6:.1f} M ev/s"
    if hz >= 1e3:
        return f"{hz / 1e3:.0f} k ev/s"
    return f"{hz:.0f} ev/s"


class Progress:
    """A progress bar on stderr (tqdm) fed by the API's callbacks: `on_batch` for a pipeline run (percent of the
    file where the reader knows it, else events; rate and noise fraction beside), `update(done, total)` for the
    rest. Off when stderr is not a terminal or with `--quiet` (logs, pipes stay clean); shown after `delay_s`."""

    PERCENT = "{desc}{percentage:3.0f}%|{bar}| {elapsed}<{remaining}{postfix}"

    def __init__(self, source=None, stream=None, *, quiet: bool = False, desc: str | None = None,
                 unit: str = "events", min_interval_s: float = 0.25, delay_s: float = 1.0):
        self.source = source
        self.stream = sys.stderr if stream is None else stream  # at call time: stderr may have been swapped
        self.enabled = not quiet and self.stream.isatty()
        self._bar = None
        if self.enabled:  # else tqdm is not even imported (start-up time)
            from tqdm import tqdm
            size = shutil.get_terminal_size((100, 24))  # a terminal that reports no size (a new pty): 100x24
            self._bar = tqdm(total=None, desc=desc, unit=unit, unit_scale=True, file=self.stream, leave=False,
                             mininterval=min_interval_s, delay=delay_s, ncols=size.columns, nrows=size.lines)

    def __call__(self, batch) -> None:
        if not self.enabled:
            return
        s: RunStats = batch.stats
        noise = 1 - s.per_class[NoiseClass.SIGNAL] / s.events_in if s.events_in else 0.0
        self.postfix(f"{s.events_in:,} events, {event_rate(s.throughput_hz)}, noise {100 * noise:.1f}%")
        fraction = getattr(self.source, "fraction_read", None)
        if fraction is not None:
            self.update(100 * fraction, 100, percent=True)
        else:
            self.update(s.events_in, None)

    def postfix(self, text: str) -> None:
        if self.enabled:
            self._bar.set_postfix_str(text, refresh=False)

    def update(self, done: float, total: float | None, percent: bool = False) -> None:
        """Where the work is: `done` of `total` (None: unknown); `percent`: show only the percentage."""
        if not self.enabled:
            return
        if percent and self._bar.bar_format != self.PERCENT:
            self._bar.bar_format = self.PERCENT
        if total != self._bar.total:
            self._bar.total = total
        self._bar.n = done
        if done == total:
            self._bar.refresh()
        else:
            self._bar.update(0)

    def done(self) -> None:
        if self._bar is not None:
            self._bar.close()


def add_quiet_flag(p) -> None:
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar (there is none when stderr is not "
                   "a terminal)")


def create_folder(folder) -> str:
    """Make `folder` (and its parents) if missing; returns the topmost folder it made, or '' (a summary
    line says what it created: `folder_note`)."""
    from ..safe_write import make_folder

    missing = first_missing(folder)
    make_folder(folder)  # a file in the way: "FILE: is a file, not a folder (the output's folder is ...)"
    return missing


def first_missing(folder) -> str:
    """The topmost folder of `folder`'s path that does not exist yet, or '' (what `create_folder` would make)."""
    folder = Path(folder)
    missing = ""
    for f in (folder, *folder.parents):
        if f.exists():
            break
        missing = str(f)
    return missing


def folder_note(made: str) -> str:
    return f" (created folder {made}/)" if made else ""


def summary_line(s: RunStats) -> str:
    pc = s.per_class
    wall = f"{s.wall_s:.2f}" if s.wall_s >= 1 else f"{s.wall_s:.3g}"  # '0.01 s' and '1.2 M ev/s' disagreed
    return (f"{counted(s.events_in, 'event')} in {wall} s ({event_rate(s.throughput_hz)}): "
            f"signal {pc[0]:,}, background {pc[1]:,}, hot pixel {pc[2]:,}")


class StopOnSignal:
    """SIGINT/SIGTERM stop the stream after the chunk in progress, so sinks close their files properly;
    a second signal interrupts at once (sinks are still closed by `Pipeline.run`)."""

    def __init__(self):
        self.signum = None
        self._old = {}

    def __enter__(self):
        for s in (signal.SIGINT, signal.SIGTERM):
            self._old[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc):
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
