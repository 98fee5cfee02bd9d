"""Transforms (crop, flip, rotate, transpose, downsample, polarity, time range, rate limit): each checked
against a plain-Python definition event by event, with the invariant kit and hypothesis."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evstream.events import EventChunk, Geometry, concat
from evstream.pipeline import Pipeline, build
from evstream.testing import (
    assert_bounded_state,
    assert_cameras_independent,
    assert_chunk_invariant,
    frames_of,
    random_bounds,
    random_stream,
    split,
)
from evstream.transforms.geometry import crop_kernel
from evstream.transforms.select import UNIT, token_bucket

G = Geometry(13, 9)

SPECS = [
    {"kind": "crop", "x0": 2, "y0": 1, "width": 7, "height": 5},
    {"kind": "flip", "axis": "x"},
    {"kind": "flip", "axis": "y"},
    {"kind": "rotate", "degrees": 90},
    {"kind": "rotate", "degrees": 180},
    {"kind": "rotate", "degrees": 270},
    {"kind": "transpose"},
    {"kind": "downsample", "factor": 3},
    {"kind": "polarity", "keep": "off"},
    {"kind": "time_range", "start_us": 5000, "end_us": 20_000},
    {"kind": "rate_limit", "rate_hz": 8000, "burst_events": 5},
]


def stream(seed, n=800):
    s = random_stream(seed, n, G, mean_dt_us=60)
    return s.replace(cls=s.label)


def plain(spec, s: EventChunk):
    """The transform's definition, one event at a time: (rows of (t, x, y, p, cls, label), geometry)."""
    w, h = s.geometry.width, s.geometry.height
    kind = spec["kind"]
    rows = []
    tokens, last = spec.get("burst_events", 0) * UNIT, None
    for t, x, y, p, c, lab in zip(s.t.tolist(), s.x.tolist(), s.y.tolist(), s.p.tolist(), s.cls.tolist(),
                                  s.label.tolist()):
        if kind == "crop":
            x, y = x - spec["x0"], y - spec["y0"]
            if not (0 <= x < spec["width"] and 0 <= y < spec["height"]):
                continue
        elif kind == "flip":
            x, y = (w - 1 - x, y) if spec["axis"] == "x" else (x, h - 1 - y)
        elif kind == "rotate":
            x, y = {90: (y, w - 1 - x), 180: (w - 1 - x, h - 1 - y), 270: (h - 1 - y, x)}[spec["degrees"]]
        elif kind == "transpose":
            x, y = y, x
        elif kind == "downsample":
            x, y = x // spec["factor"], y // spec["factor"]
        elif kind == "polarity" and p != {"on": 1, "off": 0}[spec["keep"]]:
            continue
        elif kind == "time_range" and not spec["start_us"] <= t < spec["end_us"]:
            continue
        elif kind == "rate_limit":
            if last is not None:
                tokens = min(spec["burst_events"] * UNIT, tokens + (t - last) * spec["rate_hz"])
            last = t
            if tokens < UNIT:
                continue
            tokens -= UNIT
        rows.append((t, x, y, p, c, lab))
    geometry = {"crop": Geometry(spec.get("width", 1), spec.get("height", 1)),
                "rotate": G if spec.get("degrees") == 180 else Geometry(h, w), "transpose": Geometry(h, w),
                "downsample": Geometry(-(-w // spec.get("factor", 1)), -(-h // spec.get("factor", 1)))}
    return rows, geometry.get(kind, s.geometry)


def outputs(stage, chunks):
    outs = [stage(c) for c in chunks]
    return concat(outs, outs[0].geometry).to_structured()


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: "-".join(str(v) for v in s.values()))
def test_matches_the_definition(spec):
    s = stream(4)
    stage = build("stage", spec)
    out = stage(s)
    rows, geometry = plain(spec, s)
    assert out.geometry == geometry == stage.out_geometry(G)
    got = list(zip(out.t.tolist(), out.x.tolist(), out.y.tolist(), out.p.tolist(), out.cls.tolist(),
                   out.label.tolist()))
    assert got == rows
    assert out.t_end == s.t_end  # the watermark stays
    assert (len(out) < len(s)) <= stage.drops_events
    assert (geometry != G) <= stage.changes_geometry


def test_rotations_turn_the_count_image_as_numpy_does():
    s = random_stream(1, 400, G)
    base = np.zeros((G.height, G.width), int)
    np.add.at(base, (s.y, s.x), 1)
    for k, deg in ((1, 90), (2, 180), (3, 270)):
        out = build("stage", {"kind": "rotate", "degrees": deg})(s)
        img = np.zeros((out.geometry.height, out.geometry.width), int)
        np.add.at(img, (out.y, out.x), 1)
        assert np.array_equal(img, np.rot90(base, k))
    out = build("stage", {"kind": "transpose"})(s)
    img = np.zeros((out.geometry.height, out.geometry.width), int)
    np.add.at(img, (out.y, out.x), 1)
    assert np.array_equal(img, base.T)


@settings(max_examples=max(1, settings().max_examples * 3 // 5))  # the invariant kit per example: 3/5
@given(st.integers(0, 2**32 - 1), st.sampled_from(range(len(SPECS))))
def test_chunk_invariant_causal_bounded(seed, which):
    spec = SPECS[which]
    s = stream(seed, 600)
    assert_chunk_invariant(lambda: build("stage", spec), s, seed, apply=outputs, splits=2, one_event=False)
    # causal: a prefix's output is the whole stream's output for the prefix's events, whatever follows
    u = s.replace(t=s.t + np.arange(len(s)))  # distinct times: an output event's time says where it came from
    m = int(np.random.default_rng(seed).integers(1, len(u)))
    whole, prefix = outputs(build("stage", spec), [u]), outputs(build("stage", spec), [u[:m]])
    assert np.array_equal(whole[whole["t"] <= u.t[m - 1]], prefix)


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: "-".join(str(v) for v in s.values()))
def test_one_event_chunks_bounded_state_independent_cameras(spec):
    s = stream(7, 300)
    assert_chunk_invariant(lambda: build("stage", spec), s, 1, apply=outputs, splits=1)
    assert_bounded_state(lambda: build("stage", spec), lambda n: stream(2, n), n=1500)
    assert_cameras_independent(lambda: build("stage", spec), [stream(k, 200) for k in range(3)], 3)


def test_rate_limit_caps_and_reports():
    s = stream(9, 3000)  # ~16 k events/s
    stage = build("stage", {"kind": "rate_limit", "rate_hz": 4000, "burst_events": 10})
    out = concat([stage(c) for c in split(s, random_bounds(1, len(s)))])
    span_s = (s.t[-1] - s.t[0]) * 1e-6
    assert len(out) <= 10 + 4000 * span_s + 1
    assert stage.passed == len(out) and stage.dropped == len(s) - len(out) > 0
    assert f"dropped {stage.dropped:,} of 3,000 events" in stage.report()
    quiet = build("stage", {"kind": "rate_limit", "rate_hz": 1e6})
    assert len(quiet(s)) == len(s) and quiet.dropped == 0


def test_a_pipeline_with_transforms_reports_geometry_and_drops():
    pipe = Pipeline.from_config({"stage": [{"kind": "crop", "x0": 1, "y0": 1, "width": 6, "height": 4},
                                           {"kind": "rotate", "degrees": 90},
                                           {"kind": "rate_limit", "rate_hz": 2000, "burst_events": 3}],
                                 "framer": {"kind": "histogram", "window_us": 5000}})
    assert pipe.out_geometry(G) == Geometry(4, 6)
    s = stream(2, 2000)
    frames = []
    stats = pipe.run(split(s, [0, 700, 2000]), on_batch=lambda b: frames.extend(b.frames))
    assert stats.events_in + stats.events_dropped == len(s) and stats.events_dropped > 0
    assert all(f.data.shape == (2, 6, 4) for f in frames)
    assert len(pipe.reports()) == 1 and "dropped" in pipe.reports()[0]


def test_bad_parameters_are_refused():
    for spec, what in (({"kind": "rotate", "degrees": 45}, "degrees"), ({"kind": "flip", "axis": "z"}, "axis"),
                       ({"kind": "downsample", "factor": 0}, "factor"), ({"kind": "polarity", "keep": 1}, "keep"),
                       ({"kind": "time_range", "start_us": 10, "end_us": 5}, "end_us"),
                       ({"kind": "rate_limit", "rate_hz": 0}, "rate_hz"),
                       ({"kind": "crop", "width": 0}, "width")):
        with pytest.raises(ValueError, match=what):
            build("stage", spec)
    with pytest.raises(ValueError, match="does not fit the 13x9 sensor"):
        build("stage", {"kind": "crop", "x0": 10, "width": 5, "height": 2})(stream(1, 10))


# -- kernels against plain Python on random input ---------------------------------------------------
@settings(max_examples=2 * settings().max_examples)  # cheap examples: twice the profile
@given(st.integers(0, 2**32 - 1), st.integers(0, 200))
def test_kernels_match_plain_python(seed, n):
    rng = np.random.default_rng(seed)
    x, y = rng.integers(0, 40, n).astype(np.uint16), rng.integers(0, 30, n).astype(np.uint16)
    x0, y0, w, h = (int(v) for v in rng.integers(0, 20, 4) + [0, 0, 1, 1])
    tt, pp = np.sort(rng.integers(0, 10**6, n)).astype(np.int64), rng.integers(0, 2, n).astype(np.uint8)
    out = (np.empty(n + 1, np.int64), np.empty(n + 1, np.uint16), np.empty(n + 1, np.uint16),
           np.empty(n + 1, np.uint8), np.empty(n + 1, np.intp))
    k = crop_kernel(tt, x, y, pp, x0, y0, w, h, *out)
    ref = [(int(tt[i]), int(x[i]) - x0, int(y[i]) - y0, int(pp[i]), i) for i in range(n)
           if x0 <= x[i] < x0 + w and y0 <= y[i] < y0 + h]
    assert list(zip(*(a[:k].tolist() for a in out))) == ref

    t = np.cumsum(rng.integers(0, 500, n)).astype(np.int64)
    rate, cap = int(rng.integers(1, 10_000)), int(rng.integers(1, 5)) * UNIT
    state, flags = np.array([cap, 0, 0], np.int64), np.empty(n, np.uint8)
    k = token_bucket(t, state, rate, cap, flags)
    tokens, ref = cap, []
    for i in range(n):
        if i:
            tokens = min(cap, tokens + (int(t[i]) - int(t[i - 1])) * rate)
        if tokens >= UNIT:
            tokens -= UNIT
            ref.append(i)
    assert np.flatnonzero(flags).tolist() == ref and k == len(ref) and state[0] == tokens


def test_frames_of_a_transformed_stream_are_those_of_the_transformed_events():
    s = stream(3, 1000)
    pipe = Pipeline([build("stage", {"kind": "downsample", "factor": 2})], build("framer", {"kind": "count"}))
    frames = []

    class Collect:
        def write(self, batch):
            frames.extend(batch.frames)

        def close(self, stats):
            pass

    pipe.run(split(s, [0, 10, 500, 1000]), [Collect()])
    direct = frames_of(build("framer", {"kind": "count"}), [build("stage", {"kind": "downsample", "factor": 2})(s)])
    assert len(frames) == len(direct) > 3
    for a, b in zip(frames, direct):
        assert a.data.shape == (1, 5, 7) and np.array_equal(a.data, b.data)


# -- a time range at the reader -------------------------------------------------------------------
class ListSource:
    """A source that cannot seek: chunks from a list, counting how many were read."""

    def __init__(self, chunks):
        self.chunks, self.geometry, self.read = chunks, chunks[0].geometry, 0

    def __iter__(self):
        for c in self.chunks:
            self.read += 1
            yield c


def test_time_range_source_filters_and_stops_reading(tmp_path):
    from evstream.sources import native, open_source

    from evstream.transforms import TimeRangeSource

    s = stream(6, 5000)
    path = tmp_path / "rec.npz"
    native.save(path, s)
    start, end = int(s.t[1234]), int(s.t[3456]) + 1
    want = s[(s.t >= start) & (s.t < end)]
    for chunk_events in (1, 333, 10_000):
        src = TimeRangeSource(native.open(path, chunk_events=chunk_events), start, end)
        assert src.geometry == G
        got = concat(list(src), G)
        assert np.array_equal(got.to_structured()[["t", "x", "y", "p"]], want.to_structured()[["t", "x", "y", "p"]])
    chunks = split(s, list(range(0, len(s), 100)) + [len(s)])
    plain = ListSource(chunks)
    src = TimeRangeSource(plain, start, end)
    out = list(src)
    assert not src.seeks and np.array_equal(concat(out).t, want.t)
    assert plain.read < len(chunks) - 10  # it stopped reading after the range
    assert out[-1].t_end == end  # no watermark past the range
    open_ended = concat(list(TimeRangeSource(open_source(path), start_us=start)), G)
    assert np.array_equal(open_ended.t, s.t[s.t >= start])
    with pytest.raises(ValueError, match="end_us"):
        TimeRangeSource(plain, 10, 10)


def test_a_reader_that_seeks_is_asked_to():
    from evstream.transforms import TimeRangeSource

    class Seeking(ListSource):
        def set_time_range(self, start_us, end_us):
            self.asked = (start_us, end_us)
            return True

    src = TimeRangeSource(Seeking([stream(1, 50)]), 100, 900)
    assert src.seeks and src.source.asked == (100, 900)


@settings(max_examples=2 * settings().max_examples)  # cheap examples: twice the profile
@given(st.integers(0, 2**32 - 1), st.integers(0, 200))
def test_compaction_kernel_matches_plain_python(seed, n):
    from evstream.transforms.base import compact

    rng = np.random.default_rng(seed)
    flags = (rng.random(n) < rng.random()).astype(np.uint8)
    t, x = np.sort(rng.integers(0, 10**6, n)), rng.integers(0, 500, n).astype(np.uint16)
    y, p = rng.integers(0, 500, n).astype(np.uint16), rng.integers(0, 2, n).astype(np.uint8)
    out = (np.empty(n + 1, np.int64), np.empty(n + 1, np.uint16), np.empty(n + 1, np.uint16),
           np.empty(n + 1, np.uint8), np.empty(n + 1, np.intp))
    k = compact(flags, t, x, y, p, *out)
    ref = [(int(t[i]), int(x[i]), int(y[i]), int(p[i]), i) for i in range(n) if flags[i]]
    assert list(zip(*(a[:k].tolist() for a in out))) == ref


def test_an_empty_time_range_is_said_in_one_line(tmp_path, capsys):
    """--start-us past the last event (or a range holding none; often a time in the wrong unit or origin)
    wrote an empty output with exit 0 and not a word: now one warning line naming the file, the range and
    the times read; a seeking reader (EVT3) that skips everything says so too. A range with events says
    nothing."""
    import warnings
    from pathlib import Path

    import evstream
    from evstream.cli import main

    rec = Path(__file__).resolve().parents[1] / "recordings" / "bar.npz"
    raw = tmp_path / "bar.raw"
    assert main(["convert", str(rec), str(raw), "--quiet"]) == 0
    for path, seeks in ((rec, False), (raw, True)):
        capsys.readouterr()
        assert main(["convert", str(path), str(tmp_path / "empty.npz"), "--start-us", "99999999", "--quiet"]) == 0
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith(f"evstream: warning: {path}: no event in the time range 99999999")
        assert evstream.info(tmp_path / "empty.npz")["events"] == 0
        with pytest.warns(UserWarning, match="no event in the time range 5 <= t < 6 µs"):
            assert len(evstream.read(path, start_us=5, end_us=6)) == 0
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            source = evstream.open(path, start_us=99999999)
            assert source.seeks is seeks and list(source) == []
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert len(evstream.read(path, start_us=100_000)) > 0
