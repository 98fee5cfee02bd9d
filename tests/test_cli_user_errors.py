"""Mistakes users make, through the command line: damaged files, wrong flags, wrong pipeline files.
The rule: one line on stderr naming the file (and where it can, the byte) and the reason, exit code 1
(runtime) or 2 (usage); never an "internal error", a traceback or silently lost data."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cli_checks import one_line_error

from evstream.cli import main

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "recordings" / "bar.npz"
# How long a child may take to start when it compiles numba kernels: with the ahead-of-time kernels out of
# date (a kernel's source edited since `make aot`) and a cold numba cache, `subscribe` with the paper's
# cascade took 203 s of wall time (4.6 s of CPU) to say "subscribed to" at load 24. A bound, not a pace.
START_S = 600


def run(argv, capsys):
    """(exit code, stdout, stderr) of one `evstream` command run in this process."""
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize("member", ["t.npy", "x.npy", "y.npy", "p.npy", "label.npy"])
def test_native_npz_with_a_damaged_member_is_a_one_line_error(tmp_path, capsys, member):
    data = bytearray(SHIPPED.read_bytes())
    with zipfile.ZipFile(SHIPPED) as z:
        info = z.getinfo(member)
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    for k in range(8):  # flip bytes spread over the member's compressed data
        data[start + (k + 1) * info.compress_size // 10] ^= 0x5A
    bad = tmp_path / "bar.npz"
    bad.write_bytes(bytes(data))
    rc, _, err = run(["info", bad], capsys)
    assert rc == 1
    line = one_line_error(err)
    assert str(bad) in line and "unreadable native file" in line


@pytest.mark.parametrize("fraction", [0.13, 0.5, 0.97])
def test_native_npz_cut_short_says_truncated_not_unknown_format(tmp_path, capsys, fraction):
    data = SHIPPED.read_bytes()
    bad = tmp_path / "bar.npz"
    bad.write_bytes(data[: int(len(data) * fraction)])
    rc, _, err = run(["replay", bad, "--save", tmp_path / "x.rrd"], capsys)
    assert rc == 1
    line = one_line_error(err)
    assert str(bad) in line and "truncated" in line and f"byte {bad.stat().st_size}" in line
    assert "unrecognised format" not in line


@pytest.mark.parametrize("name, cut", [("prophesee_gen41_hd_evt3_expelliarmus.raw", 309_029),
                                       ("dvxplorer_320x240_tonic.aedat4", 474_630),
                                       ("nmnist_sample.bin", 10_818)])
def test_a_truncated_recording_warns_in_one_line_and_keeps_the_events_before(tmp_path, capsys, real_data,
                                                                               name, cut):
    cut_file = tmp_path / name
    cut_file.write_bytes((real_data / name).read_bytes()[:cut])
    rc, out, err = run(["info", cut_file], capsys)
    assert rc == 0 and "events" in out
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err  # not Python's "file.py:123: EventWarning: ..." plus a line of our code
    assert lines[0].startswith("evstream: warning: ") and name in lines[0] and "truncated" in lines[0]


def _chunk_spans(path):
    """(start, end, compressed records' start) of every MCAP chunk, by mcap's own stream reader."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    spans = []
    with open(path, "rb") as f:
        reader = StreamReader(f, emit_chunks=True)
        start = f.tell()
        for rec in reader.records:
            if isinstance(rec, Chunk):
                spans.append((start, f.tell(), f.tell() - len(rec.data)))
            start = f.tell()
    return spans


def test_an_archive_damaged_in_the_middle_is_an_error_not_a_short_recording(tmp_path, capsys):
    archive = tmp_path / "turntable.mcap"
    rc, _, _ = run(["archive", ROOT / "recordings" / "turntable.npz", archive, "--keep-noise", "--frames",
                    "--points"], capsys)
    assert rc == 0
    spans = _chunk_spans(archive)
    assert len(spans) >= 3
    original = archive.read_bytes()
    start, end, data_start = spans[1]  # the second chunk: more of the recording follows it
    data = bytearray(original)
    data[(data_start + end) // 2] ^= 0xFF
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(data))
    rc, out, err = run(["info", bad], capsys)
    assert rc == 1, out  # before: exit 0 with the first chunk's events only, the rest gone
    line = one_line_error(err)
    assert f"{bad} at byte {start}: damaged MCAP chunk" in line
    # a writer killed inside a chunk is still read up to there, with a warning (docs/archive.md)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(original[: (spans[2][0] + spans[2][1]) // 2])
    rc, out, err = run(["info", cut], capsys)
    assert rc == 0 and "evstream: warning:" in err and "ends inside a record" in err


@pytest.mark.parametrize("toml, says", [
    ('[[stages]]\nkind = "density"\n', "unknown table 'stages'"),  # before: ran with no stage, exit 0
    ('[stage]\nkind = "density"\n', "[[stage]] (double brackets)"),
    ('[[stage]]\nkind = "density"\nL = 5\n', "stage 'density': unknown parameter 'L'; its parameters: radius_px, "),
    ('[[stage]]\nname = "density"\n', "a stage needs kind = one of "),
    ('[[stage]]\nkind = "stcf"\n[framer]\nkind = "fw"\nwindow = 5000\n', "unknown parameter 'window'; its "
                                                                         "parameters: window_us, "),
])
def test_a_wrong_pipeline_file_names_the_mistake(tmp_path, capsys, toml, says):
    path = tmp_path / "pipeline.toml"
    path.write_text(toml)
    rc, out, err = run(["replay", SHIPPED, "--pipeline", path, "--save", tmp_path / "x.rrd"], capsys)
    assert rc == 1, out
    line = one_line_error(err)
    assert str(path) in line and says in line
    assert not (tmp_path / "x.rrd").exists()  # refused before anything ran


@pytest.mark.parametrize("argv, says", [
    (["replay", SHIPPED, "--speed", "-1"], "--speed -1: must be >= 0"),  # was exit 1
    (["replay", SHIPPED, "--speed", "nan"], "--speed nan: must be >= 0"),  # was a replay at full speed
    (["replay", SHIPPED, "--slab-ms", "0"], "--slab-ms 0: must be positive"),  # was exit 1, no flag named
    (["archive", SHIPPED, "OUT.mcap", "--speed", "-1"], "--speed -1: must be >= 0"),
    (["archive", SHIPPED, "OUT.mcap", "--flush-s", "-1"], "--flush-s -1: must be positive"),  # was accepted
    (["archive", SHIPPED, "OUT.mcap", "--packet-us", "0"], "--packet-us 0: must be positive"),
    (["eval", SHIPPED, "--seeds", "0"], "--seeds 0: must be positive"),  # printed empty tables, exit 0
    (["info", SHIPPED, "--geometry", "0x0"], "--geometry 0x0: Geometry.width must be"),  # was "--Geometry..."
    (["info", SHIPPED, "--geometry", "abc"], "--geometry abc: expected WIDTHxHEIGHT"),
    (["publish", SHIPPED, "--speed", "inf"], "--speed inf: must be >= 0"),
    (["subscribe", "evstream/*/events", "--geometry", "5x0"], "--geometry 5x0: Geometry.height must be"),
    (["subscribe", "evstream/*/events", "--flush-s", "0"], "--flush-s 0: must be positive"),
    # a Rerun recording written as x.mcap or x.npz (a name that says another format; over a recording too)
    (["replay", SHIPPED, "--save", "x.mcap"], "--save x.mcap: a Rerun recording's name ends in .rrd"),
    (["replay", SHIPPED, "--save", "out/x.npz"], "--save out/x.npz: a Rerun recording's name ends in .rrd"),
    (["subscribe", "evstream/*/events", "--save", "x"], "--save x: a Rerun recording's name ends in .rrd"),
    (["convert", SHIPPED, "x.mcap"], "x.mcap: output format from the extension: .npz (native), .raw (EVT3/EVT2), "
                                      ".h5; an MCAP archive: evstream archive REC OUT.mcap"),  # no way on was said
    (["convert", SHIPPED, "x.rrd"], "x.rrd: output format from the extension: .npz (native), .raw (EVT3/EVT2), "
                                     ".h5; a Rerun recording: evstream replay REC --save OUT.rrd"),
    (["replay", SHIPPED, "--denoise", "undistort"], "--denoise undistort: needs camera_info = FILE.yaml"),  # was 1
    # a comma list, as a user types it: was "could not convert string to float: '-'" (the string's characters)
    (["archive", SHIPPED, "OUT.mcap", "--denoise", "undistort", *(f"--set={k}=100" for k in ("fx", "fy", "cx", "cy")),
      "--set", "distortion=-0.3,0.1"], "undistort: distortion is a list of numbers, as in --set "
                                       "'distortion=[-0.3, 0.1, 0, 0]'; got '-0.3,0.1'"),
])
def test_a_flag_value_that_cannot_work_is_a_usage_error_naming_the_flag(tmp_path, capsys, monkeypatch, argv, says):
    monkeypatch.chdir(tmp_path)  # OUT.mcap, out/ land here if a check is missing
    rc, _, err = run(argv, capsys)
    assert rc == 2
    assert says in one_line_error(err)
    assert not any(tmp_path.iterdir())  # refused before anything was written


def test_replay_saving_where_no_file_can_be_written_is_a_plain_error(tmp_path, capsys):
    taken = tmp_path / "taken.rrd"
    taken.mkdir()  # a directory where the recording should go
    rc, out, err = run(["replay", SHIPPED, "--save", taken], capsys)
    assert rc == 1 and out == ""
    line = one_line_error(err)  # was "internal error: RuntimeError: Failed to create file ..."
    assert line.startswith(f"evstream: error: {taken}: cannot write the Rerun recording") and "directory" in line


# -- live: what a publisher says when nobody gets its packets (real Zenoh router on loopback) --------------
def test_publisher_whose_router_goes_away_says_how_much_nobody_received(tmp_path):
    from test_zenoh_live import PacketCount, Procs, free_port

    procs = Procs(tmp_path)
    try:
        port = free_port()
        router = procs.router(port)
        sub = procs.subscriber(port, "evstream/*/events", "--denoise", "none", "--until-end",
                               "--archive", str(tmp_path / "flow.mcap"))
        # bar.npz is 0.5 s of events (50 packets): 10 s at --speed 0.05, so the router dies in the middle and
        # the publisher has seconds to hear of it (at 3.3 s, under load 10+, the stream could end first).
        # The router goes after 5 packets, not 15: under load 30+ a publisher seconds behind its pace puts the
        # rest at once (paced catches up), and all 50 had been delivered when the 15th was counted here.
        with PacketCount(port, "evstream/cam/events") as flowing:
            pub = procs.start("publish", SHIPPED, "--key", "evstream/cam/events", "--connect",
                              f"tcp/127.0.0.1:{port}", "--speed", "0.05", "--wait-subscribers", "20", "--drain-s", "1",
                              "--json")
            flowing.wait(5)  # a tenth of the stream out, the rest to go
            assert pub.poll() is None, procs.stderr(pub)
            router.send_signal(signal.SIGTERM)
            router.wait(timeout=30)
        got = procs.result(pub)  # exit 0: the camera itself did nothing wrong
        assert 0 < got["unmatched_packets"] < got["packets"] == 50
        assert 0 < got["unmatched_events"] < got["events"]
        warning = [line for line in procs.stderr(pub).splitlines() if line.startswith("evstream: warning:")]
        assert len(warning) == 1, procs.stderr(pub)
        assert (f"{got['unmatched_packets']:,} of 50 packets ({got['unmatched_events']:,} events) went out while no "
                "subscriber matched evstream/cam/events") in warning[0]
        sub.send_signal(signal.SIGTERM)
        received = procs.result(sub)
        # what the subscriber got and what the publisher says nobody got add up to what was published
        assert received["events"] + got["unmatched_events"] <= got["events"]
        assert received["events"] >= got["events"] - got["unmatched_events"] - 10_000  # in flight at the cut
    finally:
        procs.kill_all()


def test_publish_says_its_rate_over_the_streaming_not_the_wait_for_a_subscriber(tmp_path):
    """`publish` printed a rate over a time that counted more than the streaming (the user audit: the wait for a
    subscriber, the drain; and the first packet's put, which loaded the encoder's kernels, ~0.5 s). Now the
    rate is over the time from the first packet's put to the end of the last one's, said so, and the wait
    and the drain are said apart: three disjoint parts of the run, so together no longer than it."""
    import re

    from test_zenoh_live import Procs, free_port

    procs = Procs(tmp_path)
    try:
        port = free_port()
        procs.router(port)
        flags = ["--key", "evstream/cam/events", "--connect", f"tcp/127.0.0.1:{port}", "--speed", "0", "--drain-s", "1"]
        pub = procs.start("publish", SHIPPED, *flags, "--wait-subscribers", "4", "--json")  # nobody will come
        got = procs.result(pub)
        assert got["packets"] == 50 and got["waited_s"] >= 4
        assert got["stream_s"] > 0 and got["events_per_s"] == pytest.approx(got["events"] / got["stream_s"])
        assert got["stream_s"] + got["waited_s"] + got["drained_s"] <= got["wall_s"]

        pub = procs.start("publish", SHIPPED, *flags, "--wait-subscribers", "1")
        assert pub.wait(timeout=120) == 0, procs.stderr(pub)
        line = (tmp_path / f"out{pub.n}.txt").read_text().strip()
        assert re.fullmatch(r"published 174,999 events in 50 packets on evstream/cam/events: [\d.]+ [Mk]? ?ev/s over "
                            r"the [\d.]+ s from the first packet to the last \(not counted: [\d.]+ s waiting for a "
                            r"subscriber(, [\d.]+ s draining)?\)", line), line
    finally:
        procs.kill_all()


@pytest.mark.parametrize("name, where", [("dvxplorer_320x240_tonic.aedat4", ": event 0:"),  # no byte offsets
                                         ("prophesee_gen3_vga_evt2_faery.raw", " at byte 170: event 0:")])
def test_an_error_never_names_a_made_up_byte_range(capsys, real_data, name, where):
    rc, _, err = run(["info", real_data / name, "--geometry", "100x100"], capsys)
    assert rc == 1
    line = one_line_error(err)
    assert "bytes 0..0" not in line  # AEDAT4's decoder gives no offsets: it said "in bytes 0..0"
    assert f"{real_data / name}{where}" in line and "outside the 100x100 sensor" in line


def test_an_output_that_is_the_input_recording_is_refused_and_the_recording_kept(tmp_path, capsys):
    rec = tmp_path / "bar.npz"
    rec.write_bytes(SHIPPED.read_bytes())
    archive = tmp_path / "a.mcap"
    assert run(["archive", rec, archive], capsys)[0] == 0
    kept = archive.read_bytes()
    (tmp_path / "link.mcap").symlink_to(archive)
    for argv, says in [
        (["archive", archive, archive], f"{archive}: that is the input recording"),  # was: emptied, exit 0
        (["archive", archive, tmp_path / "link.mcap"], "link.mcap: that is the input recording"),
        (["replay", rec, "--save", rec], f"--save {rec}: that is the input recording"),  # was: overwritten
    ]:
        rc, _, err = run(argv, capsys)
        assert rc == 2 and says in one_line_error(err)
    assert archive.read_bytes() == kept and rec.read_bytes() == SHIPPED.read_bytes()


def test_the_command_replay_prints_for_opening_its_file_runs_in_the_same_shell(tmp_path):
    env = {**os.environ, "PATH": "/usr/bin:/bin"}  # a shell where the venv is not activated (make demo)
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "replay", SHIPPED, "--save", "x.rrd"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    line = next(line for line in r.stdout.splitlines() if "open it with:" in line)
    command = line.split("open it with:")[1].split()[0]
    exe = shutil.which(command, path=env["PATH"]) or (str(tmp_path / command) if "/" in command else None)
    assert exe and os.access(exe, os.X_OK), f"{command!r} does not run in that shell"  # was plain 'rerun'
    v = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
    assert v.returncode == 0 and "rerun" in v.stdout.lower()
    # the other way it names replays the recording (was "evstream replay --spawn / --serve": typed with the
    # .rrd, as the line suggests, it failed: an .rrd is not a recording)
    alternative = line.split("(or: ")[1].split(" --spawn")[0].split()
    assert alternative == ["evstream", "replay", str(SHIPPED)]
    again = subprocess.run([sys.executable, "-m", "evstream.cli", *alternative[1:], "--save", "y.rrd", "--quiet"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr


def test_a_reader_that_leaves_early_is_not_an_error_message():
    """`evstream info REC | head -1`: the pipe closes before evstream writes."""
    p = subprocess.Popen([sys.executable, "-m", "evstream.cli", "info", SHIPPED], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # the reader is gone before a byte is written
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 141  # 128 + SIGPIPE, as a tool killed by it
    assert err == ""  # was "evstream: error: [Errno 32] Broken pipe"


def test_archive_of_a_recording_with_a_long_pause_before_a_small_packet(tmp_path):
    """A camera left idle for hours, then a few events: the packet after the pause steps its EVT3 clock
    across ~2,000 wraps. That wrote past the encoder's buffer (sized from the packet's first event):
    segfault or glibc abort in `evstream archive`. In a child process, so a crash cannot take pytest."""
    from evstream.sources import native, open_source

    from evstream.events import concat

    src = open_source(SHIPPED)
    ev = concat(list(src), src.geometry)
    half = len(ev) // 2
    t = ev.t.copy()
    t[half:] += 10 * 3600 * 1_000_000  # ten hours of silence
    paused = ev.replace(t=t)[: half + 3]  # then three events
    rec, out = tmp_path / "paused.npz", tmp_path / "paused.mcap"
    native.save(rec, paused, {})
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "archive", rec, out, "--denoise", "none"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, (r.returncode, r.stderr)
    back = concat(list(open_source(out)), src.geometry)
    assert len(back) == len(paused)
    for f in "txyp":
        np.testing.assert_array_equal(getattr(back, f), getattr(paused, f))


def _limit_memory():  # a child that would try to take the machine's memory gets MemoryError instead
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))


def test_a_geometry_too_large_for_memory_is_a_one_line_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "replay", SHIPPED, "--geometry", "60000x60000",
                        "--save", tmp_path / "x.rrd"], capture_output=True, text=True, timeout=120,
                       preexec_fn=_limit_memory)
    assert r.returncode == 1  # was: 'internal error: MemoryError'
    line = one_line_error(r.stderr)
    assert line.startswith("evstream: error: out of memory: ") and "GiB" in line


def test_one_corrupt_coordinate_in_a_file_without_a_size_is_an_error_not_a_giant_sensor(tmp_path, real_data):
    """The .npy twin has no sensor size: it is fitted to the events. One event at (60000, 60000) made a
    60001x60001 sensor, and the cascade's per-pixel state (13 GiB a stage) ran the machine out of memory."""
    a = np.load(real_data / "dvxplorer_320x240_tonic.npy")
    a["x"][30000] = a["y"][30000] = 60000
    bad = tmp_path / "one_bad_event.npy"
    np.save(bad, a)
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "archive", bad, tmp_path / "out.mcap"],
                       capture_output=True, text=True, timeout=120, preexec_fn=_limit_memory)
    assert r.returncode == 1
    line = one_line_error(r.stderr)
    assert f"{bad} at byte {bad.stat().st_size - (len(a) - 30000) * a.dtype.itemsize}: event 30000: (60000, 60000) " \
        "outside the 2048x2048 sensor" in line and "MemoryError" not in line
    # a real recording without a size still gets its own sensor
    rc = subprocess.run([sys.executable, "-m", "evstream.cli", "info", real_data / "dvxplorer_320x240_tonic.npy"],
                        capture_output=True, text=True, timeout=120)
    assert rc.returncode == 0 and "320x240" in rc.stdout


def test_a_packet_claiming_a_giant_sensor_is_refused_in_a_file_and_skipped_live(tmp_path):
    """EventPackets carry width/height (uint32). One claiming 60000x60000 gave the replay, or a live
    subscriber, a 60001x60001 pipeline: MemoryError, or the machine out of memory. A file is refused;
    on the wire the packet is counted as malformed and the stream goes on (docs/live.md)."""
    from evstream.sources.zenoh_session import open_session
    from mcap.writer import Writer
    from test_zenoh_live import Procs, _end_stream, free_port, matched_publisher

    from evstream.codecs.event_packet import DATATYPE, MSGDEF, encode_packet
    from evstream.codecs.packets import to_packet

    t = np.arange(10, dtype=np.int64) + 1000
    x = np.arange(10, dtype=np.uint16)
    p = np.zeros(10, np.uint8)
    path = tmp_path / "giant.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        schema = w.register_schema(name=DATATYPE, encoding="ros2msg", data=MSGDEF.encode())
        ch = w.register_channel(topic="/dvs/events", message_encoding="cdr", schema_id=schema)
        data = encode_packet(to_packet(t, x, x, p, width=60000, height=60000))
        w.add_message(ch, log_time=1000, publish_time=1000, data=data)
        w.finish()
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "replay", path, "--save", tmp_path / "g.rrd"],
                       capture_output=True, text=True, timeout=START_S, preexec_fn=_limit_memory)
    assert r.returncode == 1
    assert "claim a 60000x60000 sensor, larger than any event camera" in one_line_error(r.stderr)

    procs = Procs(tmp_path)
    try:
        port = free_port()
        ep = f"tcp/127.0.0.1:{port}"
        procs.router(port)
        n = len(procs.procs)
        sub = subprocess.Popen([sys.executable, "-m", "evstream.cli", "subscribe", "evstream/*/events", "--connect", ep,
                                "--until-end", "--json"], cwd=ROOT, preexec_fn=_limit_memory,
                               stdout=open(tmp_path / f"out{n}.txt", "wb"), stderr=open(tmp_path / f"err{n}.txt", "wb"))
        sub.n = n
        procs.procs.append(sub)
        # the subscriber runs the default pipeline (the paper's cascade: per-pixel state that a 60001x60001
        # sensor would have taken out of memory), whose kernels it loads before it says "subscribed to": with
        # them to compile under load that took minutes, and a 30-s wait failed the test (START_S)
        procs.wait_for(sub, "subscribed to", timeout_s=START_S)
        session = open_session(connect=[ep])
        try:
            pub = matched_publisher(session, "evstream/evil/events", timeout_s=60)
            assert pub.matching_status.matching, "the subscriber never matched: the packets would go nowhere"
            pub.put(encode_packet(to_packet(t, x, x, p, width=60000, height=60000, seq=0)))
            pub.put(encode_packet(to_packet(t + 1000, x, x, p, width=346, height=260, seq=1)))
            _end_stream(session, pub)  # both packets and the end mark reached the router
            out = procs.result(sub, timeout_s=START_S)  # exit 0: it lived through it; the session open till then (as
            # in test_zenoh_live: closing drops what Zenoh still holds on the way, docs/live.md)
        finally:
            session.close()
        got = out["cameras"]["evil"]
        assert got["malformed"] == 1 and got["events"] == 10 and got["ended"]
        assert "sensor size 60000x60000: larger than any event camera" in procs.stderr(sub)
    finally:
        procs.kill_all()


def test_a_header_claiming_a_giant_sensor_is_refused_before_memory_runs_out(tmp_path, real_data):
    raw = (real_data / "prophesee_gen41_hd_evt3_expelliarmus.raw").read_bytes()
    at = raw.index(b"% evt 3.0\n")
    bad_raw = tmp_path / "claims.raw"
    bad_raw.write_bytes(raw[:at] + b"% geometry 60000x60000\n" + raw[at:])  # a corrupt header line
    a = dict(np.load(SHIPPED))
    a["width"] = a["height"] = np.int64(60000)
    bad_npz = tmp_path / "claims.npz"
    np.savez(bad_npz, **a)
    for bad in (bad_raw, bad_npz):
        r = subprocess.run([sys.executable, "-m", "evstream.cli", "replay", bad, "--save", tmp_path / "x.rrd"],
                           capture_output=True, text=True, timeout=120, preexec_fn=_limit_memory)
        assert r.returncode == 1  # was: MemoryError for a 13 GiB cascade state (or the machine out of memory)
        line = one_line_error(r.stderr)
        assert f"{bad}: the file claims a 60000x60000 sensor" in line and "larger than any event camera" in line
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "info", bad_raw, "--geometry", "1280x720", "--json"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and '"events": 219596' in r.stdout  # the user's --geometry still reads it


def test_stats_bins_over_a_pause_of_months_take_memory_for_the_events_only():
    """A camera paused 2^50 µs (36 years: a corrupt clock) inside one chunk: the statistics used a dense
    row per 10 ms bin of the pause (TiB), MemoryError in replay; a 2^42 µs pause took 9.8 GiB."""
    from evstream.sinks.rerun_sink import StatsBins

    t = np.array([0, 5, 25_000, 1 << 50, (1 << 50) + 7], np.int64)
    cls = np.array([0, 1, 2, 0, 1], np.uint8)
    bins = StatsBins(0, 10_000)
    ends, counts = bins.push(t, cls, int(t[-1]))
    gap_first, gap_last = 3, (1 << 50) // 10_000 - 1  # the empty bins around the pause: two rows, not 10^11
    assert ends.tolist() == [10_000, 20_000, 30_000, (gap_first + 1) * 10_000, (gap_last + 1) * 10_000]
    assert counts.tolist() == [[1, 1, 0], [0, 0, 0], [0, 0, 1], [0, 0, 0], [0, 0, 0]]
    end, last = bins.flush(int(t[-1]))
    assert last.tolist() == [[1, 1, 0]] and end.tolist() == [int(t[-1]) + 1]


@pytest.mark.parametrize("byte", [1190, 2245])
def test_an_aedat4_header_byte_flipped_names_the_byte_not_a_rust_panic(tmp_path, real_data, byte):
    data = bytearray((real_data / "davis346_frames_imu_evlib.aedat4").read_bytes())
    data[byte] ^= 0x80  # one bit: the XML description is no longer UTF-8
    bad = tmp_path / "flipped.aedat4"
    bad.write_bytes(bytes(data))
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "info", bad], capture_output=True, text=True,
                       timeout=120)  # a child: the decoder's panic wrote a Rust backtrace to fd 2
    assert r.returncode == 1, r.stderr
    assert "panicked" not in r.stderr and "PanicException" not in r.stderr
    line = one_line_error(r.stderr)
    assert line == (f"evstream: error: {bad} at byte {byte}: corrupt AEDAT4 header: its stream description "
                    "is not UTF-8 (invalid start byte)")


def test_an_aedat4_stream_description_broken_by_a_flipped_byte_names_the_byte(tmp_path, real_data):
    """The decoder's XML parser said where as LINE:COLUMN of the stream description ('expected '=' not '"' at
    7:22'), which names no byte of the file."""
    data = bytearray((real_data / "davis346_frames_imu_evlib.aedat4").read_bytes())
    at = data.index(b'key="compression"') + 3  # the '=' of an attribute in the XML description
    data[at] = ord('"')
    bad = tmp_path / "xml.aedat4"
    bad.write_bytes(bytes(data))
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "info", bad], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1, r.stderr
    assert one_line_error(r.stderr) == (f"evstream: error: {bad} at byte {at}: corrupt AEDAT4 header: its stream "
                                        """description (XML) is malformed: expected '=' not '"'""")


@pytest.mark.parametrize("older", [False, True])
def test_ctrl_c_in_a_replay_stops_it_with_its_summary_and_the_file_so_far(tmp_path, older):
    """Ctrl-C renamed the events so far onto --save's file, replacing an older, whole one. Now that file is
    left as it was (or not written) and the recording so far is PART.partial.rrd, named in the message."""
    rrd = tmp_path / "part.rrd"
    if older:
        rrd.write_bytes(b"an older recording")
    proc = subprocess.Popen([sys.executable, "-m", "evstream.cli", "replay", ROOT / "recordings" / "turntable.npz",
                             "--save", rrd, "--speed", "0.1", "--json"],  # 1 s of events in 10 s
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        part = Path(f"{rrd}.part")  # where the recording is written until whole (evstream.safe_write)
        deadline = time.monotonic() + 60
        while not (part.exists() and part.stat().st_size > 50_000) and time.monotonic() < deadline:
            time.sleep(0.05)  # events are flowing (not just the header): past start-up, Ctrl-C now stops it
        time.sleep(0.5)
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130  # was: 'evstream: interrupted' alone, no account of what was written
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["stopped_by"] == "SIGINT" and 0 < summary["events_in"] < 254_078
    partial = tmp_path / "part.partial.rrd"
    assert summary["rrd"] == str(partial) and summary["partial"] is True
    target = f"{rrd} left as it was" if older else f"{rrd} not written"
    assert one_line_error(err) == (f"evstream: interrupted by SIGINT; {target}; the recording of the events up "
                                   f"to there is {partial}")
    assert (rrd.read_bytes() == b"an older recording") if older else not rrd.exists()
    assert partial.stat().st_size > 100_000 and not part.exists()


def test_the_summary_rate_adds_up_for_a_small_recording(tmp_path, capsys, real_data):
    """6,676 events in 0.4 s were reported as '(0.0 M ev/s)'."""
    import re

    for _ in range(2):  # the second run has its kernels loaded: 5 ms, once printed as '0.01 s (1.2 M ev/s)'
        rc, out, _ = run(["replay", real_data / "davis346_frames_imu_evlib.aedat4", "--save", tmp_path / "x.rrd"],
                         capsys)
        assert rc == 0
        m = re.match(r"([\d,]+) events in ([\d.]+) s \(([\d.]+) (M |k |)ev/s\)", out)
        n, wall, rate = int(m[1].replace(",", "")), float(m[2]), float(m[3]) * {"M ": 1e6, "k ": 1e3, "": 1}[m[4]]
        assert n == 6_676 and rate > 0
        assert abs(rate - n / wall) <= 0.05 * n / wall + 500, out  # the printed numbers agree, to their rounding
    from evstream.cli import event_rate

    assert [event_rate(r) for r in (5.44e6, 147_400, 512.4, 0)] == ["5.4 M ev/s", "147 k ev/s", "512 ev/s", "0 ev/s"]


@pytest.mark.parametrize("header, sep, order", [
    ("", ",", "txyp"),  # plain CSV: was 'unrecognised format' though the parser reads commas
    ("t,x,y,p\n", ",", "txyp"),  # a CSV with its column names
    ("timestamp x y polarity\n", " ", "txyp"),
    ("x,y,polarity,timestamp\n", ", ", "xypt"),  # the names give the order
])
def test_csv_and_named_columns_read_the_same_events_as_the_text_file(tmp_path, real_data, header, sep, order):
    from evstream.sources import open_source

    from evstream.events import concat

    src = real_data / "dvs128_lifetime_building_events.txt"
    rows = [ln.split() for ln in src.read_text().splitlines()]
    pick = ["txyp".index(c) for c in order]
    path = tmp_path / "events.csv"
    path.write_text(header + "".join(sep.join(r[i] for i in pick) + "\n" for r in rows))
    want = concat(list(open_source(src)))
    got_src = open_source(path)
    got = concat(list(got_src))
    assert got_src.format == "text" and got_src.columns == order and got.geometry == want.geometry
    for f in "txyp":
        np.testing.assert_array_equal(getattr(got, f), getattr(want, f))


def test_subscribe_archive_in_a_folder_that_cannot_exist_fails_at_start_naming_the_flag(tmp_path, capsys):
    (tmp_path / "a_file").write_text("")
    template = tmp_path / "a_file" / "sub" / "{camera}.mcap"
    port = __import__("test_zenoh_live").free_port()  # nothing listens there: the check comes first
    rc, _, err = run(["subscribe", "evstream/*/events", "--connect", f"tcp/127.0.0.1:{port}", "--archive",
                      template], capsys)
    assert rc == 1  # was: subscribed, then '[Errno 20] Not a directory' at the first packet, the node gone
    assert one_line_error(err) == (f"evstream: error: --archive {template}: cannot create "
                                   f"{tmp_path / 'a_file' / 'sub'}: Not a directory")


def test_the_point_budget_line_accounts_for_what_was_drawn(tmp_path, capsys, real_data):
    """95.9 ms of a Gen3 camera: 195,871 points drawn under a '1,000,000/s' budget read as a broken budget;
    the line now names the saved-up burst the drawn count includes."""
    import re

    rc, out, _ = run(["replay", real_data / "prophesee_gen3_vga_evt2_faery.raw", "--save", tmp_path / "x.rrd"],
                     capsys)
    assert rc == 0
    m = re.search(r"3D view: ([\d,]+) of ([\d,]+) events drawn, ([\d,]+) dropped by the point budget "
                  r"\(([\d,]+)/s of event time, bursts up to ([\d,]+)\)", out)
    assert m, out
    drawn, total, dropped, rate, burst = (int(g.replace(",", "")) for g in m.groups())
    assert drawn + dropped == total == 521_252
    assert drawn <= rate * 95_871e-6 + burst + 1  # the numbers on the line add up


@pytest.mark.parametrize("flag", ["--json", "--roc"])
def test_eval_refuses_an_output_it_cannot_write_before_evaluating(tmp_path, capsys, flag):
    (tmp_path / "a_file").write_text("")
    out = tmp_path / "a_file" / ("rows.json" if flag == "--json" else "roc.png")
    rc, stdout, err = run(["eval", SHIPPED, "--seeds", "1", "--ratios", "1", "--rates-hz", flag, out], capsys)
    assert rc == 1 and stdout == ""  # was: every table printed first (minutes on the full set), then the error
    assert one_line_error(err) == f"evstream: error: {flag} {out}: cannot write there: Not a directory"


def test_eval_real_names_a_folder(tmp_path, capsys):
    """`eval --real FILE` said "[Errno 20] Not a directory: 'FILE'", `--real MISSING` "[Errno 2] No such file or
    directory": Python's words without the flag. Now one line naming the flag, what was typed and why."""
    for given, why in ((SHIPPED, "not a folder"), (tmp_path / "missing", "no such folder")):
        rc, _, err = run(["eval", "--real", given], capsys)
        assert rc == 2
        assert one_line_error(err) == f"evstream: error: --real {given}: {why}"


def test_a_pipeline_file_that_is_not_there_or_a_folder_is_one_line_naming_it(tmp_path, capsys):
    """`--pipeline p.toml` with no such file said Python's "[Errno 2] No such file or directory: 'p.toml'"
    (a folder: "[Errno 21] Is a directory"), and so did every row of a many-recording run."""
    for given, why in ((tmp_path / "p.toml", "no such pipeline file"), (tmp_path, "is a folder, not a pipeline file")):
        rc, _, err = run(["replay", SHIPPED, "--pipeline", given, "--save", tmp_path / "x.rrd"], capsys)
        assert rc == 1
        assert one_line_error(err) == f"evstream: error: {given}: {why}"
    assert not (tmp_path / "x.rrd").exists()


def test_a_pipeline_file_that_is_not_utf8_is_one_line_naming_it_and_the_byte(tmp_path, capsys):
    """A pipeline file saved as Latin-1 (a comment with 'é') or as UTF-16 (Notepad's "Unicode") said Python's
    "'utf-8' codec can't decode byte 0xe9 in position 5: invalid continuation byte": no file named."""
    cases = {"latin1.toml": ("# café\n[[stage]]\nkind = 'stcf'\n".encode("latin-1"), 5),
             "utf16.toml": ("[[stage]]\nkind = 'stcf'\n".encode("utf-16"), 0)}
    for name, (data, at) in cases.items():
        (tmp_path / name).write_bytes(data)
        rc, _, err = run(["replay", SHIPPED, "--pipeline", tmp_path / name, "--save", tmp_path / "x.rrd"], capsys)
        assert rc == 1
        assert one_line_error(err) == (f"evstream: error: {tmp_path / name}: not UTF-8 text: byte {at} "
                                       f"(0x{data[at]:02x}); a pipeline file is TOML, which is UTF-8")
    assert not (tmp_path / "x.rrd").exists()


CTRL_C_WHILE_THE_FLAGS_ARE_READ = """
import argparse, signal, sys
sys.argv[0] = "evstream"  # as the console script: evstream/_start.py guards the start-up
from evstream.cli import main

add_argument = argparse.ArgumentParser.add_argument


def add_argument_then_ctrl_c(self, *args, **kwargs):  # the terminal's Ctrl-C while the flags are set up
    if args[:1] == ("--start-us",):
        signal.raise_signal(signal.SIGINT)
    return add_argument(self, *args, **kwargs)


argparse.ArgumentParser.add_argument = add_argument_then_ctrl_c
sys.exit(main(["info", sys.argv[1]]))
"""


def test_ctrl_c_while_the_command_reads_its_flags_is_one_line(tmp_path):
    """Seen 2 in 80 Ctrl-Cs at random moments: the parser is built (its modules load) after start-up's guard
    was released and before the command's own handling, so Python's traceback and exit -2."""
    out = subprocess.run([sys.executable, "-c", CTRL_C_WHILE_THE_FLAGS_ARE_READ, SHIPPED], capture_output=True,
                         text=True, cwd=tmp_path, timeout=120)
    assert (out.returncode, out.stderr, out.stdout) == (130, "evstream: interrupted\n", "")


@pytest.mark.parametrize("lines, says", [
    ("0.1 1 2 1\n0.2 60000 60000 1\n", "(60000, 60000) outside the 2048x2048 sensor (size from fitted to the events "
                                       "(no size line)) (if the file's is wrong: --geometry WxH, geometry=(W, H) in "
                                       "Python)"),  # was "pass geometry=(width, height)": Python, not a flag
    ("0.2 1 2 1\n0.1 1 2 1\n", "timestamp 100000 µs goes back from 200000 µs (to accept such streams: --timestamps "
                               "sort|drop, timestamps=\"sort\" in Python)"),
    ("100 1 2 1\n200 3000000000 2 1\n", "event 1 of a block has x = 3000000000.0: not a pixel index"),  # np.float64(
])
def test_a_text_recording_that_cannot_work_says_what_to_type(tmp_path, capsys, lines, says):
    path = tmp_path / "events.txt"
    path.write_text(lines)
    rc, _, err = run(["info", path], capsys)
    assert rc == 1 and says in one_line_error(err)


def test_eval_roc_without_matplotlib_is_one_error_before_the_work(tmp_path, capsys, monkeypatch):
    """`eval --roc x.png` without matplotlib ran the whole evaluation (minutes on real recordings), then said
    "no ROC plot" and exited 0: the file the user named was never written."""
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # what `import matplotlib` meets where it is not installed
    rc, out, err = run(["eval", SHIPPED, "--methods", "stcf", "--ratios", "0.5", "--seeds", "1",
                        "--roc", tmp_path / "roc.png"], capsys)
    assert rc == 1 and out == ""  # no table: refused before the evaluation
    assert one_line_error(err) == (f"evstream: error: --roc {tmp_path / 'roc.png'}: the ROC plot needs matplotlib, "
                                   "which is not installed (pip install matplotlib; or leave out --roc)")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("framer, says", [("voxel", "wrote 1 array (.npz) to"), ("fw", "wrote 1 PNG frame to")])
def test_a_count_of_one_is_said_in_the_singular(tmp_path, capsys, framer, says):
    """'wrote 1 arrays (.npz)' (found by the user audit): one window, one file, said in the singular; and a
    recording of one event converted and archived says '1 event', '1 event packet'."""
    rc, out, err = run(["frames", SHIPPED, "--denoise", "none", "--framer", framer, "--window-us", "10000000",
                        "--out", tmp_path / "o"], capsys)
    assert rc == 0, err
    assert says in out

    import evstream

    one = evstream.read(SHIPPED, end_us=1)
    assert len(one) == 1
    with evstream.open_sink(tmp_path / "one.npz", geometry=one.geometry) as sink:
        sink.write(one)
    rc, out, err = run(["convert", tmp_path / "one.npz", tmp_path / "one.h5"], capsys)
    assert rc == 0 and out.rstrip().endswith("): 1 event"), (out, err)
    rc, out, err = run(["archive", tmp_path / "one.npz", tmp_path / "one.mcap", "--denoise", "none"], capsys)
    assert rc == 0 and out.startswith("1 event in ") and ": 1 event packet, 0 frames" in out, (out, err)
