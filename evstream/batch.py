"""Many recordings, one job: plan one task per recording (the input tree mirrored under an output folder)
and run the tasks on a Dask `distributed` cluster — a local one (N worker processes, one thread each) or
an existing scheduler's.

A task carries only paths and plain parameters; the work function is named by reference (module and
name), so nothing of the user's data is pickled onto the wire beyond Dask's own task messages. Each task
writes whole-or-nothing (evstream.safe_write), which is what makes a re-run skip what is done and a task
that Dask re-runs after a worker died safe: a half-written output never sits at the target's name.
"""

from __future__ import annotations

import glob
import logging
import os
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["RECORDING_SUFFIXES", "Task", "TaskResult", "out_name", "plan", "run_many", "start_client", "up_to_date"]

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
    status: str  # "done", "skipped" (up to date) or "failed"
    seconds: float = 0.0
    events: int | None = None
    classes: dict | None = None  # noise class name -> events
    error: str | None = None
    summary: dict = field(default_factory=dict)  # what the one-file function returned
    warnings: list[str] = field(default_factory=list)  # what the reader warned of (a truncated file), one line each

    def as_dict(self) -> dict:
        return {"source": self.source, "out": self.out, "status": self.status, "seconds": self.seconds,
                "events": self.events, "classes": self.classes, "error": self.error, "warnings": self.warnings}


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


def up_to_date(task: Task) -> bool:
    """Whether the task's output is complete and newer than its input. Complete because every writer puts
    it in place whole (a temporary renamed when done): an output at the target's name is a finished one."""
    try:
        return os.stat(task.out).st_mtime_ns >= os.stat(task.source).st_mtime_ns
    except OSError:
        return False


def worker_env() -> dict[str, str]:
    """One thread per worker process: N workers use N cores, not N x cores. Numba's kernels on one thread,
    and a task's pipeline serial (EVSTREAM_THREADS=0: a one-file command otherwise reads and writes on
    threads beside its stages, using cores the other workers have)."""
    return {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "EVSTREAM_THREADS": "0"}


def start_client(jobs: int | None = None, scheduler: str | None = None):
    """A Dask client: on an existing scheduler (`tcp://HOST:8786`), or on a new local cluster of `jobs`
    worker processes (default: the cores this process may use), one thread each, its HTTP endpoint on a
    free loopback port (no clash with another cluster's 8787), its log at errors only (a slow shutdown's
    warnings are not the user's business; a task's failure is reported by run_many). Returns
    (client, cluster or None); close both when done."""
    from distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler), None
    n = jobs or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)
    import dask

    # pre-spawn: in the worker process's environment from its start (a spawned worker imports numba before
    # the Nanny's `env` is applied, when the parent's __main__ is re-imported: the console script's is)
    pre_spawn = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **worker_env()}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": pre_spawn}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                               env=worker_env(), host="127.0.0.1", silence_logs=logging.ERROR)
    return Client(cluster), cluster


def _run_task(work: Callable, source: str, out: str, params: dict) -> dict:
    """On a worker: the one-file function, timed; its error as one line (the job goes on)."""
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:  # a reader's warning (a truncated file) goes back
        try:  # with the result: a worker's stderr is not the user's (another machine's, with --scheduler)
            summary = work(source, out, **params)
        except Exception as e:  # one recording's failure is reported, not the job's
            return {"ok": False, "error": f"{type(e).__name__}: {e}" if not str(e) else str(e),
                    "seconds": time.perf_counter() - t0, "warnings": [str(w.message) for w in caught]}
    return {"ok": True, "summary": summary, "seconds": time.perf_counter() - t0,
            "warnings": [str(w.message) for w in caught]}


def run_many(tasks: list[Task], work: Callable, params: dict | None = None, *, client=None, jobs: int | None = None,
             scheduler: str | None = None, force: bool = False, retries: int = 2,
             on_result: Callable[[TaskResult, int, int], None] | None = None,
             warm: Callable[[], None] | None = None) -> list[TaskResult]:
    """Run `work(source, out, **params)` for every task (skipping up-to-date outputs unless `force`) on a
    Dask cluster; returns one TaskResult per task, in the tasks' order. `work` must be importable on the
    workers (a module-level function) and return a dict (with `events_in` and `events_signal`, ... when it
    has them). `warm()` runs once here before anything is submitted (numba's on-disk cache, compiled once
    instead of once per worker), then on every worker (its imports and cached kernels loaded, so a
    recording's seconds are its own; `warm` must then be picklable by reference, e.g. a partial).
    `retries`: Dask's re-runs of a task whose worker died or that raised.
    `on_result(result, done, total)` is called as each finishes (progress)."""
    from distributed import as_completed

    params = params or {}
    results: dict[Task, TaskResult] = {}
    todo = []
    for t in tasks:
        if not force and up_to_date(t):
            results[t] = TaskResult(t.source, t.out, "skipped")
        else:
            todo.append(t)
    total, done = len(tasks), len(results)
    if on_result:
        for r in results.values():
            on_result(r, done, total)
    if todo:
        if warm is not None:
            warm()
        own = client is None
        cluster = None
        if own:
            client, cluster = start_client(jobs, scheduler)
        try:
            if warm is not None:  # each worker's imports and cached kernels loaded before its first recording
                client.run(warm)
            futures = {client.submit(_run_task, work, t.source, t.out, params, retries=retries, pure=False,
                                     key=f"evstream-{i}-{os.path.basename(t.source)}"): t
                       for i, t in enumerate(todo)}
            for future in as_completed(futures):
                t = futures[future]
                try:
                    got = future.result()
                except Exception as e:  # the task's worker kept dying (Dask gave up), or it was lost
                    got = {"ok": False, "error": f"{type(e).__name__}: {e}", "seconds": 0.0}
                results[t] = _result(t, got)
                done += 1
                if on_result:
                    on_result(results[t], done, total)
        finally:
            if own:
                client.close()
                if cluster is not None:
                    cluster.close()
    return [results[t] for t in tasks]


def _result(t: Task, got: dict) -> TaskResult:
    said = list(got.get("warnings", ()))
    if not got["ok"]:
        return TaskResult(t.source, t.out, "failed", seconds=got["seconds"], error=got["error"], warnings=said)
    s = got["summary"] or {}
    classes = {name: int(s[f"events_{name}"]) for name in ("signal", "background", "hot_pixel")
               if f"events_{name}" in s} or None
    events = s.get("events_in", s.get("events"))
    return TaskResult(t.source, t.out, "done", seconds=got["seconds"], events=events, classes=classes, summary=s,
                      warnings=said)
