"""`evstream frames` as a user types it, at window sizes and over recordings the defaults do not reach."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from evstream.sources import native
from framer_cases import FRAMERS

from evstream.cli import main
from evstream.events import EventChunk, Geometry, concat
from evstream.framing.bound import Cutter, cut, frames_at_once
from evstream.pipeline import Pipeline, build
from evstream.testing import assert_frames_equal, frames_of, random_bounds, random_stream, split

REC = "recordings/bar.npz"
EVSTREAM = str(Path(sys.executable).parent / "evstream")


def frames_json(capsys, *argv) -> dict:
    code = main(["frames", *map(str, argv), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)["results"][0]


@pytest.mark.parametrize("window_us", [100, 300])
def test_time_surface_over_windows_that_hold_only_noise(capsys, window_us):
    """At 100 µs many windows of bar.npz hold only events the cascade classed as noise: such a window is an
    empty frame (shared read-only counts), and the time surface counted its events into them (a numba
    TypingError, 'internal error', exit 1). Its windows and counts are those of fw's."""
    surface = frames_json(capsys, REC, "--framer", "timesurface", "--window-us", window_us)
    fw = frames_json(capsys, REC, "--framer", "fw", "--window-us", window_us)
    keys = ("frames", "mean_events", "variance_events", "empty_frames", "frames_at_end", "events_signal")
    assert {k: surface[k] for k in keys} == {k: fw[k] for k in keys}


# -- frames in batches of bounded size (evstream.framing.bound) -------------------------------------------
CUT_FRAMERS = [
    *FRAMERS,
    {"kind": "fn", "n_events": 2, "max_window_us": None},  # cut by events alone
    # more empty frames in a row than the default 1,000: the pause is crossed in that many frames' steps
    {"kind": "fw", "window_us": 20, "max_empty_frames": 3000},
    {"kind": "timesurface", "window_us": 30, "max_empty_frames": 3000},
    # and fewer: the first empty pieces of a pause still close the windows that overlap its last events
    {"kind": "oa", "window_us": 100, "stride_us": 10, "max_empty_frames": 50},
]
AT_ONCE = 6  # the budget of the test: six frames


def paused_stream(seed: int, pause_us: int = 30_000_000) -> EventChunk:
    """A labelled random stream, its classes set (the noise is not counted), with a pause in the middle."""
    s = random_stream(seed, 4000, mean_dt_us=5)
    t = s.t.copy()
    t[len(t) // 2:] += pause_us
    return s.replace(t=t, t_end=None).with_classes(s.label)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("spec", CUT_FRAMERS, ids=lambda s: "-".join(map(str, s.values())))
def test_cut_hands_a_framer_the_same_frames_a_few_at_a_time(spec, seed):
    stream = paused_stream(seed)
    chunks = split(stream, random_bounds(seed, len(stream), max_chunks=4))
    whole = frames_of(build("framer", spec), chunks)
    framer = build("framer", spec)
    budget = AT_ONCE * framer.frame_bytes(stream.geometry.n_pixels)
    got, most = [], 0
    for piece in cut(chunks, framer, budget):
        out = framer.push(piece)
        most = max(most, len(out))
        got.extend(out)
    got.extend(framer.finish())
    assert_frames_equal(got, whole)
    # k frames' steps a piece: k + 1 frames at most; fn with a time limit is cut by events and by time: twice
    by_both = spec.get("window", spec["kind"]) == "fn" and spec.get("max_window_us", 1) is not None
    assert most <= (2 if by_both else 1) * AT_ONCE + 1


def test_frames_at_once_and_what_is_not_cut():
    """At least one frame a piece, however small the budget; no framer, or a framer of the user's own that
    says no step (no `frame_step`) or not all the cut needs (`frame_bytes`, `pause_step_us`), gets the chunks
    themselves."""
    framer = build("framer", {"kind": "fw", "window_us": 20})
    size = framer.frame_bytes(100)
    assert [frames_at_once(framer, 100, b) for b in (0, size - 1, size, 2 * size - 1, 3 * size)] == [1, 1, 1, 1, 3]

    class Own:  # the least a pipeline's framer needs
        def push(self, chunk):
            return []

    class Stepped(Own):  # says its step, but not its frames' size nor a pause's step
        def frame_step(self):
            return 20, None

    chunks = split(paused_stream(0), random_bounds(0, 4000, max_chunks=4))
    for framer in (None, Own(), Stepped()):
        pieces = list(cut(chunks, framer))
        assert len(pieces) == len(chunks) and all(a is b for a, b in zip(pieces, chunks))
    before = split(paused_stream(0)[:2000].replace(t_end=None), random_bounds(0, 2000, max_chunks=4))  # 10 ms
    pieces = list(cut(before, build("framer", {"kind": "fw", "window_us": 20})))
    assert len(pieces) == len(before) and all(a is b for a, b in zip(pieces, before))


def test_cut_a_chunk_from_the_last_event_before_a_pause():
    """A chunk from the last event before a pause on: its first piece is that one event, with its own time as
    the watermark (not the chunk's last event, which would close the windows of events not yet handed on)."""
    stream = paused_stream(1)
    chunks = [stream[: len(stream) // 2 - 1], stream[len(stream) // 2 - 1 :]]
    spec = {"kind": "fw", "window_us": 20}
    framer = build("framer", spec)
    got = [f for piece in cut(chunks, framer, AT_ONCE * framer.frame_bytes(stream.geometry.n_pixels))
           for f in framer.push(piece)]
    assert_frames_equal(got + framer.finish(), frames_of(build("framer", spec), chunks))


def test_cut_gives_every_chunk_at_least_one_piece():
    """Empty chunks (a source's watermark alone) are cut too: one before any event passes as it is, and so does
    one behind the watermark; one that carries a pause is crossed in steps. One-event chunks from the first."""
    stream = paused_stream(0)
    g, half = stream.geometry, len(stream) // 2

    def empty(t_end):
        return EventChunk.empty(g, t_end, with_cls=True, with_label=True)

    chunks = [empty(int(stream.t[0])), *(stream[i : i + 1] for i in range(5)),
              stream[5:half].replace(t_end=int(stream.t[half - 1])),
              empty(int(stream.t[half])), empty(int(stream.t[half]) - 1), stream[half:]]  # the pause; behind it
    whole = frames_of(build("framer", {"kind": "fw", "window_us": 20}), chunks)
    framer = build("framer", {"kind": "fw", "window_us": 20})
    cutter = Cutter(framer, AT_ONCE * framer.frame_bytes(g.n_pixels))
    got, most = [], 0
    for chunk in chunks:
        pieces = list(cutter.pieces(chunk))
        assert pieces and (len(chunk) or chunk.t_end > stream.t[0] or pieces == [chunk])
        for piece in pieces:
            out = framer.push(piece)
            most = max(most, len(out))
            got.extend(out)
    got.extend(framer.finish())
    assert_frames_equal(got, whole)
    assert sum(fr.n_events == 0 for fr in got) >= 1000 and most <= AT_ONCE + 1  # the pause: 1,000 empty frames


def test_a_pipeline_s_batches_keep_the_classes_and_labels_over_a_pause():
    """Each piece is a batch's events: the empty pieces that cross a pause have the stream's cls and label
    arrays too (empty), or joining the batches' events would drop them (`concat` keeps them where all have)."""
    stream = paused_stream(0)
    framer = build("framer", {"kind": "fw", "window_us": 20})
    pipe = Pipeline([], framer)
    pipe.frames_bytes = AT_ONCE * framer.frame_bytes(stream.geometry.n_pixels)
    chunks = split(stream, random_bounds(0, len(stream), max_chunks=4))
    events = [b.events for chunk in chunks for b in pipe.feed(chunk)]
    assert sum(not len(e) for e in events) > 100  # the pause crossed in empty pieces, then jumped
    joined = concat(events)
    assert np.array_equal(joined.cls, stream.cls) and np.array_equal(joined.label, stream.label)


PEAK = ("import sys; from evstream.cli import main; code = main(sys.argv[1:]); "
        "print([ln for ln in open('/proc/self/status') if ln.startswith('VmHWM')][0], file=sys.stderr); "
        "sys.exit(code)")


def peak_rss_mb(argv: list[str], tmp_path) -> tuple[int, float, str]:
    """Run a command in a process of its own: its exit code, its own peak resident memory (MB: VmHWM, said
    by the process itself; wait4's ru_maxrss would count the forking pytest's high-water mark), its output."""
    proc = subprocess.run([sys.executable, "-c", PEAK, *map(str, argv[1:])], capture_output=True, text=True)
    hwm = [ln for ln in proc.stderr.splitlines() if ln.startswith("VmHWM")]
    return proc.returncode, int(hwm[-1].split()[1]) / 1024 if hwm else float("inf"), proc.stdout or proc.stderr


def test_frames_of_small_windows_take_memory_for_a_batch_not_for_a_chunk(tmp_path):
    """50 µs windows over bar.npz's 50,000-event chunks were ~2,900 frames of 346x260 at once: 2.1 GB
    (`--window-us 1` was killed by the kernel at 20 GB). Cut into pieces, a few hundred MB."""
    code, mb, out = peak_rss_mb([EVSTREAM, "frames", REC, "--framer", "fw", "--window-us", "50"], tmp_path)
    assert code == 0, out
    assert "9,999" in out  # the same frames
    assert mb < 1000, f"peak memory {mb:.0f} MB"


def test_time_surfaces_over_a_pause_take_memory_for_a_batch(tmp_path):
    """A 30 s pause closes 1,000 empty windows at once (max_empty_frames), and a time surface's empty
    window has arrays of its own: 2.5 GB at 640x480 from one chunk. Crossed in steps, a few hundred MB."""
    g = Geometry(640, 480)
    rng = np.random.default_rng(0)
    n = 2000
    t = np.sort(rng.integers(0, 20_000, n))
    t[n // 2:] += 30_000_000
    rec = tmp_path / "paused.npz"
    native.save(rec, EventChunk.from_arrays(t, rng.integers(0, g.width, n), rng.integers(0, g.height, n),
                                            rng.integers(0, 2, n), g))
    code, mb, out = peak_rss_mb([EVSTREAM, "frames", rec, "--denoise", "none", "--framer", "timesurface",
                                 "--window-us", "10000", "--json"], tmp_path)
    assert code == 0, out
    assert json.loads(out)["results"][0]["frames"] > 0
    assert mb < 1000, f"peak memory {mb:.0f} MB"


def test_archive_frames_take_the_window_flags_of_the_fw_frames_they_are(tmp_path, capsys):
    """`--frames` alone writes fw frames; `--frames --window-us 5000` was refused ('--window-us does not
    apply to --framer none'), though the help says --framer picks and fw is what it picks."""
    code = main(["archive", REC, str(tmp_path / "bar.mcap"), "--frames", "--window-us", "5000"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "100 frames" in out  # 0.5 s of bar.npz in 5 ms windows (10 ms: 50)
