"""A user's files through the command line, checked against independent reads (numpy, h5py, faery,
the format specs) rather than our own decoders, and damaged copies of them: each damage ends in one
line naming the file, the byte where the format allows, and the reason, or is documented as
undetectable (docs/formats.md, "Bad input")."""

from __future__ import annotations

import struct
import subprocess
import sys

import numpy as np
import pytest
from cli_checks import one_line_error

AEDAT4 = "davis346_frames_imu_evlib.aedat4"


def cli(*argv, env=None):
    """`evstream ...` in a child process: a decoder writing to fd 2 (a Rust panic) shows up here."""
    r = subprocess.run([sys.executable, "-m", "evstream.cli", *map(str, argv)], capture_output=True, text=True,
                       timeout=120, env=env)
    return r.returncode, r.stdout, r.stderr


def run(capsys, *argv):
    """`evstream ...` in this process (no interpreter start-up): exit code, stdout, stderr."""
    from evstream.cli import main

    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def aedat4_packets(data: bytes) -> list[int]:
    """Byte offsets of the packet headers, walked per the AEDAT 4.0 spec: '#!AER-DAT4.0\\r\\n', a uint32
    header size, the header, then packets of (int32 stream id, uint32 size, size bytes)."""
    at = 18 + struct.unpack_from("<I", data, 14)[0]
    out = []
    while at + 8 <= len(data):
        out.append(at)
        at += 8 + struct.unpack_from("<I", data, at + 4)[0]
    return out


# -- AEDAT4: a flipped packet size or header offset --------------------------------------------------
@pytest.mark.parametrize("which, bit", [(3, 0x10), (3, 0x01), (25, 0x20), (25, 0x04)])
def test_aedat4_packet_size_flipped_is_an_error_not_a_truncated_file(tmp_path, real_data, which, bit):
    """A flipped size in a packet's header made the decoder stop early (read as a cut: exit 0, a warning,
    402 of 6676 events) or panic; the data table at the end says the file is complete, so it is an error."""
    data = bytearray((real_data / AEDAT4).read_bytes())
    at = aedat4_packets(bytes(data))[which]
    size = struct.unpack_from("<I", data, at + 4)[0]
    data[at + 4] ^= bit
    bad = tmp_path / AEDAT4
    bad.write_bytes(bytes(data))
    rc, out, err = cli("info", bad)
    assert rc == 1, (out, err)
    line = one_line_error(err)
    assert line.startswith(f"evstream: error: {bad} at byte ") and "corrupt AEDAT4 packet header" in line
    named = int(line.split(" at byte ")[1].split(":")[0])
    # the packet itself, or the header the wrong size leads to (a valid-looking one may come first)
    assert at <= named <= at + 8 + max(size, struct.unpack_from("<I", data, at + 4)[0]) + 64, (at, line)


@pytest.mark.parametrize("byte", [36, 38, 40, 42])
def test_aedat4_header_offset_flipped_is_a_one_line_error_not_a_rust_panic(tmp_path, real_data, byte):
    """Bytes 32..42 are the header flatbuffer's root offset and field table; the decoder follows them
    unchecked ('range start index 1852401788 out of range', a Rust backtrace on stderr)."""
    data = bytearray((real_data / AEDAT4).read_bytes())
    data[byte] ^= 0xFF
    bad = tmp_path / AEDAT4
    bad.write_bytes(bytes(data))
    rc, out, err = cli("info", bad)
    assert rc == 1 and out == "", (rc, out, err)  # each of these flips leaves an offset pointing astray
    line = one_line_error(err)
    assert line.startswith(f"evstream: error: {bad} at byte {byte}: corrupt AEDAT4 header"), line


@pytest.mark.parametrize("bit", [0x01, 0x80])
def test_aedat4_packet_that_makes_the_decoder_panic_is_one_line_naming_the_packet(tmp_path, real_data, bit):
    """A bit flipped in the LZ4 frame header of packet 25 (a trigger packet) passes every check of ours
    and makes the Rust decoder panic ('assertion failed: data.len() >= SIZE_SIZEPREFIX + ...'): a Rust panic
    message on fd 2, then pyo3's PanicException, a BaseException. The reader's panic suppression
    (aedat4._quiet_panics, and catching BaseException) makes that one line naming the packet; without the
    first the panic message shows, without the second a traceback."""
    data = bytearray((real_data / AEDAT4).read_bytes())
    at = aedat4_packets(bytes(data))[25]
    data[at + 8 + 8] ^= bit
    bad = tmp_path / AEDAT4
    bad.write_bytes(bytes(data))
    rc, out, err = cli("info", bad)
    assert rc == 1 and out == "", (rc, out, err)
    assert "panicked" not in err and "RUST_BACKTRACE" not in err and "Traceback" not in err, err
    assert one_line_error(err) == (f"evstream: error: {bad} at byte {at}: AEDAT4 decoding failed at packet 25: "
                                   "decoder panic: assertion failed: data.len() >= SIZE_SIZEPREFIX + SIZE_UOFFSET + "
                                   "FILE_IDENTIFIER_LENGTH")


def test_aedat4_cut_in_a_packet_warns_naming_the_packet_and_keeps_the_events_before(tmp_path, real_data):
    data = (real_data / AEDAT4).read_bytes()
    packets = aedat4_packets(data)
    cut = packets[20] + 100
    bad = tmp_path / AEDAT4
    bad.write_bytes(data[:cut])
    rc, out, err = cli("info", bad)
    assert rc == 0
    line = one_line_error(err)
    assert line.startswith("evstream: warning: ") and "truncated after 20 packets" in line
    assert f"packet 20 at byte {packets[20]} claims" in line and f"ends at byte {cut}" in line


# -- HDF5: damaged compressed data is not a missing plugin --------------------------------------------
H5 = "prophesee_gen3_vga_evt2_faery.h5"


@pytest.mark.parametrize("fraction", [0.31, 0.52, 0.77])
def test_hdf5_flipped_byte_in_compressed_data_names_the_chunk_not_a_missing_plugin(tmp_path, real_data,
                                                                                    fraction):
    """A damaged gzip chunk said "Prophesee HDF5 needs its ECF filter plugin: pip install hdf5plugin" —
    advice that cannot help: gzip is built in. Now it names the chunk, its byte and the reason."""
    import h5py

    data = bytearray((real_data / H5).read_bytes())
    flip = int(len(data) * fraction)
    data[flip] ^= 0xFF
    bad = tmp_path / H5
    bad.write_bytes(bytes(data))
    rc, _, err = cli("info", bad)
    assert rc == 1
    line = one_line_error(err)
    assert "ECF" not in line and "hdf5plugin" not in line
    assert line.startswith(f"evstream: error: {bad} at byte ") and "corrupt compressed data in /events/" in line
    named = int(line.split(" at byte ")[1].split(":")[0])
    with h5py.File(real_data / H5) as f:  # h5py's own chunk index: the named chunk holds the flipped byte
        ids = [f["events"][k].id for k in "txyp"]
        chunks = [d.get_chunk_info(i) for d in ids for i in range(d.get_num_chunks())]
    assert any(c.byte_offset == named and named <= flip < named + c.size for c in chunks)


def test_hdf5_compressed_with_a_filter_this_library_lacks_says_which(tmp_path):
    """The plugin advice stays for what it is for: a filter (here an unregistered id, as ECF is without
    its plugin) that the HDF5 library cannot run."""
    import h5py
    import numpy as np

    path = tmp_path / "ecf.h5"
    with h5py.File(path, "w") as f:
        f.attrs["width"], f.attrs["height"] = 64, 48
        g = f.create_group("events")
        for k, dtype in zip("txyp", ("<i8", "<u2", "<u2", "u1")):
            ds = g.create_dataset(k, shape=(10,), dtype=dtype, chunks=(10,), compression=36559,
                                  allow_unknown_filter=True)
            ds.id.write_direct_chunk((0,), np.arange(10, dtype=dtype).tobytes())
    rc, _, err = cli("info", path)
    assert rc == 1
    line = one_line_error(err)
    assert str(path) in line and "filter 36559" in line and "ECF filter plugin" in line


# -- fixed-size records: a timestamp going back names its event's byte --------------------------------
@pytest.mark.parametrize("name", ["nmnist_sample.bin", "ncaltech101_faces_easy_0001.bin", "dvsgesture_slayer_1.bs2"])
def test_nmnist_timestamp_flipped_names_the_events_byte_not_a_250000_byte_range(tmp_path, real_data, name):
    """N-MNIST records are 5 bytes (x, y, pol|t[22:16], t[15:8], t[7:0]); a flipped high timestamp byte in
    event k makes event k+1 go back. The error said '[in bytes 0..250000]'; event k+1 is at byte 5(k+1)."""
    data = bytearray((real_data / name).read_bytes())
    k = len(data) // 5 // 3
    data[5 * k + 2] ^= 0x40  # +2^22 µs on event k's clock
    bad = tmp_path / name
    bad.write_bytes(bytes(data))
    rc, _, err = cli("info", bad)
    assert rc == 1
    line = one_line_error(err)
    assert line.startswith(f"evstream: error: {bad} at byte {5 * (k + 1)}: event {k + 1}: timestamp ")
    assert "in bytes" not in line


# -- what the viewer shows: a real recording's .rrd read back with rerun's own reader -------------------
def test_replay_rrd_puts_each_noise_class_on_its_own_entity_and_colour(tmp_path, real_data):
    """README: signal blue, background activity orange, hot pixels magenta, each class its own entity
    under events/. Read the saved .rrd back (rerun 0.41's RrdReader) and compare the points per entity
    with the classes the same pipeline gives the events, and the printed summary."""
    import json
    from collections import defaultdict

    import numpy as np
    from evstream.sources import open_source
    from rerun.chunk import RrdReader

    from evstream.events import NoiseClass, concat
    from evstream.pipeline import Pipeline, build

    name = "dvxplorer_320x240_tonic.aedat4"  # 190 k events/s: under the default point budget, all drawn
    rrd = tmp_path / "out.rrd"
    rc, out, err = cli("replay", real_data / name, "--denoise", "paper", "--save", rrd, "--json")
    assert rc == 0, err
    summary = json.loads(out)
    src = open_source(real_data / name)
    pipe = Pipeline([build("stage", {"kind": "paper"})])
    classes = concat([pipe.process(c).events for c in src], src.geometry).classes()
    want = np.bincount(classes, minlength=3)
    assert want.sum() == summary["events_in"] == 111_954 and summary["points_dropped"] == 0
    assert [summary["events_signal"], summary["events_background"], summary["events_hot_pixel"]] == want.tolist()
    assert want.min() > 0  # the recording has all three classes: the test can tell them apart

    points, class_ids, context = defaultdict(int), {}, None
    for chunk in RrdReader(rrd).stream():
        rb = chunk.to_record_batch()
        cols = rb.schema.names
        if "Points3D:positions" in cols and not chunk.is_static:
            points[chunk.entity_path] += sum(len(r) for r in rb.column(cols.index("Points3D:positions")).to_pylist()
                                             if r is not None)
        if "Points3D:class_ids" in cols and chunk.is_static:
            class_ids[chunk.entity_path] = rb.column(cols.index("Points3D:class_ids")).to_pylist()[0]
        if "AnnotationContext:context" in cols:
            context = rb.column(cols.index("AnnotationContext:context")).to_pylist()[0]
    entities = {NoiseClass.SIGNAL: "/events/signal", NoiseClass.BACKGROUND: "/events/noise/background",
                NoiseClass.HOT_PIXEL: "/events/noise/hot_pixel"}
    assert {e: points[e] for e in entities.values()} == {entities[c]: int(want[c]) for c in NoiseClass}
    assert {e: class_ids[e] for e in entities.values()} == {entities[c]: [int(c)] for c in NoiseClass}
    flat = context
    while isinstance(flat, list) and len(flat) == 1 and isinstance(flat[0], list):
        flat = flat[0]
    info = {d["class_id"]: d["class_description"]["info"] for d in flat}
    assert {c: info[int(c)]["label"] for c in NoiseClass} == {
        NoiseClass.SIGNAL: "signal", NoiseClass.BACKGROUND: "background activity", NoiseClass.HOT_PIXEL: "hot pixel"}
    r, g, b, _ = zip(*(info[int(c)]["color"].to_bytes(4, "big") for c in NoiseClass))  # RGBA, packed
    assert b[0] > max(r[0], g[0])  # signal: blue
    assert r[1] > g[1] > b[1]  # background activity: orange
    assert min(r[2], b[2]) > 2 * g[2]  # hot pixel: magenta


# -- the numbers a user sees, against independent reads -------------------------------------------------
def _raw_words(path, dtype):
    data = open(path, "rb").read()
    at, origin = 0, 0
    while data.startswith(b"%", at):  # header lines; our writer's '% t_origin_us N' shifts the clock
        end = data.index(b"\n", at) + 1
        line = data[at:end].decode("latin-1").split()
        if line[1:2] == ["t_origin_us"]:
            origin = int(line[2])
        at = end
    n = (len(data) - at) // np.dtype(dtype).itemsize
    return np.frombuffer(data, dtype, n, at), origin


def evt3_spec(path):
    """EVT 3.0 per Prophesee's spec, literally (t = TIME_HIGH·4096 + TIME_LOW, file order), plain Python."""
    words, origin = _raw_words(path, "<u2")
    out, y, th, tl, bx, pol, seen_high, loops = [], 0, 0, 0, 0, 0, False, 0
    for w in words.tolist():
        kind, v = w >> 12, w & 0xFFF
        if kind == 0x8:
            loops += seen_high and v < th % 4096  # the 24-bit clock looped (spec: TIME_HIGH goes back)
            th, seen_high = v + 4096 * loops, True
        elif kind == 0x6:
            tl = v
        elif kind == 0x0:
            y = v & 0x7FF
        elif not seen_high:
            continue
        elif kind == 0x2:
            out.append((th * 4096 + tl, v & 0x7FF, y, v >> 11))
        elif kind == 0x3:
            bx, pol = v & 0x7FF, v >> 11
        elif kind in (0x4, 0x5):
            for i in range(12 if kind == 0x4 else 8):
                if v >> i & 1:
                    out.append((th * 4096 + tl, bx + i, y, pol))
            bx += 12 if kind == 0x4 else 8
    a = np.array(out, np.int64).reshape(-1, 4)
    a[:, 0] += origin
    return a


def evt2_spec(path):
    """EVT 2.0 per the spec: CD_OFF 0 / CD_ON 1 words (t low 6 bits, x, y), TIME_HIGH 8 (t >> 6)."""
    w, origin = _raw_words(path, "<u4")
    w = w.astype(np.int64)
    kind = w >> 28
    high = np.where(kind == 8, (w & 0xFFFFFFF) << 6, -1)
    high = np.maximum.accumulate(high)
    cd = (kind <= 1) & (high >= 0)
    return np.column_stack((high[cd] + ((w[cd] >> 22) & 0x3F) + origin, (w[cd] >> 11) & 0x7FF, w[cd] & 0x7FF,
                            kind[cd]))


def independent(path):
    """(t, x, y, p) rows of a file read without evstream: numpy, h5py, the format specs."""
    import h5py

    name = str(path)
    if name.endswith(".h5"):
        with h5py.File(path) as f:
            return np.column_stack([f["events"][k][:].astype(np.int64) for k in "txyp"])
    if name.endswith((".npy", ".npz")):
        ev = np.load(path, allow_pickle=False)
        return np.column_stack([ev[k].astype(np.int64) for k in "txyp"])
    if name.endswith(".txt"):
        t, x, y, p = np.loadtxt(path, unpack=True)
        return np.column_stack((np.round(t * 1e6), x, y, p > 0)).astype(np.int64)
    if name.endswith((".bin", ".bs2")):
        r = np.fromfile(path, np.uint8)
        r = r[: len(r) // 5 * 5].reshape(-1, 5).astype(np.int64)
        return np.column_stack(((r[:, 2] & 0x7F) << 16 | r[:, 3] << 8 | r[:, 4], r[:, 0], r[:, 1], r[:, 2] >> 7))
    if name.endswith(".dat"):
        data = open(path, "rb").read()
        at = 0
        while data.startswith(b"%", at):
            at = data.index(b"\n", at) + 1
        ev = np.frombuffer(data, "<u4", offset=at + 2).reshape(-1, 2).astype(np.int64)  # + type, size bytes
        return np.column_stack((ev[:, 0], ev[:, 1] & 0x3FFF, ev[:, 1] >> 14 & 0x3FFF, ev[:, 1] >> 28))
    if name.endswith(".aedat4"):  # faery, the reference decoder SOURCES.md checked against four others
        import faery  # declared (dev) dependency: a broken install fails
        ev = np.concatenate(list(faery.events_stream_from_file(path)))
        return np.column_stack([ev[k].astype(np.int64) for k in ("t", "x", "y", "on")])
    head = open(path, "rb").read(4096)
    return evt3_spec(path) if b"% evt 3.0" in head else evt2_spec(path)


def _rows_sorted(a):
    return a[np.lexsort(a.T[::-1])]


INDEPENDENT = {  # file: sensor size (SOURCES.md)
    "prophesee_gen41_hd_evt3_expelliarmus.raw": (1280, 720), "prophesee_gen3_vga_evt2_faery.raw": (640, 480),
    "prophesee_gen3_vga_evt2_faery.h5": (640, 480), "dvxplorer_320x240_tonic.npy": (320, 240),
    "dvs128_lifetime_building_events.txt": (128, 128), "ncars_atis_sample.dat": (304, 240),
    "nmnist_sample.bin": (34, 34), "dvsgesture_slayer_1.bs2": (128, 128),
    "dvxplorer_320x240_tonic.aedat4": (320, 240), "davis346_frames_imu_evlib.aedat4": (346, 260),
    "ncaltech101_faces_easy_0001.bin": (304, 240),
}


@pytest.mark.parametrize("name", sorted(INDEPENDENT))
def test_info_and_every_convert_round_trip_match_an_independent_read(tmp_path, real_data, capsys, name):
    """`evstream info` (events, span, size, ON fraction, rate) and `convert` to .npz, EVT3, EVT2 and .h5
    then back to .npz: every event kept exactly, as a plain numpy / h5py / spec-literal read sees them
    (the EVT3 file's timestamps step back, so events are compared as sets; readers sort them)."""
    import json

    ref = _rows_sorted(independent(real_data / name))
    rc, out, err = run(capsys, "info", real_data / name, "--json")
    assert rc == 0, err
    info = json.loads(out)
    span = int(ref[:, 0].max() - ref[:, 0].min())
    assert (info["events"], info["duration_us"], (info["width"], info["height"])) == (len(ref), span,
                                                                                       INDEPENDENT[name])
    assert info["on_fraction"] == pytest.approx(ref[:, 3].mean(), abs=1e-12)
    assert info["rate_hz"] == pytest.approx(len(ref) / (span * 1e-6), rel=1e-9)
    for out_name, extra in (("a.npz", []), ("b.raw", []), ("c.raw", ["--evt", "2"]), ("d.h5", [])):
        first = tmp_path / out_name
        rc, _, err = run(capsys, "convert", real_data / name, first, *extra)
        assert rc == 0, err
        np.testing.assert_array_equal(_rows_sorted(independent(first)), ref, err_msg=out_name)
        if out_name != "b.raw":
            continue
        back = tmp_path / f"back_{first.stem}.npz"
        rc, _, err = run(capsys, "convert", first, back)
        assert rc == 0, err
        np.testing.assert_array_equal(_rows_sorted(independent(back)), ref, err_msg=f"{out_name} -> npz")


@pytest.mark.parametrize("seed, size, t0_us", [(1, (346, 260), 1_000), (2, (1280, 720), 5_000_000_123)])
def test_every_convert_writer_matches_an_independent_read_on_synthetic_events(tmp_path, capsys, seed, size, t0_us):
    """Without the shared recordings too: synthetic events (bursts of equal timestamps, border pixels,
    both polarities; past 2^32 µs: a '% t_origin_us' header) written by `convert` to .npz, EVT3, EVT2
    and .h5, each read back by numpy, h5py, the spec-literal EVT decoders above and faery: every event."""
    import faery  # declared (dev) dependency: a broken install fails
    from evstream.sources import native

    from evstream.events import Geometry
    from evstream.testing import random_stream

    s = random_stream(seed, 30_000, Geometry(*size), t0_us=t0_us, mean_dt_us=7)
    src = tmp_path / "synthetic.npz"
    native.save(src, s)
    ref = _rows_sorted(np.column_stack([s.t, s.x, s.y, s.p]).astype(np.int64))
    assert len(np.unique(ref[:, 0])) < len(ref) and ref[:, 1].max() == size[0] - 1  # bursts, border
    for out_name, extra in (("a.npz", []), ("b.raw", []), ("c.raw", ["--evt", "2"]), ("d.h5", [])):
        out = tmp_path / out_name
        rc, _, err = run(capsys, "convert", src, out, *extra)
        assert rc == 0, err
        np.testing.assert_array_equal(_rows_sorted(independent(out)), ref, err_msg=out_name)
        if out_name.endswith(".raw"):
            ev = np.concatenate(list(faery.events_stream_from_file(out)))
            got = np.column_stack([ev[k].astype(np.int64) for k in ("t", "x", "y", "on")])
            got[:, 0] += _raw_words(out, "<u2")[1]  # faery reads from the file's time origin
            np.testing.assert_array_equal(_rows_sorted(got), ref, err_msg=f"{out_name} by faery")


@pytest.mark.parametrize("name", ["nmnist_sample.bin", "ncars_atis_sample.dat", "dvxplorer_320x240_tonic.npy",
                                  "prophesee_gen41_hd_evt3_expelliarmus.raw"])
def test_frames_statistics_match_the_events_counted_with_numpy(real_data, capsys, name):
    """`evstream frames --denoise none`: FW frames [t0 + kΔt, t0 + (k+1)Δt) closed before the last event,
    FN frames of n events; rate = frames / recording span, population mean and variance of events per
    frame (docs/framing.md), each recomputed from an independent read."""
    import json

    t = np.sort(independent(real_data / name)[:, 0])
    span = int(t[-1] - t[0])
    window_us = max(1, span // 23)
    n_events = len(t) // 7
    rc, out, err = run(capsys, "frames", real_data / name, "--framer", "fw,fn", "--denoise", "none",
                       "--window-us", window_us, "--n-events", n_events, "--json")
    assert rc == 0, err
    fw, fn = json.loads(out)["results"]
    k = span // window_us  # frames whose end the last event's watermark reaches
    counts = np.bincount((t - t[0]) // window_us, minlength=k + 1)[:k]
    assert (fw["frames"], fw["duration_us"], fw["events_in"]) == (k, span, len(t))
    assert fw["frame_rate_hz"] == pytest.approx(k / (span * 1e-6), rel=1e-12)
    assert fw["mean_events"] == pytest.approx(counts.mean(), rel=1e-12)
    assert fw["variance_events"] == pytest.approx(counts.var(), rel=1e-9)
    assert fw["empty_frames"] == int(np.count_nonzero(counts == 0))
    assert (fn["frames"], fn["mean_events"], fn["variance_events"]) == (len(t) // n_events, n_events, 0.0)


def test_main_works_after_the_stderr_it_was_imported_under_is_closed(tmp_path, real_data):
    """The progress line took `sys.stderr` as a default argument, bound when evstream.cli was imported:
    a program that imported it under a redirected stderr (a notebook capture, a test runner) got
    'I/O operation on closed file' from every replay and frames run afterwards."""
    code = ("import contextlib, os, sys\n"
            "f = open(os.devnull, 'w')\n"
            "with contextlib.redirect_stderr(f):\n"
            "    from evstream.cli import main\n"
            "f.close()\n"
            f"sys.exit(main(['frames', {str(real_data / 'nmnist_sample.bin')!r}, '--denoise', 'none']))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "frames" in r.stdout and "closed file" not in r.stderr


# -- damage the raw formats cannot see: we read exactly what the bytes say --------------------------------
def _body_start(data: bytes) -> int:
    at = 0
    while data.startswith(b"%", at):
        at = data.index(b"\n", at) + 1
    return at


@pytest.mark.parametrize("name, word", [("prophesee_gen41_hd_evt3_expelliarmus.raw", 2),
                                        ("prophesee_gen3_vga_evt2_faery.raw", 4)])
@pytest.mark.parametrize("fraction", [0.37, 0.71])
def test_raw_cut_on_a_word_boundary_reads_as_a_shorter_recording(tmp_path, real_data, capsys, name, word,
                                                                   fraction):
    """Documented in docs/formats.md: no length, no checksum, so a cut between words is invisible; the
    events read are those a spec-literal decoder reads from the same bytes, and no warning is made up."""
    data = (real_data / name).read_bytes()
    body = _body_start(data)
    cut = body + int((len(data) - body) * fraction) // word * word
    bad = tmp_path / name
    bad.write_bytes(data[:cut])
    want = _rows_sorted(independent(bad))
    assert 0 < len(want) < len(_rows_sorted(independent(real_data / name)))
    rc, out, err = run(capsys, "convert", bad, tmp_path / "out.h5")
    assert rc == 0 and err == ""
    np.testing.assert_array_equal(_rows_sorted(independent(tmp_path / "out.h5")), want)


@pytest.mark.parametrize("fraction", [0.3, 0.52, 0.77, 0.9])
def test_evt2_flipped_word_type_is_read_as_the_bytes_say(tmp_path, real_data, capsys, fraction):
    """A flipped type nibble (an event becoming a word type we skip) loses that event without an error:
    the bytes are a valid EVT2 stream. Our events equal the spec-literal decode of the damaged bytes."""
    name = "prophesee_gen3_vga_evt2_faery.raw"
    data = bytearray((real_data / name).read_bytes())
    body = _body_start(bytes(data))
    words = np.frombuffer(bytes(data), "<u4", (len(data) - body) // 4, body)
    i = int(len(words) * fraction)
    i += int(np.argmax(words[i:] >> 28 <= 1))  # the next CD event word
    data[body + 4 * i + 3] ^= 0xA0  # type 0/1 -> 0xA/0xB (EXT_TRIGGER / unknown): not an event any more
    bad = tmp_path / name
    bad.write_bytes(bytes(data))
    want = _rows_sorted(independent(bad))
    assert len(want) == 521_251
    rc, out, err = run(capsys, "convert", bad, tmp_path / "out.h5")
    assert rc == 0, err
    np.testing.assert_array_equal(_rows_sorted(independent(tmp_path / "out.h5")), want)


# -- .npy shorter than its header says -----------------------------------------------------------------
@pytest.mark.parametrize("fraction", [0.0002, 0.33, 0.9999])
def test_npy_cut_short_warns_naming_the_byte_and_keeps_the_whole_rows(tmp_path, real_data, capsys, fraction):
    """It was 'unreadable NumPy file: ValueError: mmap length is greater than file size' (exit 1, no
    byte, no 'truncated'); now it reads like the other formats' cut tails: the whole rows, a warning."""
    name = "dvxplorer_320x240_tonic.npy"
    data = (real_data / name).read_bytes()
    full = np.load(real_data / name)
    start = len(data) - full.nbytes
    cut = max(start + 7, int(len(data) * fraction))
    bad = tmp_path / name
    bad.write_bytes(data[:cut])
    rows = (cut - start) // full.dtype.itemsize
    rc, out, err = run(capsys, "convert", bad, tmp_path / "out.h5")
    assert rc == 0, err
    line = one_line_error(err)
    assert line == (f"evstream: warning: {bad}: truncated: the header promises {len(full):,} rows ({len(data)} "
                    f"bytes) but the file ends at byte {cut}; kept: the {rows:,} whole rows before byte "
                    f"{start + rows * full.dtype.itemsize}")
    got = independent(tmp_path / "out.h5")
    np.testing.assert_array_equal(got, np.column_stack([full[k][:rows].astype(np.int64) for k in "txyp"]))


def test_npy_table_of_four_columns_cut_short_keeps_its_whole_rows(tmp_path, capsys):
    t = np.arange(1000, dtype=np.float64) * 1e-4
    table = np.column_stack((t, np.arange(1000) % 30, np.arange(1000) % 20, np.arange(1000) % 2))
    path = tmp_path / "table.npy"
    np.save(path, table)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 5])  # the last row loses 5 of its 32 bytes
    rc, out, err = run(capsys, "info", path, "--json")
    assert rc == 0 and "truncated" in one_line_error(err) and "999 whole rows" in err
    assert json_loads(out)["events"] == 999


def json_loads(text):
    import json

    return json.loads(text)


# -- convert: a failure leaves no half recording ----------------------------------------------------------
@pytest.mark.parametrize("evt", ["3", "2"])
def test_convert_to_raw_that_fails_midway_leaves_no_valid_looking_half_file(tmp_path, real_data, capsys, evt):
    """`convert` streams RAW output; when the input turned out bad at event 401,328 it left OUT.raw with
    the 401,328 events before — a well-formed EVT file nothing marks as partial — and had already
    destroyed an older OUT.raw. Now the output appears only whole; an older one stays."""
    name = "prophesee_gen3_vga_evt2_faery.raw"
    data = bytearray((real_data / name).read_bytes())
    data[int(len(data) * 0.77)] ^= 0xFF  # a coordinate outside the sensor, three quarters in
    bad = tmp_path / name
    bad.write_bytes(bytes(data))
    out = tmp_path / "out.raw"
    out.write_bytes(b"an older recording")
    rc, _, err = run(capsys, "convert", bad, out, "--evt", evt)
    assert rc == 1 and "outside the 640x480 sensor" in one_line_error(err)
    assert out.read_bytes() == b"an older recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, "out.raw"])


@pytest.mark.parametrize("cut", [15, 17, 300, 2000])
def test_aedat4_cut_in_its_header_says_truncated(tmp_path, real_data, cut):
    """It said 'unreadable AEDAT4 file: failed to fill whole buffer' (the Rust reader's words)."""
    bad = tmp_path / AEDAT4
    bad.write_bytes((real_data / AEDAT4).read_bytes()[:cut])
    rc, _, err = cli("info", bad)
    assert rc == 1
    line = one_line_error(err)
    size = " of 3,104 bytes" if cut >= 18 else ""
    assert line == f"evstream: error: {bad}: truncated in its header{size}: the file ends at byte {cut}"


@pytest.mark.parametrize("fraction", [0.0003, 0.5, 0.999999])
def test_hdf5_cut_short_says_truncated_and_where(tmp_path, real_data, capsys, fraction):
    """It said 'unreadable HDF5 file: OSError: Unable to synchronously open file (truncated file: eof =
    301, sblock->base_addr = 0, stored_eof = 1149045)'."""
    data = (real_data / H5).read_bytes()
    cut = int(len(data) * fraction)
    bad = tmp_path / H5
    bad.write_bytes(data[:cut])
    rc, _, err = run(capsys, "info", bad)
    assert rc == 1
    assert one_line_error(err) == (f"evstream: error: {bad}: truncated: the file ends at byte {cut}, its superblock "
                             f"says it is {len(data):,} bytes long")


# -- not a recording at all ------------------------------------------------------------------------------
@pytest.mark.parametrize("command, after", [("info", []), ("frames", []), ("replay", ["--save", "x.rrd"]),
                                            ("convert", ["x.npz"])])
@pytest.mark.parametrize("what", ["directory", "empty", "wrong extension"])
def test_a_directory_an_empty_file_or_a_renamed_binary_is_one_line(tmp_path, real_data, capsys, command, after,
                                                                   what):
    if what == "directory":
        path, says = tmp_path / "rec.raw", "is a directory, not a recording"
        path.mkdir()
    elif what == "empty":
        path, says = tmp_path / "rec.aedat4", "empty file"
        path.write_bytes(b"")
    else:  # an N-MNIST binary renamed: it has no magic, so only its extension says what it is
        path, says = tmp_path / "rec.txt", "unrecognised format"
        path.write_bytes((real_data / "nmnist_sample.bin").read_bytes())
    rc, _, err = run(capsys, command, path, *(tmp_path / a if "." in a else a for a in after))
    assert rc == 1
    assert one_line_error(err).startswith(f"evstream: error: {path}: {says}")


@pytest.mark.parametrize("fraction", [0.4, 0.52, 0.85])
def test_aedat4_packet_that_fails_to_decompress_is_named_by_its_byte(tmp_path, real_data, fraction):
    """It said 'AEDAT4 decoding failed after 54 packets: LZ4 error: ...' with no byte."""
    name = "dvxplorer_320x240_tonic.aedat4"
    data = bytearray((real_data / name).read_bytes())
    packets = aedat4_packets(bytes(data))
    k = int(len(packets) * fraction)
    flip = packets[k] + 8 + 40  # inside the packet's compressed body (its LZ4 frame)
    data[flip] ^= 0xFF
    bad = tmp_path / name
    bad.write_bytes(bytes(data))
    rc, out, err = cli("info", bad)
    assert rc == 1
    assert one_line_error(err).startswith(f"evstream: error: {bad} at byte {packets[k]}: AEDAT4 decoding failed at "
                                    f"packet {k}: ")


@pytest.mark.parametrize("k", [8, 49_998, 49_999, 65_535, 86_201, 111_952])  # around chunk and block edges
def test_npy_value_error_names_its_events_byte(tmp_path, real_data, capsys, k):
    """A structured .npy holds one event per 13-byte row after its header: an event's byte is known.
    It said 'event 86202: ...' with no byte, or '[in bytes 650192..1300192]' for a chunk that
    straddled two read blocks."""
    name = "dvxplorer_320x240_tonic.npy"
    data = bytearray((real_data / name).read_bytes())
    full = np.load(real_data / name)
    start = len(data) - full.nbytes
    data[start + k * full.dtype.itemsize + 6] ^= 0x80  # t is the first field (<i8): +2^55 µs on event k
    bad = tmp_path / name
    bad.write_bytes(bytes(data))
    rc, _, err = run(capsys, "info", bad)
    assert rc == 1
    line = one_line_error(err)
    assert line.startswith(f"evstream: error: {bad} at byte {start + (k + 1) * 13}: event {k + 1}: timestamp ")
    assert "in bytes" not in line
