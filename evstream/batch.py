"""Many recordings, one job: plan one task per recording (the input tree mirrored under an output folder)
and run the tasks on a Dask `distributed` cluster — a local one (N worker processes, one thread each) or
an existing scheduler's.

A task carries only paths and plain parameters; the work function is named by reference (module and
name), so nothing of the user's data is pickled onto the wire beyond Dask's own task messages. Each task
writes whole-or-nothing (evstream.safe_write), which is what makes a task that Dask re-runs after a worker
died safe: a half-written output never sits at the target's name.

A re-run skips a task when its output was made from the recording as it is now with the same settings:
each finished task leaves a small JSON record beside its output (`.NAME.settings.json`: the work
function, its parameters, and the size and time of the recording and of the output when it was made).
One whose settings or recording changed is made again (`TaskResult.redone` says why). An output the
record does not describe (another command's, or changed since) is not replaced unless its recording
is newer; the result says so (`TaskResult.note`).
"""

from __future__ import annotations

import glob
import inspect
import json
import logging
import os
import signal
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["NOT_SETTINGS", "RECORDING_SUFFIXES", "STOP_WAIT_S", "Task", "TaskInterrupted", "TaskResult", "TaskStop",
           "check_main_guard", "out_name", "plan", "redo_reason", "run_many", "settings_file", "settings_of",
           "start_client"]

# What a folder walk takes as a recording (open_source reads by content; a walk needs a name filter).
RECORDING_SUFFIXES = (".npz", ".npy", ".h5", ".hdf5", ".aedat4", ".aedat", ".mat", ".mcap", ".dat", ".raw",
                      ".bin", ".bs2", ".txt", ".csv")
GLOB_MAGIC = set("*?[")


@dataclass(frozen=True)
class Task:
    source: str
    out: str


@dataclass
class TaskResult:
    source: str
    out: str
    status: str  # "done", "skipped" (up to date), "failed" or "interrupted" (stopped, or never started)
    seconds: float = 0.0
    events: int | None = None
    classes: dict | None = None  # noise class name -> events
    error: str | None = None
    summary: dict = field(default_factory=dict)  # what the one-file function returned
    warnings: list[str] = field(default_factory=list)  # what the reader warned of (a truncated file), one line each
    redone: str | None = None  # done over an earlier output: why (its settings changed, its recording changed, ...)
    changed: dict = field(default_factory=dict)  # the settings that changed: name -> [before, now]
    note: str | None = None  # skipped without a record of its settings: said (`redo_reason`)

    def as_dict(self) -> dict:
        return {"source": self.source, "out": self.out, "status": self.status, "seconds": self.seconds,
                "events": self.events, "classes": self.classes, "error": self.error, "warnings": self.warnings,
                "redone": self.redone, "changed": self.changed, "note": self.note}


def _is_recording(path: Path) -> bool:
    name = path.name
    return (path.suffix.lower() in RECORDING_SUFFIXES and not name.startswith(".")
            and not name.endswith(".part") and path.is_file())


def files_named(inputs: Iterable[str]) -> list[str]:
    """Every file that paths, folders (walked) and globs name: what a command may read, which no output
    of it may be."""
    found = []
    for given in inputs:
        for path in glob.glob(given, recursive=True) if GLOB_MAGIC & set(given) else [given]:
            found += [str(p) for p in Path(path).rglob("*") if p.is_file()] if Path(path).is_dir() else [path]
    return found


def plan(inputs: Iterable[str], out_dir, suffix: str) -> list[Task]:
    """One task per recording: a file goes to OUT/NAME, a folder's recordings (walked, sorted) to
    OUT/PATH-BELOW-THE-FOLDER, a glob's matches to OUT/PATH-BELOW-THE-GLOB'S-FIXED-PART; each with its
    suffix replaced by `suffix` (".mcap"; `out_name`: rec.aedat4 beside rec.npy keeps its extension). A
    walk or a glob passes over OUT (which may lie in the input tree): an earlier run's outputs are not
    recordings to process again (they would nest OUT/OUT/... one level deeper each run). Raises
    ValueError for an input that matches nothing, or when two recordings would write the same output."""
    out_dir = Path(out_dir)
    out_real = os.path.realpath(out_dir)

    def outside_out(p: Path) -> bool:
        real = os.path.realpath(p)
        return real != out_real and not real.startswith(out_real.rstrip(os.sep) + os.sep)

    tasks: list[Task] = []
    for text in inputs:
        given = Path(text)
        if GLOB_MAGIC & set(text):
            fixed = []
            for part in given.parts:
                if GLOB_MAGIC & set(part):
                    break
                fixed.append(part)
            base = Path(*fixed) if fixed else Path(".")
            found = sorted(Path(p) for p in glob.glob(text, recursive=True))
            found = [p for p in found if _is_recording(p)] + [
                q for p in found if p.is_dir() for q in sorted(p.rglob("*")) if _is_recording(q)]
            pairs = [(p, p.relative_to(base)) for p in found if outside_out(p)]
            if not pairs:
                raise ValueError(f"{text}: matches no recording" + (f" outside the output folder {out_dir}"
                                                                    if found else ""))
        elif given.is_dir():
            walked = [p for p in sorted(given.rglob("*")) if _is_recording(p)]
            pairs = [(p, p.relative_to(given)) for p in walked if outside_out(p)]
            if not pairs:
                where = f" outside the output folder {out_dir}" if walked else ""
                raise ValueError(f"{text}: a folder with no recording in it{where} ({', '.join(RECORDING_SUFFIXES)})")
        elif given.exists():
            pairs = [(given, Path(given.name))]
        else:
            raise ValueError(f"{text}: no such file or folder")
        tasks += [Task(str(src), str(out_dir / out_name(src, rel, suffix))) for src, rel in pairs]
    seen: dict[str, str] = {}
    for t in tasks:
        key = os.path.normpath(os.path.abspath(t.out))
        if key in seen and seen[key] != t.source:
            raise ValueError(f"{t.out}: both {seen[key]} and {t.source} would write it; run them separately")
        seen[key] = t.source
    unique = {os.path.normpath(os.path.abspath(t.out)): t for t in tasks}  # a recording named twice: once
    return list(unique.values())


def out_name(source: Path, rel: Path, suffix: str) -> Path:
    """A recording's output path below OUT: its path with its extension replaced by `suffix` (rec.aedat4 ->
    rec.mcap), except when its folder holds another recording of the same name with another extension
    (tonic-style datasets keep rec.aedat4 beside rec.npy): then each keeps its extension before `suffix`
    (rec.aedat4.mcap, rec.npy.mcap), so neither is refused and the names do not depend on which of them
    a command line named."""
    if _has_namesake(source):
        return rel.with_name(rel.name + suffix)
    return rel.with_suffix(suffix)


def _has_namesake(source: Path) -> bool:
    stem = source.stem.lower()
    try:
        names = os.listdir(source.parent if str(source.parent) else ".")
    except OSError:
        return False
    return any(name.lower() != source.name.lower() and Path(name).stem.lower() == stem
               and _is_recording(source.parent / name) for name in names)


# Parameters that say how a task runs, not what it writes: a change in them does not redo an output.
NOT_SETTINGS = frozenset({"quiet", "json", "command_line"})


def settings_of(work: Callable, params: dict, files: Iterable[str] = ()) -> dict:
    """What a task's output depends on besides its recording: the work function (by name), its parameters
    but NOT_SETTINGS, as JSON gives them back (tuples as lists), and the SHA-256 of `files` it reads
    (a pipeline TOML, a model: an edit to one changes the output under the same flags)."""
    chosen = {k: params[k] for k in sorted(params) if k not in NOT_SETTINGS}
    chosen.update({f"contents of {f}": _digest(f) for f in files if f})
    return json.loads(json.dumps({"work": f"{work.__module__}:{work.__qualname__}", **chosen}))


def _digest(path: str) -> str | None:
    import hashlib

    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:  # the task says what is wrong with it
        return None


def settings_file(out) -> Path:
    """The record of how `out` was made, beside it: `.NAME.settings.json` (hidden: not another output, and
    no walk takes it for a recording)."""
    out = Path(out)
    return out.with_name(f".{out.name}.settings.json")


def _stamp(path) -> list[int]:
    st = os.stat(path)
    return [st.st_size, st.st_mtime_ns]


UNRECORDED = ("no record of the settings it was made with (another command's output, or an older evstream's): "
              "left as it is; --force makes it again")


def redo_reason(task: Task, settings: dict) -> tuple[bool, str, dict]:
    """Whether the task must run, why, and the settings that changed (name -> [before, now]):
    - no output yet: (True, "", {});
    - an output with a record beside it that describes it (its size and time): made again when its
      recording changed or the `settings` differ from the record's, else up to date (False, "", {});
    - an output without such a record (made by another command, by hand, by an evstream from before the
      records, or changed since): not known to be evstream's to replace, so left as it is (False,
      UNRECORDED, {}) unless its recording is newer than it (True, why, {}), the rule before records.
    Every writer puts its output in place whole, so an output at the target's name is a finished one."""
    try:
        made = _stamp(task.out)
    except OSError:
        return True, "", {}
    try:
        source_now = _stamp(task.source)
    except OSError:
        source_now = None
    try:
        record = json.loads(settings_file(task.out).read_text())
        before, source_was, out_was = record["settings"], record["source_stamp"], record["out_stamp"]
        if not isinstance(before, dict) or out_was != made:
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError):
        if source_now is not None and source_now[1] > made[1]:
            return True, "its recording is newer than it (no record of its settings)", {}
        return False, UNRECORDED, {}
    if source_was != source_now:
        return True, "its recording changed", {}
    if before != settings:
        changed = {k: [before.get(k), settings.get(k)] for k in sorted(set(before) | set(settings))
                   if before.get(k) != settings.get(k)}
        return True, "settings changed: " + ", ".join(f"{k} {_shown(a)} -> {_shown(b)}"
                                                     for k, (a, b) in changed.items()), changed
    return False, "", {}


def _shown(v) -> str:
    return "none" if v is None else json.dumps(v) if isinstance(v, list | dict) else str(v)


def _write_record(source: str, out: str, settings: dict, source_stamp: list[int] | None, command_line) -> None:
    """After a task wrote `out`: how it was made, beside it (written whole). A run killed before this leaves
    no record, or the last one, whose output stamp then no longer matches: either way a re-run finds an
    output without a record and leaves it as it is (`redo_reason`: UNRECORDED) until `--force`."""
    from .safe_write import AtomicOutput

    record = {"source": source, "out": out, "settings": settings, "source_stamp": source_stamp,
              "out_stamp": _stamp(out), "command_line": command_line}
    with AtomicOutput(settings_file(out)) as part:
        Path(part).write_text(json.dumps(record, indent=1) + "\n")


def worker_env() -> dict[str, str]:
    """One thread per worker process: N workers use N cores, not N x cores. Numba's kernels on one thread,
    and a task's pipeline serial (EVSTREAM_THREADS=0: a one-file command otherwise reads and writes on
    threads beside its stages, using cores the other workers have)."""
    return {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "EVSTREAM_THREADS": "0", "EVSTREAM_BATCH_WORKER": "1"}


def start_client(jobs: int | None = None, scheduler: str | None = None):
    """A Dask client: on an existing scheduler (`tcp://HOST:8786`), or on a new local cluster of `jobs`
    worker processes (default: the cores this process may use), one thread each, its HTTP endpoint on a
    free loopback port (no clash with another cluster's 8787), its log silenced (a shutdown's heartbeat
    errors and warnings are not the user's business: run_many reports each task's failure). Returns
    (client, cluster or None); close both when done."""
    from distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler), None
    n = jobs or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)
    import dask

    # pre-spawn: in the worker process's environment from its start (a spawned worker imports numba before
    # the Nanny's `env` is applied, when the parent's __main__ is re-imported: the console script's is)
    pre_spawn = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **worker_env()}
    preload = [*dask.config.get("distributed.worker.preload", []), "evstream"]  # evstream/_start.py, at the latest
    with dask.config.set({"distributed.nanny.pre-spawn-environ": pre_spawn, "distributed.worker.preload": preload}), \
            _workers_start_with_sigint_blocked():
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                               env=worker_env(), host="127.0.0.1", silence_logs=logging.CRITICAL)
    return Client(cluster), cluster


class _workers_start_with_sigint_blocked:
    """While the cluster starts, each worker process is spawned with SIGINT blocked in the spawning thread
    (multiprocessing's spawn: `util.spawnv_passfds`), and a signal mask survives fork and exec: the
    worker's Python holds a terminal's Ctrl-C from its first instruction until evstream._start ignores
    SIGINT and unblocks it, instead of raising KeyboardInterrupt in its bootstrap, with Python's lines on
    the terminal. (Blocking it in this thread is not inherited far enough: distributed's event-loop
    thread runs with an empty mask.) Only the spawns of this start: a worker restarted later (after one
    died) starts as before."""

    def __enter__(self):
        from multiprocessing import util

        self.util, self.spawn = util, util.spawnv_passfds
        if not hasattr(signal, "pthread_sigmask"):
            return self

        def spawn_blocked(path, args, passfds):
            old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                return self.spawn(path, args, passfds)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, old)

        util.spawnv_passfds = spawn_blocked
        return self

    def __exit__(self, *exc):
        self.util.spawnv_passfds = self.spawn


STOP_WAIT_S = 10.0  # after a stop, how long the running tasks get to clean up before the cluster closes
STOP_GRACE_S = 3.0  # ... of which this long to end at their next chunk; then interrupted where they are

# On each worker: the runs told to stop (run id -> signal number) and the tasks running per run, under one
# lock: a task either starts before the stop (and is waited for) or sees it and does nothing.
_lock = threading.Lock()
_stopped: dict[str, int] = {}
_running: dict[str, dict[str, int]] = {}  # run id -> task key -> the thread running it


class TaskInterrupted(KeyboardInterrupt):
    """Raised inside a task told to stop: its writers clean up as after a Ctrl-C in the one-file command
    (a temporary removed, an archive so far set aside)."""


class TaskStop:
    """A task's view of its run's stop, for the one-file functions: `.signum` (the signal that stopped
    the run, else None), like the CLI's StopOnSignal; calling it says whether to stop."""

    def __init__(self, run: str):
        self.run = run

    @property
    def signum(self) -> int | None:
        return _stopped.get(self.run)

    def __call__(self) -> bool:
        return self.run in _stopped

    def check(self) -> None:
        """Raise TaskInterrupted once the run is stopped."""
        if self.run in _stopped:
            raise TaskInterrupted(f"stopped by {signal.Signals(_stopped[self.run]).name}")


def _stop_run(run: str, signum: int) -> list[str]:
    """On a worker (client.run): the run stopped; returns the keys of its tasks running now."""
    with _lock:
        _stopped[run] = signum
        return sorted(_running.get(run, ()))


def _interrupt_run(run: str) -> int:
    """On a worker (client.run): TaskInterrupted raised in each of the run's tasks still running, at its
    thread's next Python instruction (what a second Ctrl-C does to a one-file command: a writer busy
    closing, a long chunk, stopped where it is; its clean-up runs). Under the lock, so only in a thread
    still inside its task (_run_task catches one that lands late). Returns how many."""
    import ctypes

    with _lock:
        threads = list(_running.get(run, {}).values())
        for ident in threads:
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident), ctypes.py_object(TaskInterrupted))
        return len(threads)


def _takes_stop(work: Callable) -> bool:
    try:
        return "stop" in inspect.signature(work).parameters
    except (TypeError, ValueError):
        return False


def _interrupted(error: str, seconds: float = 0.0, started: bool = True, warnings_: list | None = None) -> dict:
    """What a task stopped by its run's stop (or never started) comes back as."""
    return {"ok": False, "interrupted": True, "started": started, "error": error, "seconds": seconds,
            "warnings": warnings_ or []}


def _run_task(work: Callable, source: str, out: str, params: dict, run: str | None = None, key: str = "",
              settings: dict | None = None) -> dict:
    """On a worker: the one-file function, timed; its error as one line (the job goes on). With `run`: a
    run stopped before the task started skips it; `work` taking `stop` gets a TaskStop to poll. With
    `settings`: once the output is whole, the record of how it was made beside it (`redo_reason`)."""
    t0 = time.perf_counter()
    try:
        if run is not None:
            with _lock:
                if run in _stopped:
                    return _interrupted("not started", started=False)
                _running.setdefault(run, {})[key] = threading.get_ident()
        try:
            return _call(work, source, out, params, run, t0, settings)
        finally:
            if run is not None:
                with _lock:
                    _running.get(run, {}).pop(key, None)
    except KeyboardInterrupt:  # _interrupt_run's exception, landed after the task's own handler
        return _interrupted("interrupted", time.perf_counter() - t0)


def _call(work: Callable, source: str, out: str, params: dict, run: str | None, t0: float,
          settings: dict | None = None) -> dict:
    extra = {"stop": TaskStop(run)} if run is not None and _takes_stop(work) else {}
    try:  # before reading: a recording changed while it is read is made again by the next run
        source_stamp = _stamp(source)
    except OSError:  # the work function says what is wrong with it
        source_stamp = None
    with warnings.catch_warnings(record=True) as caught:  # a reader's warning (a truncated file) goes back
        try:  # with the result: a worker's stderr is not the user's (another machine's, with --scheduler)
            summary = work(source, out, **params, **extra)
        except KeyboardInterrupt as e:  # TaskInterrupted: its writers cleaned up, as after a Ctrl-C
            return _interrupted(str(e) or "interrupted", time.perf_counter() - t0,
                                warnings_=[str(w.message) for w in caught])
        except Exception as e:  # one recording's failure is reported, not the job's
            return {"ok": False, "error": f"{type(e).__name__}: {e}" if not str(e) else str(e),
                    "seconds": time.perf_counter() - t0, "warnings": [str(w.message) for w in caught]}
    stopped = run is not None and run in _stopped and isinstance(summary, dict) and summary.get("partial")
    said = [str(w.message) for w in caught]
    if settings is not None and not stopped:
        try:
            _write_record(source, out, settings, source_stamp, params.get("command_line"))
        except (OSError, ValueError) as e:  # the output is whole; without its record a re-run leaves it as it is
            said.append(f"{out}: no record of its settings written ({e}); a re-run leaves it as it is, "
                        "--force makes it again")
    return {"ok": True, "summary": summary, "seconds": time.perf_counter() - t0, "interrupted": bool(stopped),
            "warnings": said}


def run_many(tasks: list[Task], work: Callable, params: dict | None = None, *, client=None, jobs: int | None = None,
             scheduler: str | None = None, force: bool = False, retries: int = 2,
             on_result: Callable[[TaskResult, int, int], None] | None = None,
             warm: Callable[[], None] | None = None, stop: Callable[[], object] | None = None,
             reads: Iterable[str] = ()) -> list[TaskResult]:
    """Run `work(source, out, **params)` for every task (skipping up-to-date outputs unless `force`:
    `redo_reason`) on a Dask cluster; returns one TaskResult per task, in the tasks' order. `work` must be
    importable on the workers (a module-level function) and return a dict (with `events_in` and
    `events_signal`, ... when it has them). `warm()` runs once here before anything is submitted (numba's
    on-disk cache, compiled once instead of once per worker), then on every worker (its imports and cached
    kernels loaded, so a recording's seconds are its own; `warm` must then be picklable by reference, e.g. a partial).
    `retries`: Dask's re-runs of a task whose worker died or that raised.
    `on_result(result, done, total)` is called as each finishes (progress). `reads`: files every task reads
    besides its recording (a pipeline TOML, a model), whose contents count as settings (`redo_reason`).

    Stopping: `stop()` is polled (true, or a signal number, ends the run; a KeyboardInterrupt here does
    too, and is raised again after). The tasks not started are dropped; the running ones are told (a
    `work` taking `stop=` gets a TaskStop: the one-file commands end as after a Ctrl-C, their temporaries
    removed or an archive so far set aside); those still running after STOP_GRACE_S get TaskInterrupted
    raised where they are (a second Ctrl-C's effect; their clean-up runs), and all are waited for up to
    STOP_WAIT_S; they come back "interrupted". A second KeyboardInterrupt here closes the cluster at once."""
    if client is None and not scheduler:
        check_main_guard()  # before anything starts: the local cluster's workers would run the script again
    params = params or {}
    settings = settings_of(work, params, reads)
    results: dict[Task, TaskResult] = {}
    todo, why = [], {}
    for t in tasks:
        redo, reason, changed = redo_reason(t, settings)
        if not redo and not force:
            results[t] = TaskResult(t.source, t.out, "skipped", note=reason or None)
        else:
            todo.append(t)
            why[t] = ("--force" if force and os.path.exists(t.out) else reason or None), changed
    total, done = len(tasks), len(results)
    if on_result:
        for r in results.values():
            on_result(r, done, total)

    def stopping():
        return stop is not None and stop()

    count = [done]

    def report(t: Task, r: TaskResult) -> None:
        if r.status == "done":
            r.redone, r.changed = why[t]
        count[0] += 1
        if on_result:
            on_result(r, count[0], total)

    if todo and not stopping():
        results.update(_submit_and_wait(todo, work, params, client, jobs, scheduler, retries, warm, stop, stopping,
                                        report, settings))
    for t in tasks:  # stopped before they were submitted
        results.setdefault(t, TaskResult(t.source, t.out, "interrupted", error="not started"))
    return [results[t] for t in tasks]


def check_main_guard() -> None:
    """Stop the script with one line naming it and its line (SystemExit: exit 1, no traceback) when called
    while a script's top level runs outside `if __name__ == "__main__":`. A local cluster's workers are new
    Python processes (multiprocessing's spawn) that import the script before they work: one that starts the
    job at its top level would start it again in every worker (Dask's ~300 lines of 'Nanny failed to start'
    followed). A notebook, `python -c`, a guarded script and the fork start method are left alone."""
    import ast
    import sys

    import dask

    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None or dask.config.get("distributed.worker.multiprocessing-method", "spawn") == "fork":
        return
    frame = sys._getframe(1)
    while frame is not None and not (frame.f_globals is vars(main) and frame.f_code.co_name == "<module>"):
        frame = frame.f_back
    if frame is None:  # not from the script's top level (a function called after it ran, another thread)
        return
    try:
        tree = ast.parse(Path(path).read_bytes(), path)
    except (OSError, SyntaxError, ValueError):
        return
    if not _under_main_guard(tree.body, frame.f_lineno):
        raise SystemExit(f"{path}, line {frame.f_lineno}: run_many is called at the script's top level, and each "
                         "worker process imports the script, so each would start the job again; put the job "
                         "under `if __name__ == \"__main__\":` (docs/scale.md)")


def _under_main_guard(body: list, line: int) -> bool:
    """Whether `line` lies in the body of an `if __name__ == "__main__":` among the statements `body`."""
    import ast

    for stmt in body:
        if not stmt.lineno <= line <= (stmt.end_lineno or stmt.lineno):
            continue
        if isinstance(stmt, ast.If) and _is_main_test(stmt.test) and stmt.body[0].lineno <= line <= (
                stmt.body[-1].end_lineno or line):
            return True
        inner = [getattr(stmt, name, []) for name in ("body", "orelse", "finalbody")]
        inner += [h.body for h in getattr(stmt, "handlers", [])] + [c.body for c in getattr(stmt, "cases", [])]
        return any(isinstance(b, list) and _under_main_guard(b, line) for b in inner)
    return False


def _is_main_test(test) -> bool:
    import ast

    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = [test.left, test.comparators[0]]
    return (any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides)
            and any(isinstance(s, ast.Constant) and s.value == "__main__" for s in sides))


def _submit_and_wait(todo, work, params, client, jobs, scheduler, retries, warm, stop, stopping, report,
                     settings) -> dict:
    """run_many's cluster part: start (unless given), warm, submit, collect; a stop at any moment (during
    the start too: a worker killed by the terminal's Ctrl-C while it spawned only says that the run
    stopped) drops the unstarted tasks and waits for the running ones (_stop)."""
    from distributed import as_completed

    results: dict[Task, TaskResult] = {}

    def take(t: Task, got: dict) -> None:
        results[t] = _result(t, got)
        report(t, results[t])

    own, cluster, futures, run, interrupt = client is None, None, {}, uuid.uuid4().hex, None
    try:
        try:
            if warm is not None:
                warm()
            if own and not stopping():
                client, cluster = start_client(jobs, scheduler)
            if warm is not None and client is not None and not stopping():
                client.run(warm)  # each worker's imports and cached kernels loaded before its first recording
            if client is not None and not stopping():
                keys = [f"evstream-{i}-{os.path.basename(t.source)}-{run[:8]}" for i, t in enumerate(todo)]
                futures = {client.submit(_run_task, work, t.source, t.out, params, run, key, settings,
                                         retries=retries, pure=False, key=key): t for t, key in zip(todo, keys)}
            pending = as_completed(futures)
            while not pending.is_empty() and not stopping():
                for future in pending.next_batch(block=False):
                    take(futures[future], _got(future))
                time.sleep(0.05)
        except KeyboardInterrupt as e:  # from Python: stop as asked, then say so
            interrupt = e
        except Exception:
            if not stopping():
                raise  # else what the stop broke (a worker that died of the Ctrl-C while it started)
        if (interrupt is not None or stopping()) and client is not None and futures:
            signum = stop() if stop is not None else None
            signum = signum if isinstance(signum, int) and not isinstance(signum, bool) else signal.SIGINT
            for t, got in _stop(client, futures, run, int(signum), set(results)).items():
                take(t, got)
    finally:
        if own and client is not None:
            _close_quietly(client, cluster)
    if interrupt is not None:
        raise interrupt
    return results


def _got(future) -> dict:
    try:
        return future.result()
    except Exception as e:  # the task's worker kept dying (Dask gave up), or it was lost
        return {"ok": False, "error": f"{type(e).__name__}: {e}", "seconds": 0.0}


def _stop(client, futures: dict, run: str, signum: int, finished: set) -> dict:
    """Tell the workers the run stopped, drop the tasks not started, wait up to STOP_WAIT_S for the
    running ones (their clean-up); returns what each unfinished task came to."""
    from distributed import wait

    running = set()
    for keys in client.run(_stop_run, run, signum, on_error="ignore").values():
        running.update(keys if isinstance(keys, list) else ())
    left = {f: t for f, t in futures.items() if t not in finished}
    waiting = [f for f in left if f.key in running]
    client.cancel([f for f in left if f.key not in running])
    for timeout, then in ((STOP_GRACE_S, _interrupt_run), (STOP_WAIT_S - STOP_GRACE_S, None)):
        try:
            wait(waiting, timeout=timeout)
            break
        except TimeoutError:
            if then is not None:
                client.run(then, run, on_error="ignore")
    got = {}
    for f, t in left.items():
        if f.done() and f.status == "finished":
            got[t] = _got(f)
        elif f.key in running:
            got[t] = _interrupted(f"still running {STOP_WAIT_S:g} s after the stop: ended with the cluster (a "
                                  "temporary NAME.part beside its output may be left)")
        else:
            got[t] = _interrupted("not started", started=False)
    return got


def _close_quietly(client, cluster) -> None:
    """Close the client and the cluster it started with distributed's logging off: a worker's heartbeat
    to a scheduler already gone, or a comm closed mid-message, is no news to the user."""
    names = ("distributed", "tornado", "asyncio")
    levels = {name: logging.getLogger(name).level for name in names}
    for name in names:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    try:
        client.close()
        if cluster is not None:
            cluster.close()
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def _result(t: Task, got: dict) -> TaskResult:
    said = list(got.get("warnings", ()))
    if got.get("interrupted") and not got["ok"]:
        return TaskResult(t.source, t.out, "interrupted", seconds=got["seconds"], error=got["error"], warnings=said)
    if not got["ok"]:
        return TaskResult(t.source, t.out, "failed", seconds=got["seconds"], error=got["error"], warnings=said)
    s = got["summary"] or {}
    classes = {name: int(s[f"events_{name}"]) for name in ("signal", "background", "hot_pixel")
               if f"events_{name}" in s} or None
    events = s.get("events_in", s.get("events"))
    return TaskResult(t.source, t.out, "interrupted" if got.get("interrupted") else "done", seconds=got["seconds"],
                      events=events, classes=classes, summary=s, warnings=said,
                      error=f"stopped; the archive so far is {s.get('mcap')}" if got.get("interrupted") else None)
