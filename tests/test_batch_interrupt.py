"""Ctrl-C in a many-recording run on a real local Dask cluster (evstream.batch): the `evstream` command in
a process group of its own, sent a real SIGINT at several moments: while it loads and while tasks write
the way a terminal sends it (to the whole group, workers too), while the cluster's workers spawn to the
command alone (`kill -INT`). Each time:
exit 130, no traceback or Dask log on stderr, no temporary left, an older output untouched. And from
Python: run_many's `stop`, and a task that never polls it (interrupted where it is)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from evstream.sources import native

import evstream
from evstream import batch, synth
from evstream.cli import task_flags
from evstream.cli.files import convert_file
from evstream.safe_write import AtomicOutput

pytest.importorskip("distributed")

EVSTREAM = Path(sys.executable).parent / "evstream"  # the console script, as a user runs it
COMMANDS = {
    "convert": lambda src, out: ["convert", str(src), str(out)],
    "frames": lambda src, out: ["frames", str(src), "--out", str(out)],
    "archive": lambda src, out: ["archive", str(src), str(out), "--keep-noise"],
}
TARGET = {"convert": "a.npz", "frames": "a.frames.json", "archive": "a.mcap"}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Two recordings long enough that a task is still writing when the signal comes (seconds each)."""
    root = tmp_path_factory.mktemp("many")
    for name, seed in (("a", 1), ("b", 2)):
        native.save(root / f"{name}.npz", synth.scene("turntable", duration_us=8_000_000, seed=seed))
    return root


def children_spawning(proc: subprocess.Popen) -> bool:
    try:
        return any("spawn_main" in " ".join(c.cmdline()) for c in psutil.Process(proc.pid).children())
    except psutil.Error:
        return False


def temporaries(out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.name.endswith(".part")) if out.exists() else []


def wait_for(condition, proc, timeout_s=300.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and proc.poll() is None:
        if condition():
            return True
        time.sleep(0.02)
    return False


def run_and_interrupt(argv, moment, out: Path):
    env = {**os.environ, "EVSTREAM_THREADS": "0"}
    proc = subprocess.Popen([str(EVSTREAM), *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, start_new_session=True)
    try:
        if moment == "loading":  # numpy's C module mapped: the package's imports are under way
            reached = wait_for(lambda: "_multiarray_umath" in Path(f"/proc/{proc.pid}/maps").read_text(), proc)
        elif moment == "spawning":
            reached = wait_for(lambda: children_spawning(proc), proc)
        else:  # a task's temporary is there: it is writing
            reached = wait_for(lambda: bool(temporaries(out)), proc)
        assert reached, f"the run ended before the moment '{moment}'"
        if moment == "spawning":  # `kill -INT PID` (ignored in 3 of 3 runs before): a worker's Python, just
            os.kill(proc.pid, signal.SIGINT)  # exec'd, would print its own KeyboardInterrupt (docs/scale.md)
        else:
            os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole foreground group
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, stdout, stderr


@pytest.mark.parametrize("moment", ["loading", "spawning", "writing"])
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_ctrl_c_at_any_moment_stops_the_run_and_leaves_no_temporary(folder, tmp_path, command, moment):
    out = tmp_path / "out"
    out.mkdir()
    older = out / TARGET[command]
    older.write_text("an older output")  # --force: redone, so at risk
    argv = COMMANDS[command](folder, out) + ["--jobs", "2", "--force"]
    rc, stdout, stderr = run_and_interrupt(argv, moment, out)
    assert rc == 130, (stdout, stderr)
    assert "Traceback" not in stderr and "distributed." not in stderr and "Error" not in stderr, stderr
    assert stderr.strip().splitlines()[-1].startswith("evstream: interrupted"), stderr
    assert temporaries(out) == [], stderr  # no OUT/a.npz.part, no OUT/a.part/ of frames
    assert older.read_text() == "an older output"
    if command == "frames":
        assert not (out / "a").exists() or not any((out / "a").iterdir())
    if command == "archive":  # the archive so far set aside, as the one-file command does, and said
        for kept in out.glob("*.partial*.mcap"):
            assert str(kept) in stderr
            assert evstream.info(kept)["events"] >= 0  # a whole MCAP file: summary and footer
    if moment == "writing":
        assert "interrupted by SIGINT" in stderr and "not finished" in stderr, stderr


def test_a_terminals_ctrl_c_while_the_workers_python_starts_prints_nothing_of_theirs(folder, tmp_path):
    """The gap docs/scale.md named: a terminal's Ctrl-C (the whole group) just after a worker's Python was
    exec'd, before it imports evstream, raised KeyboardInterrupt in its bootstrap, and the worker printed
    Python's traceback. The workers now start with SIGINT blocked (the threads that spawn them block it),
    and ignore it before unblocking it: the command stops as at any other moment, with its one line."""
    for attempt, delay_s in enumerate((0.05, 0.15, 0.3)):  # each printed a worker's traceback in 2 of 2 runs
        out = tmp_path / f"out{attempt}"
        argv = COMMANDS["convert"](folder, out) + ["--jobs", "2", "--force"]
        env = {**os.environ, "EVSTREAM_THREADS": "0"}
        proc = subprocess.Popen([str(EVSTREAM), *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=env, start_new_session=True)
        try:
            assert wait_for(lambda p=proc: children_spawning(p), proc), "the run ended before its workers spawned"
            time.sleep(delay_s)  # into the worker's Python start-up (site, the spawn's imports): 0.1-1 s here
            os.killpg(proc.pid, signal.SIGINT)
            stdout, stderr = proc.communicate(timeout=300)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        assert proc.returncode == 130, (stdout, stderr)
        assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
        assert stderr.strip().splitlines()[-1].startswith("evstream: interrupted"), stderr
        assert temporaries(out) == []


def busy_writer(source: str, out: str) -> dict:
    """A work function that never polls a stop: writes its temporary, then loops in Python."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with AtomicOutput(Path(out), [source]) as part:
        Path(part).write_text("partial")
        end = time.monotonic() + 120
        while time.monotonic() < end:
            sum(range(1000))
    return {}


@pytest.fixture(scope="module")
def client():
    c, cluster = batch.start_client(jobs=2)
    yield c
    c.close()
    cluster.close()


@pytest.mark.parametrize("work", [convert_file, busy_writer], ids=["polls-stop", "never-polls"])
def test_run_many_stop_ends_running_tasks_whole_or_not_at_all(client, folder, tmp_path, work):
    out = tmp_path / "out"
    tasks = batch.plan([str(folder)], out, ".npz")
    stopped = []

    def stop():  # once a task writes (its temporary is there)
        if not stopped and temporaries(out):
            stopped.append(time.monotonic())
        return bool(stopped)

    results = batch.run_many(tasks, work, {} if work is busy_writer else task_flags("convert"), client=client,
                             force=True, stop=stop)
    assert stopped, [r.error for r in results]
    assert [r.status for r in results] == ["interrupted", "interrupted"], [r.error for r in results]
    assert temporaries(out) == []
    assert not list(out.glob("*.npz"))  # nothing took the targets' names
    # the cluster is still usable: nothing of the stopped run is left on its workers
    assert client.run(lambda: len(batch._running)) is not None
