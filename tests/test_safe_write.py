"""Nothing destroyed (issue 22): no output is (or is renamed onto) an input, by file identity; every writer
(archive, convert, replay --save, frames --out) writes beside its target and renames when whole, so a
failed run leaves what was there; an input cut short while read is an error; a full disk is one line
naming the file, with nothing left under its name."""

import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_checks import one_line_error
from evstream.sources import native, open_source, prophesee_raw

from evstream.cli import main
from evstream.events import Geometry, concat
from evstream.safe_write import AtomicOutput, OutputIsInput
from evstream.testing import random_stream

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "recordings" / "bar.npz"
EVSTREAM = str(Path(sys.executable).parent / "evstream")


def run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def events_of(path):
    return concat(list(open_source(path)))


def raw_recording(path, n=200_000):
    prophesee_raw.save(path, random_stream(3, n, Geometry(640, 480), mean_dt_us=2.0).replace(label=None))
    return path


def test_convert_onto_the_name_its_temporary_had_keeps_the_input(tmp_path, capsys):
    """`convert X.raw.part X.raw` deleted its input and wrote half the events (the temporary was X.raw.part)."""
    src = raw_recording(tmp_path / "X.raw.part")
    before = src.read_bytes()
    rc, _, err = run(["convert", src, tmp_path / "X.raw"], capsys)
    assert rc == 0, err
    assert src.read_bytes() == before
    assert len(events_of(tmp_path / "X.raw")) == len(events_of(src))


def test_convert_onto_a_hard_link_of_the_input_is_refused(tmp_path, capsys):
    src = tmp_path / "X.npz"
    shutil.copy(SHIPPED, src)
    os.link(src, tmp_path / "h.npz")
    rc, _, err = run(["convert", src, tmp_path / "h.npz"], capsys)  # rewrote the input in place
    assert rc == 2 and "h.npz: that is the input recording" in one_line_error(err)
    assert src.read_bytes() == SHIPPED.read_bytes()


def test_atomic_output_never_uses_an_existing_file_as_its_temporary(tmp_path):
    target = tmp_path / "a.mcap"
    (tmp_path / "a.mcap.part").write_bytes(b"an earlier run's partial output")
    with AtomicOutput(target) as part:
        assert part.name == "a.mcap.1.part"
        part.write_bytes(b"new")
    assert target.read_bytes() == b"new"
    assert (tmp_path / "a.mcap.part").read_bytes() == b"an earlier run's partial output"
    (tmp_path / "in.raw").write_bytes(b"x")
    os.link(tmp_path / "in.raw", tmp_path / "out.raw")
    with pytest.raises(OutputIsInput, match="out.raw: that is the input recording"):
        AtomicOutput(tmp_path / "out.raw", [tmp_path / "in.raw"])


def corrupt_midway(src: Path, dst: Path, at: int | None = None) -> Path:
    """A copy of the native recording `src` whose x member has one event off the sensor, half way (or at
    event `at`)."""
    s = events_of(src)
    x = s.x.copy()
    x[len(x) // 2 if at is None else at] = 60000
    native.save(dst, s.replace(x=x))
    return dst


def test_an_archive_that_failed_before_its_first_packet_leaves_no_part_file(tmp_path, capsys):
    """A damaged input failing at its first event kept `OUT.mcap.part` (an MCAP of nothing), one more
    `OUT.mcap.N.part` per run; it is kept only when it holds an event packet or a frame."""
    s = events_of(SHIPPED)
    x = s.x.copy()
    x[0] = 60000
    bad = tmp_path / "bad.npz"
    native.save(bad, s.replace(x=x))
    out = tmp_path / "old.mcap"
    out.write_bytes(b"the user's older file")
    for _ in range(2):
        rc, _, err = run(["archive", bad, out], capsys)
        assert rc == 1
        line = one_line_error(err)
        assert "bad.npz" in line and "outside" in line and ".part" not in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz", "old.mcap"]
    assert out.read_bytes() == b"the user's older file"


@pytest.mark.parametrize("command", ["archive", "convert.npz", "convert.raw", "convert.h5", "replay"])
def test_a_failed_run_leaves_the_old_output_as_it_was(tmp_path, capsys, command):
    """`archive BAD.raw old.mcap` turned a valid old.mcap into 2 KB with no events. (archive reads a file in
    chunks of FAST_CHUNK_EVENTS: its bad event comes after the first chunk, so that some packets were written
    before it.)"""
    from evstream.cli.common import FAST_CHUNK_EVENTS

    src = ROOT / "recordings" / "turntable.npz" if command == "archive" else SHIPPED
    at = FAST_CHUNK_EVENTS + 1_000 if command == "archive" else None
    assert at is None or at < len(events_of(src))
    bad = corrupt_midway(src, tmp_path / "bad.npz", at)
    name, _, ext = command.partition(".")
    out = tmp_path / {"archive": "old.mcap", "replay": "old.rrd"}.get(name, f"old.{ext}")
    out.write_bytes(b"the user's older file")
    argv = {"archive": ["archive", bad, out], "convert": ["convert", bad, out],
            "replay": ["replay", bad, "--save", out]}[name]
    rc, _, err = run(argv, capsys)
    assert rc == 1
    line = one_line_error(err)
    assert "bad.npz" in line and "outside" in line
    assert out.read_bytes() == b"the user's older file"
    left = sorted(p.name for p in tmp_path.iterdir())
    if name == "archive":  # the archive up to the failure is kept beside, and the error says where
        assert f"the output up to there is in {out}.part" in line and f"{out.name}.part" in left
        assert 0 < len(events_of(Path(f"{out}.part"))) < len(events_of(src))
    else:
        assert left == ["bad.npz", out.name]


def test_frames_out_writes_whole_pngs_only(tmp_path, capsys):
    rc, _, err = run(["frames", SHIPPED, "--framer", "fw", "--out", tmp_path / "f"], capsys)
    assert rc == 0, err
    names = sorted(p.name for p in (tmp_path / "f").iterdir())
    assert names and all(n.startswith("frame_") and n.endswith(".png") for n in names)


def test_an_input_that_shrinks_while_read_is_an_error(tmp_path):
    """`truncate` during `archive --speed 1` gave a partial archive, exit 0, no word."""
    src = raw_recording(tmp_path / "shrinks.raw", n=400_000)
    out = tmp_path / "s.mcap"
    proc = subprocess.Popen([EVSTREAM, "archive", src, out, "--speed", "1", "--denoise", "none"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not Path(f"{out}.part").exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    os.truncate(src, src.stat().st_size // 3)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    line = one_line_error(err)
    assert f"{src}: the file shrank from" in line and "missing" in line
    assert not out.exists()


# -- a full disk ---------------------------------------------------------------------------------------
def tmpfs(where: Path, options: str):
    """A tmpfs mounted at `where` with `options` while the test runs (CI runs as root; skipped where
    mounting is not allowed)."""
    where.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs ({options}) here (needs root): {r.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


@pytest.fixture
def full_disk(tmp_path):
    """A 2 MiB tmpfs (the tests fill it nearly)."""
    yield from tmpfs(tmp_path / "small", "size=2m")


COMMANDS = {  # command line, target name
    "convert.h5": (["convert", SHIPPED, "{d}/c.h5"], "c.h5"),  # was: a segfault in h5py, 5 of 5 runs
    "convert.npz": (["convert", SHIPPED, "{d}/c.npz"], "c.npz"),  # was: a truncated c.npz
    "convert.raw": (["convert", SHIPPED, "{d}/c.raw"], "c.raw"),
    "archive": (["archive", SHIPPED, "{d}/a.mcap", "--keep-noise", "--frames"], "a.mcap"),
    "replay": (["replay", SHIPPED, "--save", "{d}/r.rrd", "--point-budget", "0"], "r.rrd"),  # was: Rust log lines
    "frames": (["frames", SHIPPED, "--framer", "fw", "--window-us", "1000", "--out", "{d}/f"], "f"),
    # was: 'evstream: error: [Errno 28] No space left on device', no file named
    "frames.npz": (["frames", SHIPPED, "--framer", "voxel", "--window-us", "1000", "--out", "{d}/f"], "f"),
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_full_disk_is_one_line_naming_the_file_and_nothing_is_left_under_its_name(full_disk, command):
    argv, target = COMMANDS[command]
    (full_disk / "filler").write_bytes(bytes(2_000_000 - 300_000))  # 300 KB left: less than any output
    r = subprocess.run([EVSTREAM, *[a.format(d=full_disk) if isinstance(a, str) else a for a in argv]],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    line = one_line_error(r.stderr)
    # the target, not a temporary name (frames said 'DIR.part/frame_000074.png: ...')
    assert line.startswith(f"evstream: error: {full_disk / target}: no space left on the device; "), line
    assert "ERROR" not in r.stderr and "WARN" not in r.stderr  # no Rust log lines
    if command.startswith("frames"):  # nothing of the run (it is put in place whole or not at all)
        assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]
    else:
        assert not (full_disk / target).exists()
        assert not list(full_disk.glob("*.part"))


@pytest.fixture
def read_only(tmp_path):
    """A read-only tmpfs (root writes into a chmod-ed folder anyway)."""
    yield from tmpfs(tmp_path / "ro", "ro,size=1m")


READ_ONLY = {  # command line (the target last but for flags), target name
    **{k: v for k, v in COMMANDS.items() if k != "replay"},
    "replay": (["replay", SHIPPED, "--save", "{d}/r.rrd"], "r.rrd"),
    "synth": (["synth", "bar", "{d}/s.npz", "--duration-ms", "50"], "s.npz"),
    "train": (["train", SHIPPED, "--out", "{d}/m.npz", "--events-per-stream", "2000", "--quiet"], "m.npz"),
}


@pytest.mark.parametrize("command", list(READ_ONLY))
def test_a_read_only_folder_is_one_line_naming_the_target(read_only, capsys, command):
    """An output in a read-only folder said Python's "[Errno 30] Read-only file system: '/d/c.raw.part'":
    a temporary file's name the user never typed (train's `.m.npz.tmp1234`). Now the target and the reason."""
    argv, target = READ_ONLY[command]
    rc, _, err = run([a.format(d=read_only) if isinstance(a, str) else a for a in argv], capsys)
    assert rc == 1
    line = one_line_error(err)
    assert line.startswith(f"evstream: error: {read_only / target}: cannot write") and "Errno" not in line, line
    assert line.endswith("Read-only file system"), line


@pytest.mark.parametrize("command", ["archive", "convert", "frames", "eval"])
def test_many_recordings_into_a_read_only_folder_is_one_line_before_any_task(read_only, capsys, command):
    """The many-recordings form said Python's "[Errno 30] Read-only file system: 'OUT'" on every recording's row
    (after starting a cluster). Now one line naming the folder, exit 1, before anything runs."""
    recordings = str(Path(SHIPPED).parent) + "/"
    for out in (read_only, read_only / "new" / "deeper"):
        argv = [command, recordings, *(["--out"] if command in ("frames", "eval") else []), str(out)]
        rc, stdout, err = run(argv, capsys)
        assert rc == 1 and stdout == ""
        assert err == f"evstream: error: {out}: cannot write there: Read-only file system\n"
    if command == "convert":  # not the folder form's 'cannot write there: File exists'
        rc, _, err = run(["convert", SHIPPED, "/dev/null"], capsys)
        assert rc == 1 and err.startswith("evstream: error: /dev/null: not a folder, and many recordings go to one")


def test_a_rerun_recording_on_a_full_disk_ends_every_time(full_disk):
    """rerun-sdk 0.41's file writer, stopped by a full disk, left `flush()` waiting for ever in about half
    the runs (and the SDK's destructor and exit flush after it): replay --save hung. Six runs, each ends."""
    for run_no in range(6):
        for p in full_disk.iterdir():
            p.unlink()
        (full_disk / "filler").write_bytes(bytes(2_000_000 - 500_000))
        r = subprocess.run([EVSTREAM, "replay", SHIPPED, "--save", str(full_disk / "r.rrd"), "--point-budget", "0"],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 1 and "no space left" in one_line_error(r.stderr), (run_no, r.stderr)
        assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]


def test_a_disk_that_fills_while_an_archive_is_written_keeps_the_older_archive(full_disk, capsys):
    out = full_disk / "a.mcap"
    out.write_bytes(b"older archive")
    (full_disk / "filler").write_bytes(bytes(2_000_000 - 400_000))
    rc, _, err = run(["archive", SHIPPED, out, "--keep-noise", "--frames"], capsys)
    assert rc == 1 and "no space left" in one_line_error(err)
    assert out.read_bytes() == b"older archive"
    np.testing.assert_equal(sorted(p.name for p in full_disk.iterdir()), ["a.mcap", "filler"])


def test_an_archive_stopped_early_from_the_api_leaves_the_target_and_sets_its_events_aside(tmp_path):
    """`evstream.archive(..., stop=)` renamed the events so far onto OUT, replacing an older archive."""
    import evstream

    out = tmp_path / "a.mcap"
    out.write_bytes(b"older")
    calls = []
    summary = evstream.archive(SHIPPED, out, stop=lambda: calls.append(1) or len(calls) >= 2)
    assert out.read_bytes() == b"older" and not Path(f"{out}.part").exists()
    assert summary["partial"] is True and summary["mcap"] == str(tmp_path / "a.partial.mcap")
    assert 0 < len(events_of(summary["mcap"])) == summary["events_signal"] < len(events_of(SHIPPED))
    whole = evstream.archive(SHIPPED, out)  # not stopped: put in place as before
    assert whole["partial"] is False and whole["mcap"] == str(out) and out.read_bytes()[:5] != b"older"


def test_set_aside_never_replaces_a_file_and_keeps_the_extension(tmp_path):
    (tmp_path / "x.rrd").write_bytes(b"target")
    (tmp_path / "x.partial.rrd").write_bytes(b"first")
    out = AtomicOutput(tmp_path / "x.rrd")
    out.part.write_bytes(b"second")
    assert out.set_aside() == tmp_path / "x.partial.1.rrd"
    assert [(p.name, p.read_bytes()) for p in sorted(tmp_path.iterdir())] == [
        ("x.partial.1.rrd", b"second"), ("x.partial.rrd", b"first"), ("x.rrd", b"target")]


def test_a_second_ctrl_c_keeps_the_archive_so_far_and_says_where(tmp_path):
    """The second signal raises KeyboardInterrupt mid-run: the target stays, the archive so far is closed in
    OUT.part and the interruption names it (it said only 'evstream: interrupted')."""
    import evstream

    class Interrupted:
        geometry = Geometry(64, 48)
        path = None

        def __iter__(self):
            stream = random_stream(5, 20_000, self.geometry, mean_dt_us=50.0)
            yield stream[:10_000]
            raise KeyboardInterrupt

    out = tmp_path / "a.mcap"
    out.write_bytes(b"older")
    with pytest.raises(KeyboardInterrupt) as e:
        evstream.archive(Interrupted(), out, pipeline=evstream.build_pipeline("none"))
    assert str(e.value) == f"{out} left as it was; the output up to there is in {out}.part"
    assert out.read_bytes() == b"older" and len(events_of(f"{out}.part")) == 10_000


def text_recording(path, bad_last_line: bool):
    """0.4 s of the bar scene as a text file; with `bad_last_line`, one event outside the sensor at the end:
    the run fails after its frames were written."""
    from evstream import synth

    c = synth.scene("bar", duration_us=400_000, seed=0)
    lines = [f"{c.geometry.width} {c.geometry.height}"] + [f"{t} {x} {y} {int(p)}" for t, x, y, p in
                                                            zip(c.t, c.x, c.y, c.p)]
    path.write_text("\n".join(lines + (["400001 999 5 1"] if bad_last_line else [])) + "\n")
    return path


def test_frames_out_that_fails_leaves_the_folder_as_it_was(tmp_path, capsys):
    """A run that failed after writing frames left them (and a new, empty or half-filled folder) behind,
    over the frames of an earlier run; a whole run replaced frames but kept an earlier run's extra ones."""
    good, bad = text_recording(tmp_path / "good.txt", False), text_recording(tmp_path / "bad.txt", True)
    frames = ["--framer", "fw", "--window-us", "20000", "--quiet"]
    rc, _, err = run(["frames", bad, "--out", tmp_path / "new", *frames], capsys)
    assert rc == 1 and "outside the 346x260 sensor" in one_line_error(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.txt", "good.txt"]  # no folder, no .part
    old = tmp_path / "old"
    old.mkdir()
    (old / "notes.txt").write_text("mine")
    for i in range(30):
        (old / f"frame_{i:06d}.png").write_bytes(b"an older frame")
    before = {p.name: p.read_bytes() for p in old.iterdir()}
    rc, _, err = run(["frames", bad, "--out", old, *frames], capsys)
    assert rc == 1 and {p.name: p.read_bytes() for p in old.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.txt", "good.txt", "old"]
    rc, out, err = run(["frames", good, "--out", old, *frames], capsys)
    assert rc == 0, err
    pngs = sorted(p.name for p in old.glob("frame_*.png"))
    assert pngs == [f"frame_{i:06d}.png" for i in range(20)]  # the 10 older ones past the end are gone
    assert all((old / name).read_bytes().startswith(b"\x89PNG") for name in pngs)
    assert (old / "notes.txt").read_text() == "mine" and f"wrote 20 PNG frames to {old}\n" in out


def fill(folder: Path) -> None:
    """Fill the file system `folder` is on, to the last byte."""
    f = open(folder / "filler", "wb")  # noqa: SIM115 - closing may raise ENOSPC too
    try:
        while True:
            f.write(bytes(4096))
            f.flush()
    except OSError:
        pass
    try:
        f.close()
    except OSError:
        pass


@pytest.mark.parametrize("what", ["synth", "eval --json", "eval --roc"])
def test_synth_and_eval_outputs_on_a_full_disk_keep_the_older_file(full_disk, capsys, what):
    """`synth OUT`, `eval --json FILE` and `eval --roc FILE` wrote their file in place: a full disk (or a
    Ctrl-C) left it empty or cut short, the older file gone."""
    out = full_disk / {"synth": "s.npz", "eval --json": "rows.json", "eval --roc": "roc.png"}[what]
    out.write_bytes(b"older")
    fill(full_disk)
    argv = {"synth": ["synth", "bar", out, "--duration-ms", "100"],
            "eval --json": ["eval", SHIPPED, "--methods", "baf", "--ratios", "1.0", "--seeds", "1", "--json", out],
            "eval --roc": ["eval", SHIPPED, "--methods", "baf", "--ratios", "1.0", "--seeds", "1", "--roc", out]}[what]
    rc, _, err = run(argv, capsys)
    assert rc == 1 and "no space left" in one_line_error(err) and str(out) in one_line_error(err)
    assert out.read_bytes() == b"older"
    assert sorted(p.name for p in full_disk.iterdir()) == sorted([out.name, "filler"])


def test_eval_of_a_named_recording_that_cannot_be_read_is_one_line(tmp_path, capsys):
    """It printed 'skipping REC: ...' then 'error: no recording to evaluate' and exited 2 (a usage error)."""
    cut = tmp_path / "cut.npz"
    cut.write_bytes(SHIPPED.read_bytes()[:5000])  # no zip directory
    rc, _, err = run(["eval", cut, "--methods", "baf", "--ratios", "1.0", "--seeds", "1"], capsys)
    assert rc == 1, err
    assert one_line_error(err).startswith(f"evstream: error: {cut}")


def test_subscribe_save_writes_each_cameras_recording_beside_its_name_until_the_end(tmp_path):
    """A second camera's `live.CAM.rrd` was written in place from its first packet: an older file of that
    name was gone at once, and a killed subscriber left a cut-short one."""
    import argparse

    from evstream.sinks.rerun_viewer import open_output

    from evstream.cli.subscriber import Subscriber

    for cam in ("a", "b"):
        (tmp_path / f"live.{cam}.rrd").write_bytes(b"older")
    node = Subscriber(argparse.Namespace(keyexpr="evstream/*/events"))
    node.viewer = open_output(save=str(tmp_path / "live.rrd"))
    try:
        for cam in ("first", "a", "b"):
            node.viewer_rec(cam).log("x", __import__("rerun").Scalars(1.0))
        assert (tmp_path / "live.a.rrd").read_bytes() == b"older" and (tmp_path / "live.b.rrd.part").exists()
        node.finish_recordings()
        node.viewer.finish()
    finally:
        node.viewer.stop()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.a.rrd", "live.b.rrd", "live.rrd"]
    assert all((tmp_path / f"live.{c}.rrd").read_bytes()[:5] != b"older" for c in "ab")


@pytest.mark.parametrize("flag", ["--json", "--roc"])
def test_eval_never_writes_its_rows_or_plot_over_a_recording_it_reads(tmp_path, capsys, flag):
    """`eval REC --json REC` wrote the JSON rows over the recording (exit 0); so did a link to it, or a
    file of the --real folder."""
    rec = tmp_path / "rec.npz"
    shutil.copy(SHIPPED, rec)
    os.symlink(rec, tmp_path / "link.npz")
    for argv in ([rec, flag, rec], [rec, flag, tmp_path / "link.npz"], ["--real", tmp_path, flag, rec]):
        rc, _, err = run(["eval", *argv, "--methods", "baf", "--ratios", "1.0", "--seeds", "1"], capsys)
        assert rc == 2 and "that is the input recording" in one_line_error(err)
        assert rec.read_bytes() == SHIPPED.read_bytes()


def test_atomic_folder_replaces_stale_frames_only_where_it_wrote(tmp_path):
    from evstream.safe_write import AtomicFolder

    out = tmp_path / "frames"
    (out / "fw").mkdir(parents=True)
    for name in ("frame_000000.png", "fw/frame_000000.png", "fw/frame_000001.png", "notes.txt"):
        (out / name).write_bytes(b"old")
    with AtomicFolder(out, replaces=("frame_*.png",)) as part:
        (part / "fw").mkdir()
        (part / "fw" / "frame_000000.png").write_bytes(b"new")
        assert part.name == "frames.part" and not (out / "fw" / "frame_000000.png").read_bytes() == b"new"
    got = {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert got == {"frame_000000.png": b"old", "fw/frame_000000.png": b"new", "notes.txt": b"old"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames"]
    with pytest.raises(RuntimeError), AtomicFolder(out, replaces=("frame_*.png",)) as part:
        (part / "frame_000000.png").write_bytes(b"newer")
        raise RuntimeError("failed")
    assert (out / "frame_000000.png").read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == [
        "frames"]


def test_subscribe_archive_in_a_read_only_folder_fails_at_start(read_only, capsys):
    """`subscribe --archive RO/OUT_{camera}.mcap` subscribed, then failed when the first camera arrived (its
    publisher's stream lost). The folder is tried at start, before any session opens."""
    port = __import__("test_zenoh_live").free_port()  # nothing listens there: the check comes first
    template = read_only / "OUT_{camera}.mcap"
    rc, _, err = run(["subscribe", "evstream/*/events", "--connect", f"tcp/127.0.0.1:{port}", "--archive", template],
                     capsys)
    assert rc == 1
    assert one_line_error(err) == (f"evstream: error: --archive {template}: cannot write in {read_only}: "
                                   "Read-only file system")



@pytest.mark.parametrize("command", [["convert", SHIPPED, "{out}.raw"], ["archive", SHIPPED, "{out}.mcap"],
                                     ["replay", SHIPPED, "--save", "{out}.rrd"],
                                     ["eval", SHIPPED, "--methods", "stcf", "--ratios", "0.5", "--seeds", "1",
                                      "--json", "{out}.json"]], ids=["convert", "archive", "replay", "eval"])
def test_an_output_that_is_a_device_is_written_into_not_replaced(tmp_path, capsys, command):
    """`eval --json /dev/null` (as root) renamed a regular file over /dev/null: the temporary went into /dev and
    was renamed onto the device. A character device (a /dev/null made here) is now written into, as `cp`
    does, and stays a device; nothing is left beside it."""
    argv = [str(a).format(out=tmp_path / "null") for a in command]
    device = Path(argv[-1])
    try:
        os.mknod(device, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("no permission to make a character device here (needs root)")
    rc, _, err = run(argv, capsys)
    assert rc == 0, err
    assert device.is_char_device() and os.listdir(tmp_path) == [device.name]


def test_eval_rows_into_a_named_pipe_reach_its_reader(tmp_path, capsys):
    """`--json FIFO` replaced the pipe with a file, and its reader never had a byte."""
    fifo = tmp_path / "rows.json"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader is there: the writer's open does not wait
    try:
        rc, _, err = run(["eval", SHIPPED, "--methods", "stcf", "--ratios", "0.5", "--seeds", "1", "--json", fifo],
                         capsys)
        assert rc == 0, err
        assert fifo.is_fifo() and b'"stcf"' in os.read(reader, 1 << 16)  # one small document: in the pipe's buffer
    finally:
        os.close(reader)
