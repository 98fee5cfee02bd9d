"""`evstream ...` — the command line: a package of thin commands over the Python API, and the composition
root (with evstream.api, the only part of the core that imports sources and sinks).

Exit codes: 0 ok, 1 runtime failure (bad input, I/O), 2 usage error. Errors print as one line;
`--debug` shows the traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

# Before Rerun's Rust logger starts (at `import rerun`): the .rrd writer's own log lines about a failed
# write stay off; the command reports that failure itself, in one line naming the file (RUST_LOG, when
# set, wins).
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd=off,re_sdk::recording_stream=off")

from .. import _start, jit
from ..events import EventError
from . import archive, evaluate, files, frames, publish, replay, router, stages, subscribe, train
from .batch import flags_of
from .common import Progress, UsageError, event_rate
from .replay import LagMeter

__all__ = ["LagMeter", "Progress", "event_rate", "main", "parser", "task_flags"]

# the order `evstream --help` lists them in
COMMANDS = (files.add_info_parser, replay.add_parser, archive.add_parser, frames.add_parser,
            files.add_convert_parser, evaluate.add_synth_parser, evaluate.add_eval_parser, train.add_parser,
            train.add_calibrate_parser,
            publish.add_parser, subscribe.add_parser, router.add_parser, stages.add_parser)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="evstream", description="Streaming event-camera pipeline.")
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = ap.add_subparsers(dest="command", required=True)
    for add in COMMANDS:
        add(sub)
    return ap


def task_flags(command: str, *argv: str) -> dict:
    """A command's flags as a batch task's plain values, for evstream.batch.run_many:
    `task_flags("archive", "--keep-noise")` (what `evstream archive ... --keep-noise` would use)."""
    return flags_of(parser().parse_args([command, "SOURCE", "OUT", *argv]))


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning (a truncated file, dropped events) as one line for the user, not Python's
    `path.py:123: EventWarning: ...` plus a line of our source code."""
    print(f"evstream: warning: {message}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    ap = parser()  # imports the commands' modules: Ctrl-C is still start-up's one line (evstream/_start.py)
    args = ap.parse_args(argv)  # exits 2 on usage errors
    _start.release()  # loaded: Ctrl-C is KeyboardInterrupt again (or the command's own handler)
    with warnings.catch_warnings():  # restores the caller's warning display afterwards
        if not args.debug:
            warnings.showwarning = _show_warning
        with jit.quiet_notes(getattr(args, "quiet", False)):  # the note on stale compiled kernels (evstream/jit.py)
            return _run(args)


def _run(args) -> int:
    try:
        return args.func(args)
    except UsageError as e:
        print(f"evstream: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:  # a second Ctrl-C: at once (what a writer kept, it says)
        print(f"evstream: interrupted; {e}" if str(e) else "evstream: interrupted", file=sys.stderr)
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

