"""Many recordings on a real Dask cluster (evstream.batch, `evstream archive FOLDER/ OUT/`): a
`distributed.LocalCluster` of two worker processes archives a folder (the shipped recordings and
synthetic ones made with the API), compared event for event with the one-file command; a worker killed
mid-job; a re-run that skips what is done; a bad recording reported while the others go on."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from evstream.sources import native, open_source

from evstream import batch, synth
from evstream.cli import main, task_flags
from evstream.cli.archive import archive_file
from evstream.events import concat

distributed = pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]
# The one-file command's flags, also the batch's: every class kept (compared too), a fifth of a second of
# each recording (quick on a loaded machine).
FLAGS = ["--keep-noise", "--end-us", "200000", "--quiet"]


@pytest.fixture(scope="module")
def client():
    c, cluster = batch.start_client(jobs=2)  # a distributed.LocalCluster of 2 worker processes, 1 thread each
    assert isinstance(cluster, distributed.LocalCluster) and len(cluster.workers) == 2
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """recordings/*.npz, and synthetic ones (made with the API) one folder down."""
    root = tmp_path_factory.mktemp("dataset")
    for rec in sorted((ROOT / "recordings").glob("*.npz")):
        shutil.copy(rec, root / rec.name)
    (root / "synthetic").mkdir()
    for seed, scene in enumerate(("bar", "ball", "turntable")):
        native.save(root / "synthetic" / f"{scene}.npz", synth.scene(scene, duration_us=150_000, seed=seed))
    return root


def events_of(path) -> dict:
    chunk = concat(list(open_source(path)))
    return {k: getattr(chunk, k) for k in ("t", "x", "y", "p", "cls", "label") if getattr(chunk, k) is not None}


def assert_same_events(a, b):
    ea, eb = events_of(a), events_of(b)
    assert ea.keys() == eb.keys()
    assert len(ea["t"]) > 0
    for k in ea:
        np.testing.assert_array_equal(ea[k], eb[k], err_msg=f"{a} vs {b}: {k}")


def params(**extra) -> dict:
    return {**task_flags("archive", *FLAGS), **extra}


def _numba_threads():
    import numba

    return numba.config.NUMBA_NUM_THREADS


def _pipeline_threads():
    return os.environ.get("EVSTREAM_THREADS")


def test_workers_run_numba_on_one_thread(client):
    """One thread per worker: numba's, and the task's pipeline serial (no reader/writer threads)."""
    assert set(client.run(_numba_threads).values()) == {1}
    assert set(client.run(_pipeline_threads).values()) == {"0"}
    assert all(w["nthreads"] == 1 for w in client.scheduler_info()["workers"].values())


def test_plan_mirrors_the_tree_and_refuses_collisions(dataset, tmp_path):
    tasks = batch.plan([str(dataset)], tmp_path / "out", ".mcap")
    got = sorted(os.path.relpath(t.out, tmp_path / "out") for t in tasks)
    assert got == ["ball.mcap", "bar.mcap", "synthetic/ball.mcap", "synthetic/bar.mcap", "synthetic/turntable.mcap",
                   "turntable.mcap"]
    globbed = batch.plan([str(dataset / "synthetic" / "b*.npz")], tmp_path / "out", ".mcap")
    assert [Path(t.out).name for t in globbed] == ["ball.mcap", "bar.mcap"]
    with pytest.raises(ValueError, match="would write it"):
        batch.plan([str(dataset / "bar.npz"), str(dataset / "synthetic" / "bar.npz")], tmp_path / "o", ".mcap")
    with pytest.raises(ValueError, match="matches no recording"):
        batch.plan([str(dataset / "*.nothing")], tmp_path / "o", ".mcap")


def test_cluster_archives_a_folder_as_the_one_file_command(client, dataset, tmp_path):
    out = tmp_path / "out"
    tasks = batch.plan([str(dataset)], out, ".mcap")
    results = batch.run_many(tasks, archive_file, params(), client=client)
    assert [r.status for r in results] == ["done"] * len(tasks), [r.error for r in results]
    for task, r in zip(tasks, results):
        one = tmp_path / "one" / (Path(task.out).name)
        assert main(["archive", task.source, str(one), *FLAGS]) == 0
        assert_same_events(task.out, one)
        assert r.events == len(events_of(one)["t"])
        assert sum(r.classes.values()) == r.events
    assert not list(out.rglob("*.part"))


def test_a_worker_killed_mid_job_loses_and_duplicates_nothing(client, dataset, tmp_path):
    out = tmp_path / "out"
    tasks = batch.plan([str(dataset)], out, ".mcap")
    killed = []

    def kill_a_busy_worker(result, done, total):
        if killed:
            return
        for _ in range(200):  # a worker with a task in hand (the other one may be between tasks)
            busy = [w for w, keys in client.processing().items() if keys]
            if busy:
                pid = client.run(os.getpid, workers=[busy[0]])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.01)

    results = batch.run_many(tasks, archive_file, params(speed=0.5), client=client, on_result=kill_a_busy_worker)
    assert killed, "no worker was busy after the first task finished"
    assert [r.status for r in results] == ["done"] * len(tasks), [r.error for r in results]
    written = sorted(p for p in out.rglob("*.mcap"))
    assert written == sorted(Path(t.out) for t in tasks)  # each once, under its own name
    reference = tmp_path / "reference"
    for task in tasks:
        one = reference / Path(task.out).relative_to(out)
        assert main(["archive", task.source, str(one), *FLAGS]) == 0
        assert_same_events(task.out, one)
    # what the killed task had written stays beside its target as a .part, never at the target's name
    assert all(p.name.endswith(".part") for p in out.rglob("*") if p.is_file() and p.suffix != ".mcap"
               and not p.name.endswith(".settings.json"))
    client.wait_for_workers(2, timeout=60)  # the nanny restarts the worker


def test_rerun_skips_what_is_done_and_reports_a_bad_recording(client, dataset, tmp_path, capsys):
    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    (data / "broken.npz").write_bytes(b"PK\x03\x04 not a zip at all")
    out = tmp_path / "out"
    address = client.scheduler.address
    argv = ["archive", str(data), str(out), "--scheduler", address, *FLAGS, "--json"]
    assert main(argv) == 1  # the broken one failed, the others are done
    first = capsys.readouterr()
    assert "broken.npz" in first.err and "Traceback" not in first.err
    import json

    report = json.loads(first.out)
    assert (report["done"], report["skipped"], report["failed"]) == (6, 0, 1)
    assert not (out / "broken.mcap").exists()
    mtimes = {p: p.stat().st_mtime_ns for p in out.rglob("*.mcap")}
    os.utime(data / "bar.npz")  # newer than its archive: redone
    (data / "broken.npz").unlink()
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    status = {Path(r["source"]).relative_to(data).as_posix(): r["status"] for r in report["recordings"]}
    assert status.pop("bar.npz") == "done"
    assert set(status.values()) == {"skipped"}
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.mcap") if p.name != "bar.mcap"} == {
        p: t for p, t in mtimes.items() if p.name != "bar.mcap"}
    assert main([*argv, "--force"]) == 0
    assert json.loads(capsys.readouterr().out)["done"] == 6


def test_a_rerun_with_other_settings_makes_again_what_they_change(client, dataset, tmp_path, capsys):
    """A re-run used to skip every recording whose output was newer than it, whatever the flags: `archive
    DATA/ OUT/ --end-us 100000` then `--end-us 50000` said "3 skipped" and kept the longer archives. Each
    output now has its settings recorded beside it; a re-run with other settings makes it again and says
    so in the table; the same settings still skip. An output without a record (the user's own one-file
    archive in that folder, an older evstream's) is not replaced, and the table says why it was skipped."""
    data = tmp_path / "data"
    shutil.copytree(dataset / "synthetic", data)
    out = tmp_path / "out"
    base = ["archive", str(data), str(out), "--scheduler", client.scheduler.address, "--keep-noise"]

    def run(*flags, quiet=True) -> dict:
        assert main([*base, *flags, "--json", *(["--quiet"] if quiet else [])]) == 0
        report = json.loads(capsys.readouterr().out)
        return {Path(r["source"]).name: r for r in report["recordings"]}

    first = run("--end-us", "100000")
    assert {r["status"] for r in first.values()} == {"done"} and not any(r["redone"] for r in first.values())
    records = sorted(p.name for p in out.glob(".*.settings.json"))
    assert records == [".ball.mcap.settings.json", ".bar.mcap.settings.json", ".turntable.mcap.settings.json"]
    assert {r["status"] for r in run("--end-us", "100000").values()} == {"skipped"}
    assert {r["status"] for r in run("--end-us", "100000", quiet=False).values()} == {"skipped"}  # not a setting
    shorter = run("--end-us", "50000")
    assert {r["status"] for r in shorter.values()} == {"done"}
    assert all(r["changed"] == {"end_us": [100000, 50000]} for r in shorter.values())
    for name, r in shorter.items():
        assert r["events"] < first[name]["events"]
        assert len(events_of(out / name.replace(".npz", ".mcap"))["t"]) == r["events"]
    assert main([*base, "--end-us", "50000", "--denoise", "stcf", "--quiet"]) == 0  # the table says what changed
    printed = capsys.readouterr().out
    assert "3 done (3 redone), 0 skipped" in printed
    assert f"redone: {data / 'bar.npz'}: settings changed: --denoise (not given) -> stcf" in printed
    assert printed.count("  redone  ") == 3
    (out / ".bar.mcap.settings.json").unlink()  # an output made by an older evstream, without a record
    mine = out / "ball.mcap"
    assert main(["archive", str(data / "ball.npz"), str(mine), "--frames", "--quiet"]) == 0  # the user's own
    kept = {p: p.read_bytes() for p in (out / "bar.mcap", mine)}
    assert main([*base, "--end-us", "60000", "--quiet"]) == 0  # other settings: a re-run replaced both
    printed = capsys.readouterr().out
    assert {p: p.read_bytes() for p in kept} == kept
    assert "1 done (1 redone), 2 skipped" in printed
    for name in ("bar.npz", "ball.npz"):
        assert (f"skipped: {data / name}: no record of the settings it was made with (another command's output, "
                "or an older evstream's): left as it is; --force makes it again") in printed
    os.utime(data / "bar.npz")  # its recording newer than it: made again, as before the records
    again = run("--end-us", "60000")
    assert again["bar.npz"]["redone"] == "its recording is newer than it (no record of its settings)"
    assert again["ball.npz"]["status"] == "skipped" and again["ball.npz"]["note"].startswith("no record")
    assert run("--end-us", "60000", "--force")["ball.npz"]["redone"] == "--force"


def test_an_edited_pipeline_file_makes_the_recordings_again(client, dataset, tmp_path, capsys):
    """`archive DATA/ OUT/ --pipeline p.toml`, p.toml edited, the same command again: the flags are the same,
    the pipeline is not (its contents count as a setting)."""
    data = tmp_path / "data"
    shutil.copytree(dataset / "synthetic", data)
    toml = tmp_path / "p.toml"
    toml.write_text('[[stage]]\nkind = "stcf"\n')
    argv = ["archive", str(data), str(tmp_path / "out"), "--pipeline", str(toml), "--end-us", "50000",
            "--scheduler", client.scheduler.address, "--quiet"]
    assert main(argv) == 0
    assert main(argv) == 0
    assert "0 done, 3 skipped" in capsys.readouterr().out
    toml.write_text('[[stage]]\nkind = "baf"\n')
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "3 done (3 redone), 0 skipped" in printed and f"settings changed: {toml} was edited" in printed


def test_frames_convert_and_eval_reruns_follow_their_settings(client, dataset, tmp_path, capsys):
    """The same for `frames`, `convert` and `eval --out`: a changed flag makes the recordings again."""
    data = tmp_path / "data"
    shutil.copytree(dataset / "synthetic", data)
    scheduler = ["--scheduler", client.scheduler.address, "--quiet"]
    commands = {
        "frames": (["frames", str(data), "--out", str(tmp_path / "frames"), "--framer", "fw", "--end-us", "100000",
                    *scheduler], ["--window-us", "20000"], "--window-us"),
        "convert": (["convert", str(data), str(tmp_path / "converted"), "--end-us", "100000", *scheduler],
                    ["--to", "raw"], None),
        "eval": (["eval", str(data), "--out", str(tmp_path / "eval"), "--ratios", "0.5", "--rates-hz", "--seeds", "1",
                  "--methods", "baf", "--min-duration-s", "0.1", *scheduler], ["--methods", "stcf"], "--methods baf"),
    }
    for name, (argv, other, said) in commands.items():
        assert main(argv) == 0, name
        assert "3 done, 0 skipped" in capsys.readouterr().out, name
        assert main(argv) == 0, name
        assert "0 done, 3 skipped" in capsys.readouterr().out, name
        if name == "convert":  # another format is another output; another --end-us is the same one again
            other = ["--end-us", "60000"]
            said = "--end-us 100000 -> 60000"
        assert main([*argv, *other]) == 0, name
        printed = capsys.readouterr().out
        assert "3 done (3 redone), 0 skipped" in printed and said in printed, (name, printed)


def test_an_output_folder_inside_the_input_tree_is_not_read_back(client, dataset, tmp_path, capsys):
    """`archive DATA/ DATA/clean/` run twice: the second run skips every recording and reads none of the
    first run's archives back as recordings (it used to archive DATA/clean/*.mcap into DATA/clean/clean/,
    one level deeper each run); the same for a glob reaching into OUT, and OUT named as the input itself."""
    data = tmp_path / "data"
    shutil.copytree(dataset / "synthetic", data)
    out = data / "clean"
    argv = ["archive", str(data), str(out), "--scheduler", client.scheduler.address, *FLAGS, "--json"]
    assert main(argv) == 0
    first = json.loads(capsys.readouterr().out)
    assert (first["done"], first["skipped"]) == (3, 0)
    made = sorted(p.relative_to(data).as_posix() for p in data.rglob("*.mcap"))
    assert made == ["clean/ball.mcap", "clean/bar.mcap", "clean/turntable.mcap"]
    assert main(argv) == 0
    second = json.loads(capsys.readouterr().out)
    assert (second["done"], second["skipped"], second["failed"]) == (0, 3, 0)
    assert sorted(p.relative_to(data).as_posix() for p in data.rglob("*.mcap")) == made
    globbed = batch.plan([str(data / "**")], out, ".mcap")
    assert sorted(Path(t.source).name for t in globbed) == ["ball.npz", "bar.npz", "turntable.npz"]
    link = tmp_path / "link"
    link.symlink_to(out)  # the same folder by another name
    assert all(Path(t.source).parent == data for t in batch.plan([str(data)], link, ".mcap"))
    assert main(["archive", str(out), str(out), "--quiet"]) == 2
    assert "no recording in it outside the output folder" in capsys.readouterr().err


def test_a_workers_reader_warning_reaches_the_user_in_one_line(client, dataset, tmp_path, capsys):
    """A truncated recording in a batch: its reader's warning (on a worker process, maybe another machine)
    comes back with the task's result and is printed as the one-file command prints it; it was Python's
    `.../sources/_base.py:249: EventWarning: ...` plus a line of our code, on the worker's stderr."""
    data = tmp_path / "data"
    data.mkdir()
    assert main(["convert", str(dataset / "bar.npz"), str(data / "whole.raw"), "--quiet"]) == 0
    raw = (data / "whole.raw").read_bytes()
    (data / "cut.raw").write_bytes(raw[: len(raw) - 3])  # half an EVT3 word at the end
    capsys.readouterr()
    argv = ["archive", str(data), str(tmp_path / "out"), "--scheduler", client.scheduler.address, "--quiet", "--json"]
    assert main(argv) == 0  # read to the end (no --end-us): the truncation is seen
    captured = capsys.readouterr()
    said = [line for line in captured.err.splitlines() if "half an EVT3 word" in line]
    assert len(said) == 1 and said[0].startswith("evstream: warning: ") and "cut.raw" in said[0]
    report = {Path(r["source"]).name: r for r in json.loads(captured.out)["recordings"]}
    assert report["whole.raw"]["warnings"] == [] and report["cut.raw"]["warnings"] == [said[0].split(": ", 2)[2]]


def test_convert_many_writes_what_the_one_file_command_writes(client, dataset, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["convert", str(dataset / "synthetic" / "b*.npz"), str(dataset / "turntable.npz"), str(out), "--to", "raw",
            "--scheduler", client.scheduler.address, "--quiet"]
    assert main(argv) == 0
    table = capsys.readouterr().out
    assert "3 done, 0 skipped" in table and "0 failed" in table
    for rec in [*sorted((dataset / "synthetic").glob("b*.npz")), dataset / "turntable.npz"]:
        one = tmp_path / "one" / rec.with_suffix(".raw").name
        assert main(["convert", str(rec), str(one), "--quiet"]) == 0
        assert (out / one.name).read_bytes() == one.read_bytes()


def test_several_recordings_need_a_folder(dataset, tmp_path, capsys):
    assert main(["archive", str(dataset / "bar.npz"), str(dataset / "ball.npz"), str(tmp_path / "x.mcap")]) == 2
    assert "go to a folder" in capsys.readouterr().err
    assert main(["archive", str(dataset / "bar.npz"), str(tmp_path / "a.txt")]) == 2  # the one-file form's error


def test_frames_many_writes_what_the_one_file_command_writes_and_a_rerun_skips(client, dataset, tmp_path, capsys):
    """`frames DIR/ --out OUT/`: each recording's PNGs in OUT/ITS-PATH/ byte for byte those of the one-file
    command, its statistics in OUT/ITS-PATH.frames.json equal to the one-file --json's; `--set` reaches
    the tasks; a re-run skips every recording, --force redoes them."""
    out = tmp_path / "out"
    flags = ["--framer", "fw", "--window-us", "40000", "--end-us", "200000", "--denoise", "paper",
             "--set", "coarse.window_us=8000", "--quiet"]
    argv = ["frames", str(dataset / "synthetic"), "--out", str(out), "--scheduler", client.scheduler.address, *flags]
    assert main(argv) == 0
    assert "3 done, 0 skipped" in capsys.readouterr().out
    for rec in sorted((dataset / "synthetic").glob("*.npz")):
        one = tmp_path / "one" / rec.stem
        assert main(["frames", str(rec), "--out", str(one), "--json", *flags]) == 0
        want = json.loads(capsys.readouterr().out)["results"]
        got = json.loads((out / f"{rec.stem}.frames.json").read_text())["results"]
        assert [r["frames"] for r in got] == [r["frames"] for r in want] and got[0]["frames"] > 0
        assert got[0]["events_signal"] == want[0]["events_signal"] < got[0]["events_in"]  # the cascade ran
        assert got[0]["mean_events"] == want[0]["mean_events"]
        pngs = sorted(p.name for p in one.glob("*.png"))
        assert pngs and pngs == sorted(p.name for p in (out / rec.stem).glob("*.png"))
        for name in pngs:
            assert (out / rec.stem / name).read_bytes() == (one / name).read_bytes()
    assert main(argv) == 0
    assert "0 done, 3 skipped" in capsys.readouterr().out
    assert main([*argv, "--force"]) == 0
    printed = capsys.readouterr().out
    assert "3 done (3 redone), 0 skipped" in printed and "settings changed" not in printed
    assert printed.count(": --force") == 3
    assert main(["frames", str(dataset / "synthetic" / "*.npz"), *flags]) == 2  # several recordings need --out
    assert "--out FOLDER" in capsys.readouterr().err


def test_frames_many_leaves_nothing_for_a_recording_that_failed(client, dataset, tmp_path, capsys):
    """A recording that failed (after some of its frames were written) left its folder OUT/NAME/ behind,
    empty or half filled, beside the finished ones."""
    from test_safe_write import text_recording

    data = tmp_path / "data"
    data.mkdir()
    shutil.copy(dataset / "bar.npz", data / "good.npz")
    text_recording(data / "bad.txt", bad_last_line=True)
    out = tmp_path / "out"
    argv = ["frames", str(data), "--out", str(out), "--scheduler", client.scheduler.address, "--framer", "fw",
            "--window-us", "20000", "--quiet"]
    assert main(argv) == 1
    assert "bad.txt" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [".good.frames.json.settings.json", "good", "good.frames.json"]
    assert len(list((out / "good").glob("frame_*.png"))) > 5


def test_eval_many_gives_the_rows_of_the_one_process_eval_and_a_rerun_skips(client, dataset, tmp_path, capsys):
    """`eval DIR/ --out OUT/`: a task per recording; its rows (OUT/PATH.eval.json) are those the one-process
    `eval` computes for it; the tables and --json FILE cover every recording; a re-run skips them all."""
    out = tmp_path / "out"
    flags = ["--ratios", "0.5", "--rates-hz", "--seeds", "1", "--methods", "baf,paper", "--min-duration-s", "0.1",
             "--quiet"]
    argv = ["eval", str(dataset / "synthetic"), "--out", str(out), "--scheduler", client.scheduler.address,
            "--json", str(tmp_path / "rows.json"), *flags]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "3 done, 0 skipped" in printed and "all recordings (mean)" in printed
    many = json.loads((tmp_path / "rows.json").read_text())
    assert main(["eval", *sorted(map(str, (dataset / "synthetic").glob("*.npz"))), "--json",
                 str(tmp_path / "one.json"), *flags]) == 0
    capsys.readouterr()
    one = json.loads((tmp_path / "one.json").read_text())
    key = lambda r: (r["recording"], r["method"], r["condition"])  # noqa: E731
    assert len(one) == 6 and sorted(many, key=key) == sorted(one, key=key)
    assert sorted(p.name for p in out.glob("*.eval.json")) == ["ball.eval.json", "bar.eval.json",
                                                                "turntable.eval.json"]
    assert main(argv) == 0
    assert "0 done, 3 skipped" in capsys.readouterr().out
    assert main(["eval", str(dataset / "synthetic"), "--out", str(out), "--methods", "learned", "--quiet"]) == 2
    assert "leave-one-recording-out" in capsys.readouterr().err


def test_recordings_of_one_name_in_two_formats_get_an_output_each(tmp_path):
    """A folder with rec.aedat4 and rec.npy (tonic's datasets ship both) was refused: both went to rec.mcap.
    Now each keeps its extension in its output's name, whichever way the command line names them."""
    data = tmp_path / "data"
    (data / "sub").mkdir(parents=True)
    for name in ("rec.aedat4", "rec.npy", "other.npz", "sub/rec.npz"):
        (data / name).write_bytes(b"x")
    want = {"rec.aedat4.mcap", "rec.npy.mcap", "other.mcap", "sub/rec.mcap"}
    got = {os.path.relpath(t.out, tmp_path / "out") for t in batch.plan([str(data)], tmp_path / "out", ".mcap")}
    assert got == want
    globbed = batch.plan([str(data / "rec.npy"), str(data / "*.aedat4")], tmp_path / "out", ".frames.json")
    assert sorted(Path(t.out).name for t in globbed) == ["rec.aedat4.frames.json", "rec.npy.frames.json"]


def test_tonics_aedat4_and_npy_of_one_recording_both_convert(client, real_data, tmp_path, capsys):
    data = tmp_path / "tonic"
    data.mkdir()
    for ext in ("aedat4", "npy"):
        shutil.copy(real_data / f"dvxplorer_320x240_tonic.{ext}", data)
    out = tmp_path / "out"
    assert main(["convert", str(data), str(out), "--to", "npz", "--scheduler", client.scheduler.address,
                 "--quiet"]) == 0
    assert "2 done, 0 skipped" in capsys.readouterr().out
    for ext in ("aedat4", "npy"):
        rec = data / f"dvxplorer_320x240_tonic.{ext}"
        assert len(events_of(out / f"{rec.name}.npz")["t"]) == len(events_of(rec)["t"]) > 1000


def _write_out(source, out):
    Path(out).write_bytes(Path(source).read_bytes())
    return {}


def test_an_unwritten_settings_record_says_what_a_rerun_does(tmp_path):
    """The record beside an output could not be written (here a folder has its name): the task is done and
    warns. The warning said "a re-run makes it again", but a re-run leaves an output without a record as it
    is (redo_reason: UNRECORDED); the warning says that now, and --force."""
    source, out = tmp_path / "rec.npz", tmp_path / "out" / "rec.mcap"
    source.write_bytes(b"recording")
    out.parent.mkdir()
    batch.settings_file(out).mkdir()  # the record's name is taken
    settings = batch.settings_of(_write_out, {})
    got = batch._run_task(_write_out, str(source), str(out), {}, settings=settings)
    assert got["ok"] and out.read_bytes() == b"recording"
    [warning] = got["warnings"]
    assert warning.startswith(f"{out}: no record of its settings written (")
    assert warning.endswith("a re-run leaves it as it is, --force makes it again")
    assert batch.redo_reason(batch.Task(str(source), str(out)), settings) == (False, batch.UNRECORDED, {})


def test_a_bad_pipeline_or_model_file_is_one_error_before_the_cluster_starts(dataset, tmp_path, capsys):
    """`archive DATA/ OUT/ --pipeline missing.toml` started the cluster, then failed every recording with the
    same line, one per row of the table. The file is read once first: one error, exit 1, nothing written."""
    (tmp_path / "bad.toml").write_text("kind = [\n")
    (tmp_path / "model.npz").write_bytes((ROOT / "recordings" / "bar.npz").read_bytes())
    cases = {("--pipeline", tmp_path / "missing.toml"): "missing.toml: no such pipeline file",
             ("--pipeline", tmp_path / "bad.toml"): "bad.toml: not valid TOML",
             ("--denoise", "learned", "--model", tmp_path / "model.npz"): "model.npz: not an evstream model file"}
    for flags, said in cases.items():
        rc = main(["archive", str(dataset), str(tmp_path / "out"), *map(str, flags), "--jobs", "1", "--quiet"])
        out, err = capsys.readouterr()
        assert rc == 1 and out == "" and len(err.splitlines()) == 1, err
        assert err.startswith(f"evstream: error: {tmp_path / said.split(':')[0]}:") and said in err, err
        assert not (tmp_path / "out").exists()


def test_one_recording_into_a_folder_named_like_a_file_or_beside_a_namesake_says_where_it_went(client, dataset,
                                                                                                  tmp_path, capsys):
    """Session 9's audit: `archive w/bar.npz OUT` wrote OUT/bar.npz.mcap (w/ also holds bar.raw) and
    `archive bar.npz d.mcap` with a folder d.mcap wrote d.mcap/bar.mcap; the table said neither."""
    w = tmp_path / "w"
    w.mkdir()
    shutil.copy(dataset / "bar.npz", w / "bar.npz")
    assert main(["convert", str(w / "bar.npz"), str(w / "bar.raw"), "--end-us", "20000", "--quiet"]) == 0
    out = tmp_path / "d.mcap"
    out.mkdir()
    argv = ["archive", str(w / "bar.npz"), str(out), "--end-us", "20000", "--quiet",
            "--scheduler", client.scheduler.address]
    capsys.readouterr()
    assert main(argv) == 0
    said = capsys.readouterr()
    assert (out / "bar.npz.mcap").is_file()
    assert f"named: {w / 'bar.npz'} -> {out / 'bar.npz.mcap'}: a recording beside another of the same name " \
           "keeps its extension in its output's name" in said.out.splitlines()
    assert said.err == (f"evstream: note: {out} is a folder: the output goes into it (the many-recordings form); "
                        f"to write the file {out}, move the folder away\n")
    assert main([*argv[:2], str(tmp_path / "e.mcap") + "/", *argv[3:]]) == 0  # a folder asked for: no note
    said = capsys.readouterr()
    assert said.err == "" and "named: " in said.out


SCRIPT = """import evstream
from evstream import batch
{before}
def job():
    tasks = batch.plan([{rec!r}], {out!r}, ".mcap")
    for r in batch.run_many(tasks, evstream.archive, {{"end_us": 20_000}}, jobs=1):
        print(r.status, r.events)
{call}
"""


@pytest.mark.parametrize("before, call, line", [
    ("", "job()", 8),  # the job started at the script's top level, as the audit's script did
    ("", "if __name__ != '__main__':\n    pass\nelse:\n    job()", 11),  # a guard's else runs in the workers too
    ("import sys\nif len(sys.argv) > 5:\n    pass\n", "for _ in range(1):\n    job()", 12),
])
def test_run_many_from_a_script_without_the_main_guard_is_one_line_saying_what_to_write(tmp_path, before, call, line):
    """A script calling run_many outside `if __name__ == "__main__":` printed ~170 lines per worker ('Nanny
    failed to start', multiprocessing's bootstrapping error: each spawned worker imports the script, which
    started the job again). Now one line naming the script's line and what to write, exit 1, nothing started."""
    script = tmp_path / "job.py"
    script.write_text(SCRIPT.format(before=before, call=call, rec=str(ROOT / "recordings" / "bar.npz"),
                                    out=str(tmp_path / "out")))
    r = subprocess.run([sys.executable, script], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr.splitlines() == [f"{script}, line {line}: run_many is called at the script's top level, and "
                                     "each worker process imports the script, so each would start the job again; "
                                     "put the job under `if __name__ == \"__main__\":` (docs/scale.md)"]
    assert not (tmp_path / "out").exists()


def test_run_many_from_a_guarded_script_runs(tmp_path):
    """The same script with the guard (the call reached through a function, the test reversed): the job runs
    on the local cluster."""
    script = tmp_path / "job.py"
    script.write_text(SCRIPT.format(before="", call="if '__main__' == __name__:\n    job()",
                                    rec=str(ROOT / "recordings" / "bar.npz"), out=str(tmp_path / "out")))
    r = subprocess.run([sys.executable, script], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[0] == "done" and (tmp_path / "out" / "bar.mcap").exists()
