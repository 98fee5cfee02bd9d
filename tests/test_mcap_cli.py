"""`evstream archive` end to end: the command, replaying its output, and real processes stopped by
SIGINT/SIGTERM (a valid file) or killed with SIGKILL (every complete chunk recovered)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from evstream.sources import mcap_log, native, open_source
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from evstream.cli import main
from evstream.events import Geometry, concat
from evstream.testing import random_stream

EVSTREAM = str(Path(sys.executable).parent / "evstream")


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """About 3 s of labelled events at 346x260 (≈ 200k events/s)."""
    path = tmp_path_factory.mktemp("rec") / "rec.npz"
    native.save(path, random_stream(11, 600_000, Geometry(346, 260), mean_dt_us=5.0), {"scene": "random"})
    return path


def test_archive_command_and_replay_of_the_archive(recording, tmp_path, capsys):
    out = tmp_path / "a.mcap"
    code = main(["archive", str(recording), str(out), "--denoise", "truth", "--keep-noise", "--frames",
                 "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["events_in"] == 600_000 and summary["frames_written"] > 100 and summary["stopped_by"] is None
    src = open_source(out)
    got = concat(list(src))
    truth = concat(list(open_source(recording)))
    assert len(got) == len(truth)
    order = np.lexsort((truth.label, truth.t))
    np.testing.assert_array_equal(got.t, truth.t[order])
    np.testing.assert_array_equal(got.cls, truth.label[order])  # the truth stage's classes came back
    prov = mcap_log.provenance(out)
    assert prov["pipeline"]["stages"][0]["kind"] == "truth" and prov["pipeline"]["framer"]["kind"] == "fw"
    assert prov["source"] == str(recording) and prov["width"] == 346
    assert main(["info", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["events"] == 600_000
    assert main(["replay", str(out), "--denoise", "none", "--save", str(tmp_path / "r.rrd"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["events_background"] == int(
        (truth.label == 1).sum())


def test_archive_usage_errors(recording, tmp_path):
    assert main(["archive", str(recording), str(tmp_path / "a.txt")]) == 2
    assert main(["archive", str(recording), str(tmp_path / "a.mcap"), "--denoise", "nope"]) == 2
    assert main(["archive", str(tmp_path / "missing.npz"), str(tmp_path / "a.mcap")]) == 1


def _start(recording, out, *extra, chunks=3):
    proc = subprocess.Popen([EVSTREAM, "archive", str(recording), str(out), "--denoise", "truth", "--speed", "1",
                             "--flush-s", "0.1", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # wait until a few chunks are on disk (beside OUT until whole)
        if len(_complete_chunks(_part(out))) >= chunks:
            return proc
        if proc.poll() is not None:
            raise AssertionError(f"archiver ended early: {proc.communicate()}")
        time.sleep(0.05)
    proc.kill()
    raise AssertionError("archiver wrote no chunks in 60 s")


def _part(out) -> Path:
    """Where an archive is written until it is whole (`evstream.safe_write`)."""
    return Path(f"{out}.part")


def _complete_chunks(path) -> list[int]:
    """Messages in each chunk that mcap's own stream reader can read whole (stops at the cut)."""
    out = []
    if not os.path.exists(path):
        return out
    try:
        with open(path, "rb") as f:
            for rec in StreamReader(f, emit_chunks=True).records:
                if isinstance(rec, Chunk):
                    out.append(sum(isinstance(r, Message) for r in breakup_chunk(rec, validate_crc=True)))
    except Exception:  # the end of a file still being written, or cut by a kill
        pass
    return out


def _full_archive(recording, tmp_path):
    out = tmp_path / "full.mcap"
    assert main(["archive", str(recording), str(out), "--denoise", "truth"]) == 0
    return concat(list(open_source(out)))


def test_sigkill_loses_at_most_the_chunk_in_progress(recording, tmp_path):
    out = tmp_path / "killed.mcap"
    proc = _start(recording, out, chunks=5)  # a bounded wait for chunks on disk, not a fixed sleep
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert not out.exists()  # the target is never a half-written file
    part = _part(out)
    with open(part, "rb") as f:
        assert f.read()[-8:] != mcap_log.MAGIC  # no footer: the writer never finished
    in_chunks = sum(_complete_chunks(part))
    with pytest.warns(mcap_log.TruncatedFileWarning, match=f"recovered {in_chunks:,} event packets"):
        src = open_source(part)
        got = concat(list(src))
    assert src.recovered_messages == in_chunks > 0
    full = _full_archive(recording, tmp_path)
    assert 0 < len(got) < len(full)
    for f in "txyp":
        np.testing.assert_array_equal(getattr(got, f), getattr(full, f)[: len(got)])


@pytest.mark.parametrize(("sig", "older"), [(signal.SIGINT, True), (signal.SIGTERM, False)])
def test_sigint_and_sigterm_finish_a_valid_file_beside_the_target(recording, tmp_path, sig, older):
    """Ctrl-C used to rename the events so far onto OUT: an older, whole archive there was replaced by a
    partial one. Now OUT is left as it was (or not written) and the archive so far, closed properly, is
    OUT-STEM.partial.mcap, which the message names."""
    out = tmp_path / f"stopped-{sig.name}.mcap"
    if older:
        out.write_bytes(b"an older archive")
    proc = _start(recording, out, "--json")
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, stderr
    partial = tmp_path / f"stopped-{sig.name}.partial.mcap"
    target = f"{out} left as it was" if older else f"{out} not written"
    assert stderr.decode().strip().splitlines()[-1] == (
        f"evstream: interrupted by {sig.name}; {target}; the archive of the events up to there is {partial}")
    assert (out.read_bytes() == b"an older archive") if older else not out.exists()
    assert not _part(out).exists()
    summary = json.loads(stdout.decode().strip().splitlines()[-1])
    assert summary["stopped_by"] == sig.name and 0 < summary["events_in"] < 600_000
    assert summary["mcap"] == str(partial) and summary["partial"] is True
    with open(partial, "rb") as f:
        assert make_reader(f).get_summary() is not None  # footer and summary written
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a complete file: no truncation warning
        got = concat(list(open_source(partial)))
    assert len(got) == summary["events_signal"]
    assert int(mcap_log.read_metadata(partial)["evstream.stats"]["run_events_in"]) == summary["events_in"]


def test_a_second_interrupted_archive_does_not_replace_the_first_partial_file(recording, tmp_path):
    out = tmp_path / "a.mcap"
    (tmp_path / "a.partial.mcap").write_bytes(b"the first interrupted run")
    proc = _start(recording, out)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert (tmp_path / "a.partial.mcap").read_bytes() == b"the first interrupted run"
    assert stderr.decode().strip().endswith(f"is {tmp_path / 'a.partial.1.mcap'}")
    assert len(concat(list(open_source(tmp_path / "a.partial.1.mcap")))) > 0


@pytest.mark.parametrize("name", ["prophesee_gen41_hd_evt3_expelliarmus.raw", "davis346_frames_imu_evlib.aedat4"])
def test_real_recordings_archive_and_read_back_with_their_classes(real_data, tmp_path, name):
    from evstream.pipeline import Pipeline, build

    rec = real_data / name
    out = tmp_path / "real.mcap"
    assert main(["archive", str(rec), str(out), "--denoise", "paper", "--keep-noise", "--frames"]) == 0
    pipe = Pipeline([build("stage", {"kind": "paper"})])
    want = concat([pipe.process(c).events for c in open_source(rec)])
    want = want[np.lexsort((want.cls, want.t))]
    got = concat(list(open_source(out)))
    assert got.geometry == want.geometry and len(got) == len(want) > 1_000
    for f in ("t", "x", "y", "p", "cls"):
        np.testing.assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f)
    assert 0 < int((got.cls != 0).sum()) < len(got)


def test_sigkill_at_random_points_after_the_first_packet_recovers_a_prefix(recording, tmp_path):
    """Issue 22: 5 of 12 kills in the first second recovered nothing (the first chunk closed after 1 s or
    4 MiB). The first chunk now closes with the first packet, so any kill after it recovers events, the
    events the archive would hold, in order. `EVSTREAM_KILLS=N` for more kills (seeded)."""
    rng = np.random.default_rng(22)
    full = _full_archive(recording, tmp_path)
    for k in range(int(os.environ.get("EVSTREAM_KILLS", "3"))):
        out = tmp_path / f"k{k}.mcap"
        proc = subprocess.Popen([EVSTREAM, "archive", str(recording), str(out), "--denoise", "truth", "--speed", "1",
                                 "--flush-s", "0.2"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 60
        while not _complete_chunks(_part(out)) and time.monotonic() < deadline:  # the first packet is written
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        time.sleep(float(rng.uniform(0, 1.5)))
        proc.kill()
        proc.wait(timeout=30)
        assert not out.exists()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mcap_log.TruncatedFileWarning)
            got = concat(list(open_source(_part(out))))
        assert 0 < len(got) < len(full)
        for f in "txyp":
            np.testing.assert_array_equal(getattr(got, f), getattr(full, f)[: len(got)])
