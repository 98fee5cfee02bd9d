"""A pipeline hands its framer each chunk in pieces (`evstream.framing.bound`): however a script drives it
(`evstream.batches`, `Pipeline.run`), the frames of one batch stay within `Pipeline.frames_bytes`, and they
are the frames the framer gives the whole chunk."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from framer_cases import FRAMERS
from hypothesis import example, given
from hypothesis import strategies as st

import evstream
from evstream.events import concat
from evstream.framing.bound import frames_at_once
from evstream.pipeline import Pipeline, build
from evstream.testing import assert_frames_equal, frames_of, random_bounds, random_stream, split

ROOT = Path(__file__).resolve().parents[1]
BAR = ROOT / "recordings" / "bar.npz"



def digest(frames, h=None):
    """A running hash of frames: their times, counts of events and pixels (a representation's arrays too)."""
    h = h or hashlib.sha256()
    for f in frames:
        h.update(np.array([f.t_start, f.t_end, f.n_events], np.int64).tobytes())
        h.update(np.ascontiguousarray(f.counts).tobytes())
        data = getattr(f, "data", None)
        if data is not None:
            h.update(np.ascontiguousarray(data).tobytes())
    return h


# The child: one chunk of bar.npz (0.5 s, 174,999 events) through `evstream.batches` or `Pipeline.run` with
# 100 µs windows: 5,000 frames of 346x260 (1.8 GB) if one batch held them all. It prints the frames' count
# and hash, then its own peak resident memory (VmHWM; wait4's ru_maxrss would count the forking pytest's).
CHILD = """
import sys
import evstream
sys.path.insert(0, "tests")
from test_pipeline_bound import digest

events = evstream.read(sys.argv[1])
pipe = evstream.build_pipeline(framer=evstream.framer("fw", window_us=100))
h, n, most = digest([]), 0, 0
def seen(batch):
    global h, n, most
    digest(batch.frames, h)
    n, most = n + len(batch.frames), max(most, len(batch.frames))
if sys.argv[2] == "batches":
    for batch in evstream.batches(pipe, [events]):
        seen(batch)
else:
    class Sink:
        def write(self, batch):
            seen(batch)
        def close(self, stats):
            pass
    pipe.run([events], [Sink()])
print(n, most, h.hexdigest())
print([ln for ln in open("/proc/self/status") if ln.startswith("VmHWM")][0], file=sys.stderr)
"""


@pytest.mark.parametrize("how", ["batches", "run"])
def test_a_script_with_a_small_window_over_one_big_chunk_takes_memory_for_a_batch(how):
    """`evstream.batches(pipe, [evstream.read(path)])` with `window_us=100` held the 5,000 frames of the
    one chunk in one batch: 1.8 GB (`window_us=1` grows without bound). The commands cut their sources
    themselves; a script did not. Now the pipeline cuts for its framer: a few hundred MB, the same frames."""
    proc = subprocess.run([sys.executable, "-c", CHILD, str(BAR), how], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    n, most, got = proc.stdout.split()
    peak_mb = int(next(ln for ln in proc.stderr.splitlines() if ln.startswith("VmHWM")).split()[1]) / 1024
    events = evstream.read(BAR)
    want = digest(frames_of(build("framer", {"kind": "fw", "window_us": 100}),
                            split(events, list(range(0, len(events), 2000)) + [len(events)])))  # 10 frames at once
    assert (int(n), got) == (5000, want.hexdigest())
    framer = build("framer", {"kind": "fw", "window_us": 100})
    assert int(most) <= frames_at_once(framer, events.geometry.n_pixels) + 1  # 186 + 1 of 5,000
    assert peak_mb < 1000, f"peak memory {peak_mb:.0f} MB"


@given(seed=st.integers(0, 2**32 - 1), spec=st.sampled_from(FRAMERS), at_once=st.integers(1, 8),
       paused=st.booleans(), threads=st.booleans())
@example(seed=0, spec=FRAMERS[3], at_once=1, paused=False, threads=False)  # oa 40/10: 4 windows open at the end
@example(seed=0, spec=FRAMERS[3], at_once=1, paused=True, threads=False)  # the pause crossed in enough empty pieces
def test_the_frames_are_the_same_however_the_pipeline_cuts_the_chunks(seed, spec, at_once, paused, threads):
    """A random stream (a 30 s pause in it, or not) in random chunks through a pipeline whose batches hold
    `at_once` frames' bytes: the framer's frames of the whole stream in one chunk, the events unchanged and
    in order, each batch within 2 * at_once + 1 frames (fn with a time limit is cut by events and by time) but
    the end of the stream's, which holds every window still open (oa 40/10: 4, found by hypothesis at at_once 1)."""
    stream = random_stream(seed, 600, mean_dt_us=5)
    if paused:
        t = stream.t.copy()
        t[len(t) // 2:] += 30_000_000
        stream = stream.replace(t=t, t_end=None)
    stream = stream.with_classes(stream.label)
    want = frames_of(build("framer", spec), [stream])
    pipe = Pipeline([], build("framer", spec))
    pipe.frames_bytes = at_once * pipe.framer.frame_bytes(stream.geometry.n_pixels)
    batches = []

    class Sink:
        def write(self, batch):
            batches.append((batch.events, list(batch.frames)))

        def close(self, stats):
            pass

    chunks = split(stream, random_bounds(seed, len(stream), max_chunks=5))
    stats = pipe.run(chunks, [Sink()], threads=threads)
    assert_frames_equal([f for _, frames in batches for f in frames], want)
    assert max(len(frames) for _, frames in batches[:-1]) <= 2 * at_once + 1
    # the last batch is the end of the stream's: the windows still open, as many as overlap (oa: window / stride)
    open_windows = -(-spec["window_us"] // spec["stride_us"]) if "stride_us" in spec else 1
    assert len(batches[-1][1]) <= max(2 * at_once + 1, open_windows)
    events = concat([e for e, _ in batches], stream.geometry)
    assert np.array_equal(events.t, stream.t) and np.array_equal(events.x, stream.x)
    assert stats.chunks == len(chunks) and stats.events_in == len(stream) and stats.frames == len(want)
