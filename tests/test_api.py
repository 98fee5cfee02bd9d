"""The Python API (evstream.api, evstream.writers): what the CLI does, a script does — with the same results."""

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import evstream
from evstream.cli import main
from evstream.events import EventChunk, EventError, Geometry, NoiseClass
from evstream.testing import random_stream

G = Geometry(40, 30)
BAR = "recordings/bar.npz"

TONIC = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i1")])  # tonic's DVS dtype
FAERY = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("on", "?")])  # faery's


def as_dtype(chunk: EventChunk, dtype) -> np.ndarray:
    out = np.zeros(len(chunk), dtype)
    for name in dtype.names:
        out[name] = chunk.p if name == "on" else getattr(chunk, name)
    return out


@pytest.mark.parametrize("dtype", [TONIC, FAERY], ids=["tonic", "faery"])
def test_a_structured_array_is_classified_as_the_same_events_in_a_chunk(dtype):
    chunk = random_stream(3, 4000, G)
    want = evstream.stage("stcf", tau_us=5000)(chunk).cls
    arr = as_dtype(chunk, dtype)
    got = evstream.classify({"kind": "stcf", "tau_us": 5000}, arr, geometry=(40, 30, 2))
    assert got.dtype == np.uint8 and np.array_equal(got, want)
    kept = evstream.clean(evstream.stage("stcf", tau_us=5000), arr, geometry="40x30")
    assert kept.dtype == dtype and np.array_equal(kept["t"], chunk.t[want == NoiseClass.SIGNAL])


def test_a_stream_of_chunks_is_classified_chunk_by_chunk_as_the_whole():
    chunk = random_stream(4, 3000, G)
    whole = evstream.classify("paper", chunk)
    parts = list(evstream.classify(evstream.build_pipeline("paper"), (chunk[a:a + 700] for a in range(0, 3000, 700))))
    assert np.array_equal(np.concatenate([c.cls for c in parts]), whole)
    kept = list(evstream.clean("paper", iter([chunk[:1500], chunk[1500:]])))
    assert sum(len(c) for c in kept) == int((whole == 0).sum())


@given(seed=st.integers(0, 2**16), n=st.integers(0, 500))
def test_the_transform_is_a_fresh_stage_per_sample(seed, n):
    chunk = random_stream(seed, n, G)
    arr = as_dtype(chunk, TONIC)
    transform = evstream.Denoise(sensor_size=(40, 30, 2), kind="stcf", tau_us=3000)
    first, second = transform(arr), transform(arr)
    assert np.array_equal(first, second)  # no state carried from one sample to the next
    assert np.array_equal(first, arr[evstream.stage("stcf", tau_us=3000)(chunk).cls == 0])


def test_the_transform_refuses_a_bad_stage_when_made_not_in_a_worker():
    with pytest.raises(ValueError, match="unknown parameter 'tau'"):
        evstream.Denoise(sensor_size=(40, 30), kind="stcf", tau=3)
    assert "kind='stcf'" in repr(evstream.Denoise(sensor_size=(40, 30), kind="stcf"))


def _off_sensor(a):
    a = a.copy()
    a["x"][3] = 40  # the sensor is 40 wide
    return a


@pytest.mark.parametrize("make, message", [
    (lambda a: a[["x", "y", "t"]], "lacks field"),
    (lambda a: a.astype([("x", "<i2"), ("y", "<i2"), ("t", "<f8"), ("p", "<i1")]), "integer microseconds"),
    (lambda a: a[::-1], "goes back"),
    (_off_sensor, "outside the 40x30 sensor"),
])
def test_a_structured_array_that_cannot_work_is_one_line(make, message):
    arr = as_dtype(random_stream(5, 50, G), TONIC)
    bad = make(arr)
    with pytest.raises(EventError, match=message) as e:
        evstream.classify("stcf", bad, geometry=G)
    assert "\n" not in str(e.value)
    with pytest.raises(EventError, match="pass geometry"):
        evstream.classify("stcf", arr)


def test_the_catalogue_lists_every_registered_kind_with_units_and_defaults():
    entries = {(e["role"], e["kind"]): e for e in evstream.catalogue()}
    from evstream.pipeline import kinds
    assert {k for r, k in entries if r == "stage"} == set(kinds("stage"))
    assert {k for r, k in entries if r == "framer"} == set(kinds("framer"))
    paper = {p["name"]: p for p in entries["stage", "paper"]["parameters"]}
    assert paper["coarse.window_us"]["default"] == 20_000 and paper["coarse.window_us"]["unit"] == "µs"
    assert paper["fine.lam"]["default"] == evstream.stage("dc").lam
    fw = {p["name"]: p for p in entries["framer", "fw"]["parameters"]}
    assert fw["window_us"]["default"] == 10_000 and fw["all_events"]["unit"] == ""


def test_settings_reach_sub_stages_and_are_checked():
    spec = evstream.set_params({"kind": "paper"}, ["coarse.window_us=10000", "fine.lam=0.2", "coarse.mode=absolute"])
    stage = evstream.stage(**spec)
    assert stage.density.window_us == 10_000 and stage.timeseries.lam == 0.2 and stage.density.mode == "absolute"
    with pytest.raises(ValueError, match="has no parameter 'coarse.bogus'; its parameters: coarse.radius_px"):
        evstream.set_params({"kind": "paper"}, ["coarse.bogus=1"])
    with pytest.raises(ValueError, match="expected PARAM=VALUE"):
        evstream.set_params({"kind": "paper"}, ["coarse.window_us"])


def test_set_on_the_command_line_is_the_api_with_the_same_parameters(capsys):
    assert main(["replay", BAR, "--set", "coarse.window_us=5000", "--set", "fine.lam=0.3", "--json",
                 "--save", "out/test_api/set.rrd"]) == 0
    got = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    classes = evstream.classify(evstream.stage("paper", coarse={"window_us": 5000}, fine={"lam": 0.3}),
                                evstream.read(BAR))
    default = evstream.classify("paper", evstream.read(BAR))
    assert got["events_signal"] == int((classes == 0).sum()) != int((default == 0).sum())
    assert main(["replay", BAR, "--set", "coarse.window_us=-1", "--save", "out/test_api/set.rrd"]) == 2
    assert "--set coarse.window_us=-1: window_us must be" in capsys.readouterr().err
    assert main(["replay", BAR, "--pipeline", "x.toml", "--set", "a=1", "--save", "out/test_api/set.rrd"]) == 2


def test_evstream_stages_prints_the_catalogue(capsys):
    assert main(["stages", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(evstream.catalogue(), default=str))
    assert main(["stages", "framer"]) == 0
    out = capsys.readouterr().out
    assert "window_us = 10000 µs" in out and "  paper " not in out and "stages (" not in out


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".raw"])
def test_a_file_sink_written_from_a_loop_holds_the_kept_events(tmp_path, suffix):
    source = evstream.open(BAR)
    pipe = evstream.build_pipeline("paper")
    with evstream.open_sink(tmp_path / f"clean{suffix}") as sink:
        for batch in evstream.batches(pipe, source):
            sink.write(batch)
    kept = evstream.clean("paper", evstream.read(BAR))
    back = evstream.read(tmp_path / f"clean{suffix}")
    assert back.geometry == source.geometry and len(back) == len(kept) == pipe.stats.per_class[0]
    assert np.array_equal(back.t, kept.t) and np.array_equal(back.x, kept.x) and np.array_equal(back.p, kept.p)
    assert [p.name for p in tmp_path.iterdir()] == [f"clean{suffix}"]  # no .part left


@pytest.mark.parametrize("suffix", [".npz", ".raw"])
def test_a_loop_that_fails_leaves_the_old_file(tmp_path, suffix):
    out = tmp_path / f"a{suffix}"
    out.write_bytes(b"old")
    with pytest.raises(RuntimeError), evstream.open_sink(out, geometry=G) as sink:
        sink.write(random_stream(1, 100, G))
        raise RuntimeError("the loop failed")
    assert out.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == [out.name]


@pytest.mark.parametrize("suffix", [".npz", ".raw", ".mcap"])
def test_an_open_sink_is_a_sink_of_pipeline_run(tmp_path, suffix):
    """`pipe.run(source, [evstream.open_sink(OUT)])` was a TypeError (Pipeline.run closes its sinks with the
    run's statistics; SinkWriter.close took none). Now it writes what the loop writes; a run that fails
    (Pipeline.run calls `fail`) leaves the old file and no temporary."""
    out = tmp_path / f"a{suffix}"
    stats = evstream.build_pipeline("paper").run(evstream.open(BAR), [evstream.open_sink(out)])
    back, kept = evstream.read(out), evstream.clean("paper", evstream.read(BAR))
    assert len(back) == len(kept) == stats.per_class[0] and np.array_equal(back.t, kept.t)

    def failing():
        yield from evstream.open(BAR, end_us=100_000)
        raise RuntimeError("the source failed")

    before = out.read_bytes()
    with pytest.raises(RuntimeError, match="the source failed"):
        evstream.build_pipeline("paper").run(failing(), [evstream.open_sink(out, source=evstream.open(BAR))])
    assert out.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == [out.name]


def test_mcap_and_rrd_sinks_from_a_loop(tmp_path):
    source = evstream.open(BAR)
    with evstream.open_sink(tmp_path / "a.mcap", geometry=source.geometry) as mcap, \
            evstream.open_sink(tmp_path / "a.rrd", geometry=source.geometry) as rrd:
        for chunk in evstream.clean("paper", source):
            mcap.write(chunk)
            rrd.write(chunk)
    back = evstream.read(tmp_path / "a.mcap")
    assert len(back) == len(evstream.clean("paper", evstream.read(BAR))) == rrd.stats.per_class[0]
    assert (tmp_path / "a.rrd").stat().st_size > 1000
    with pytest.raises(ValueError, match="no sink for that name"):
        evstream.open_sink(tmp_path / "a.txt")


def test_convert_is_the_command(tmp_path, capsys):
    summary = evstream.convert(BAR, tmp_path / "a.raw", evt=2)
    assert main(["convert", BAR, str(tmp_path / "b.raw"), "--evt", "2", "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    keys = ("source", "format", "events", "width", "height")
    assert [cli[k] for k in keys] == [summary[k] for k in keys]
    assert (tmp_path / "a.raw").read_bytes() == (tmp_path / "b.raw").read_bytes()
    with pytest.raises(ValueError, match="input"):
        evstream.convert(tmp_path / "a.raw", tmp_path / "a.raw")
    assert evstream.info(tmp_path / "a.raw")["events"] == summary["events"] == len(evstream.read(BAR))


def test_open_keeps_a_time_range():
    whole = evstream.read(BAR)
    part = evstream.read(BAR, start_us=100_000, end_us=200_000)
    want = whole[(whole.t >= 100_000) & (whole.t < 200_000)]
    assert len(part) == len(want) > 0 and np.array_equal(part.t, want.t) and np.array_equal(part.x, want.x)
    assert evstream.info(BAR, end_us=50_000)["events"] == int((whole.t < 50_000).sum())


def test_open_cuts_the_chunks_it_is_asked_for():
    whole = evstream.read(BAR)
    sizes = [len(c) for c in evstream.open(BAR, chunk_events=7_000)]
    assert sum(sizes) == len(whole) and set(sizes[:-1]) == {7_000} and 0 < sizes[-1] <= 7_000


@pytest.mark.parametrize("given", [2.5, True, 0, -3, "100"])
def test_open_refuses_a_chunk_size_that_is_not_a_whole_number_of_events(given):
    """`chunk_events=2.5` read 2-event chunks and `True` 1-event ones (int() of what was given), without a word."""
    with pytest.raises(ValueError, match=r"chunk_events=.*: a whole number of events, at least 1"):
        evstream.open(BAR, chunk_events=given)
    assert [len(c) for c in evstream.open(BAR, chunk_events=np.int64(50_000))][0] == 50_000


def test_open_sink_refuses_the_recording_a_script_reads(tmp_path):
    """`src = evstream.open(A)` then `open_sink(A)` (or a link to A) wrote over the recording being read."""
    import gc
    import os
    import shutil

    from evstream.safe_write import OutputIsInput

    rec = tmp_path / "rec.npz"
    shutil.copy(BAR, rec)
    os.link(rec, tmp_path / "link.npz")
    before = rec.read_bytes()
    source = evstream.open(rec, start_us=0, end_us=100_000)
    for out in (rec, tmp_path / "link.npz"):
        with pytest.raises(OutputIsInput, match="that is the input recording"):
            evstream.open_sink(out, geometry=source.geometry)
    del source
    gc.collect()  # a source that is gone is not read any more: its file may be written
    other = tmp_path / "other.npz"
    shutil.copy(BAR, other)
    with pytest.raises(OutputIsInput):  # what the script says it reads, opened or not
        evstream.open_sink(other, geometry=G, inputs=[other])
    with pytest.raises(OutputIsInput):
        evstream.open_sink(rec, source=evstream.read(other) and evstream.open(rec))
    with evstream.open_sink(rec, source=evstream.open(other)) as sink:  # source= gives the geometry
        sink.write(evstream.read(other))
    assert rec.read_bytes() != before and len(evstream.read(rec)) == len(evstream.read(BAR))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.npz", "other.npz", "rec.npz"]


@pytest.mark.parametrize("suffix", [".npz", ".raw", ".h5", ".mcap", ".rrd"])
def test_a_sink_never_closed_leaves_no_temporary_and_says_so(tmp_path, suffix):
    """An open_sink neither closed nor used with `with` left OUT.part behind for good."""
    import gc

    from evstream.sources import EventWarning

    out = tmp_path / f"a{suffix}"
    out.write_bytes(b"old")
    sink = evstream.open_sink(out, geometry=G)
    sink.write(random_stream(1, 1000, G))
    with pytest.warns(EventWarning, match=f"{out}: open_sink.* was never closed"):
        del sink
        gc.collect()
    assert out.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == [out.name]


def test_a_script_that_ends_without_closing_its_sink_leaves_no_temporary(tmp_path):
    import subprocess
    import sys

    out = tmp_path / "a.mcap"
    script = (f"import evstream\nsink = evstream.open_sink({str(out)!r}, geometry=(346, 260))\n"
              "sink.write(evstream.read('recordings/bar.npz'))\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                       cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 0, r.stderr
    assert f"{out}: open_sink(...) was never closed" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_convert_and_archive_refuse_a_recording_the_script_has_open(tmp_path):
    """`src = evstream.open(A)`, then `evstream.convert(B, A)` or `evstream.archive(B, A)` wrote over A."""
    import shutil

    from evstream.safe_write import OutputIsInput

    raw, mcap = tmp_path / "a.raw", tmp_path / "a.mcap"
    evstream.convert(BAR, raw)
    evstream.archive(BAR, mcap)
    before = raw.read_bytes(), mcap.read_bytes()
    sources = [evstream.open(raw), evstream.open(mcap)]
    shutil.copy(BAR, tmp_path / "b.npz")
    with pytest.raises(OutputIsInput):
        evstream.convert(tmp_path / "b.npz", raw)
    with pytest.raises(OutputIsInput):
        evstream.archive(tmp_path / "b.npz", mcap)
    assert (raw.read_bytes(), mcap.read_bytes()) == before and len(sources) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap", "a.raw", "b.npz"]


@pytest.mark.parametrize("bad", [np.float64("nan"), np.int64(-7), np.float32(-0.5)], ids=["nan", "neg-int", "neg-f32"])
def test_a_bad_value_is_said_as_a_plain_value_not_as_numpy_code(bad):
    """Every stage and framer of the catalogue, every numeric parameter given a NumPy scalar it refuses:
    the message shows the value (`got nan`), not NumPy 2's repr (`np.float64(nan)`)."""
    said = 0
    for entry in evstream.catalogue():
        make = evstream.stage if entry["role"] == "stage" else evstream.framer
        for param in entry["parameters"]:
            if param["type"] not in ("int", "float"):
                continue
            try:
                make(entry["kind"], **{param["name"]: bad})
            except (ValueError, TypeError, evstream.EventError) as e:
                text = str(e)
                assert "np." not in text and "numpy" not in text, (entry["kind"], param["name"], text)
                said += "got " in text
    assert said >= 10  # the check ran on messages that show the value


def test_what_is_not_events_is_one_type_error_saying_what_was_given():
    """`clean("stcf", [1, 2, 3])` gave a generator whose first item raised `object of type 'int' has no
    len()` from inside the stage; `clean("stcf", 5)` failed only when iterated."""
    chunk, later = evstream.read(BAR, end_us=10_000), evstream.read(BAR, start_us=10_000, end_us=20_000)
    for fn in (evstream.classify, evstream.clean):
        with pytest.raises(TypeError, match=rf"^{fn.__name__}: events is a int; give an EventChunk, a structured "
                                            r"array or a stream \(iterable\) of EventChunks$"):
            fn("stcf", 5)
        with pytest.raises(TypeError, match=rf"^{fn.__name__}: item 1 of the stream is a list, not an EventChunk"):
            list(fn("stcf", [chunk, [1, 2, 3]]))
        assert 0 < sum(map(len, fn("stcf", [chunk, later]))) <= len(chunk) + len(later)  # a list of chunks: a stream


def test_a_stream_whose_time_goes_back_between_chunks_is_an_event_error():
    """docs/api.md: time going back is an EventError; each chunk was checked alone, so the same chunk twice
    (or chunks out of order) went through a stage without a word."""
    early, late = evstream.read(BAR, end_us=10_000), evstream.read(BAR, start_us=10_000, end_us=20_000)
    for fn in (evstream.classify, evstream.clean):
        with pytest.raises(evstream.EventError, match=rf"^{fn.__name__}: item 2 of the stream starts at "
                                                       rf"t={early.t[0]} µs, before the last event of item 1 "
                                                       rf"\(t={late.t[-1]} µs\): time goes back$"):
            list(fn("stcf", [early, late, early]))
        assert len(list(fn("stcf", [early, early[:0], late]))) == 3  # an empty chunk between: in order


@pytest.mark.parametrize("what", ["downsample", {"kind": "crop", "x0": 5, "y0": 3, "width": 20, "height": 10},
                                  "flip", ["stcf", "keep_signal"], [{"kind": "rotate", "degrees": 90}, "stcf"]],
                         ids=["downsample", "crop", "flip", "keep_signal", "rotate+stcf"])
@pytest.mark.parametrize("dtype", [TONIC, FAERY], ids=["tonic", "faery"])
def test_a_transform_on_a_structured_array_gives_the_events_it_keeps_where_it_puts_them(what, dtype):
    """`clean("downsample", arr)` gave the array untouched (x up to 345 on a 173-wide output), and a stage
    that drops events (crop, keep_signal) an IndexError from numpy's boolean index: the kept events' classes
    were laid over the input's rows. Now the array holds what the chunk form gives, in the array's dtype."""
    chunk = random_stream(5, 3000, G)
    arr = as_dtype(chunk, dtype)
    if dtype is TONIC:
        arr["p"] = np.where(chunk.p > 0, 1, -1)  # tonic's -1/+1 comes back as -1/+1
    want = evstream.clean(evstream.build_pipeline(*(what if isinstance(what, list) else [what])), chunk)
    got = evstream.clean(what, arr, geometry=(40, 30))
    assert got.dtype == dtype and len(got) == len(want) > 0
    for name in dtype.names:
        assert np.array_equal(got[name], want.t if name == "t" else want.p if name == "on" else
                              np.where(want.p > 0, 1, -1) if name == "p" else getattr(want, name)), name
    kept = evstream.Denoise(sensor_size=(40, 30, 2), kind="downsample")(arr)  # a tonic-style Downsample
    assert len(kept) == len(arr) and kept["x"].max() == chunk.x.max() // 2


@pytest.mark.parametrize("form", ["chunk", "array"])
def test_classify_refuses_a_stage_that_drops_events_instead_of_giving_fewer_classes(form):
    """`classify("crop", chunk)` gave 231 classes for 111,954 events: not one per event given."""
    chunk = random_stream(6, 2000, G)
    events = chunk if form == "chunk" else as_dtype(chunk, TONIC)
    for what in ({"kind": "crop", "width": 20, "height": 10}, ["stcf", "keep_signal"]):
        with pytest.raises(ValueError, match=r"^classify: (crop|keep_signal) drops events: there is no class for "
                                             r"every event given; clean\(\) gives the events kept"):
            evstream.classify(what, events, geometry=(40, 30))
    assert len(evstream.classify("flip", events, geometry=(40, 30))) == len(chunk)  # moves, keeps every event
    streamed = list(evstream.classify({"kind": "crop", "width": 20, "height": 10}, [chunk]))  # a stream: chunks
    assert streamed[0].geometry == Geometry(20, 10)


def test_a_built_stage_given_the_recording_again_is_an_event_error():
    """A notebook cell looping `clean(stage, chunk)` over a recording, run a second time with the same stage,
    kept 163,082 events of ball.npz instead of 190,691: the stage's state from the end of the recording
    classed its start. Each call was checked alone; now the stage's time order holds across calls."""
    stage, pipe = evstream.stage("paper"), evstream.build_pipeline("stcf")
    for chunk in evstream.open(BAR, end_us=50_000):
        evstream.clean(stage, chunk)
        evstream.classify(pipe, chunk)
    last = int(evstream.read(BAR, end_us=50_000).t[-1])
    again = evstream.read(BAR, end_us=10_000)
    says = (rf"^{{}}: the events start at t={again.t[0]} µs, before the last event this stage was given "
            rf"\(t={last} µs\): time goes back; for another pass build a fresh stage \(evstream.stage\) "
            r"or pass its name$")
    with pytest.raises(evstream.EventError, match=says.format("clean")):
        evstream.clean(stage, again)
    with pytest.raises(evstream.EventError, match=says.format("classify")):
        evstream.classify(pipe, again.to_structured(), geometry=again.geometry)
    with pytest.raises(evstream.EventError, match=says.format("clean")):
        list(evstream.clean(stage, evstream.open(BAR)))
    later = evstream.read(BAR, start_us=50_000, end_us=60_000)
    assert len(evstream.classify(stage, later)) == len(later)  # the recording goes on: in order
    assert len(evstream.clean("paper", again)) > 0 and len(evstream.clean(evstream.stage("paper"), again)) > 0


@pytest.mark.parametrize("fn", [evstream.classify, evstream.clean])
def test_a_pipeline_that_batches_ran_since_starts_afresh_for_classify_and_clean(fn):
    """`classify(pipe, events)`, then `batches(pipe, source)` (a whole stream, from the pipeline as built), then
    `classify(pipe, events)` again was refused: "time goes back", against the first call's last event, though
    the pipeline had started and ended a stream since. The stream in progress is the pipeline's own: one
    `batches` ended starts afresh (what a new pipeline gives); one left early is still going on."""
    events = evstream.read(BAR, end_us=50_000)

    def result(out):
        return out if fn is evstream.classify else out.t

    pipe = evstream.build_pipeline("paper")
    first = result(fn(pipe, events)).copy()
    assert np.array_equal(first, result(fn(evstream.build_pipeline("paper"), events)))
    list(evstream.batches(pipe, evstream.open(BAR)))
    assert np.array_equal(result(fn(pipe, events)), first)  # as a new pipeline
    for _ in zip(range(1), evstream.batches(pipe, evstream.open(BAR, start_us=20_000))):  # a loop left early
        pass
    with pytest.raises(evstream.EventError, match=rf"^{fn.__name__}: the events start at t={events.t[0]} µs, before "
                                                  r"the last event this stage was given \(t=\d+ µs\): time goes back"):
        fn(pipe, events)


@pytest.mark.parametrize("kind, params", [("voxel", {"bins": 3, "window_us": 20_000}),
                                          ("timesurface", {"tau_us": 5_000, "window": "fn", "n_events": 700}),
                                          ("histogram", {"window_us": 15_000})])
def test_represent_is_a_tonic_style_transform_to_arrays(kind, params):
    """A tonic user handing a sample's structured array to a framer got "'numpy.ndarray' object has no
    attribute 'geometry'"; `Represent` is the Denoise of the representations: array in, (windows, C, H, W)
    float32 out, every window the framer gives for the sample, a fresh framer per call."""
    chunk = random_stream(7, 5000, G)
    framer = evstream.framer(kind, **params)
    want = [r.data for r in [*framer.push(chunk), *framer.finish()]]
    to_array = evstream.Represent(sensor_size=(40, 30, 2), kind=kind, **params)
    for sample in (as_dtype(chunk, TONIC), as_dtype(chunk, FAERY), chunk):
        got = to_array(sample)
        assert got.dtype == np.float32 and got.flags.c_contiguous and got.shape[0] == len(want) > 1
        assert np.array_equal(got, np.stack(want))  # the same for each call: no state carried between samples
    assert to_array(as_dtype(chunk[:0], TONIC)).shape == (0, *want[0].shape)  # no event, no window
    with pytest.raises(ValueError, match=r"^Represent: 'fw' makes frames to look at, not arrays; the "
                                         r"representations: .*voxel.*\(window='fw' chooses the window\)$"):
        evstream.Represent(sensor_size=(40, 30), kind="fw")
    with pytest.raises(ValueError, match="^voxel: bins must be"):
        evstream.Represent(sensor_size=(40, 30), kind="voxel", bins=0)  # when made, not in a DataLoader worker


def _stream_result(pipe, rec, stop_after=None):
    """Classes, frames and statistics of one `batches` run of `pipe` over `rec` (cut after `stop_after` batches)."""
    classes, frames = [], []
    for i, batch in enumerate(evstream.batches(pipe, evstream.open(rec))):
        if stop_after is not None and i == stop_after:
            break
        classes.append(batch.events.classes().copy() if len(batch.events) else np.zeros(0, np.uint8))
        frames += [(f.t_start, f.t_end, f.n_events, f.image.copy()) for f in batch.frames]
    return np.concatenate(classes), frames, pipe.stats.as_dict() | {"wall_s": 0, "throughput_hz": 0}, pipe.reports()


def _same(got, want) -> bool:
    (c1, f1, s1, r1), (c2, f2, s2, r2) = got, want
    return (np.array_equal(c1, c2) and s1 == s2 and r1 == r2 and len(f1) == len(f2)
            and all(a[:3] == b[:3] and np.array_equal(a[3], b[3]) for a, b in zip(f1, f2)))


@pytest.mark.parametrize("stages", [("paper",), ("stcf", {"kind": "rate_limit", "rate_hz": 50_000})])
def test_a_pipeline_given_another_stream_gives_what_a_new_pipeline_gives(stages):
    """The same pipeline object over a second recording (or the first again: a notebook cell run twice)
    carried the first stream's state into the second: bar.npz after ball.npz was classed with ball's state
    and its stats said 447,748 events in (both added up). Each `batches` is one stream, from the pipeline
    as built: both streams, the first again and a run after one left early give what new pipelines give."""
    def fresh():
        return evstream.build_pipeline(*stages, framer="fw")

    pipe = fresh()
    first = _stream_result(pipe, "recordings/ball.npz")
    second = _stream_result(pipe, BAR)
    again = _stream_result(pipe, "recordings/ball.npz")
    assert _same(first, _stream_result(fresh(), "recordings/ball.npz"))
    assert _same(second, _stream_result(fresh(), BAR))
    assert _same(again, first)
    _stream_result(pipe, BAR, stop_after=3)  # a loop left early (an error, a break), then run again
    assert _same(_stream_result(pipe, BAR), second)


def test_pipeline_process_after_finish_and_run_start_a_new_stream(tmp_path):
    chunks = list(evstream.open(BAR))
    pipe = evstream.build_pipeline("paper", framer="fw")
    want = [pipe.process(c).events.classes().copy() for c in chunks]
    pipe.finish(chunks[0].geometry)
    assert all(np.array_equal(pipe.process(c).events.classes(), w) for c, w in zip(chunks, want))  # a new stream
    assert pipe.stats.events_in == sum(len(c) for c in chunks)
    stats = [pipe.run(evstream.open(BAR)).as_dict()["events_signal"] for _ in range(2)]
    assert stats == [int(sum((w == 0).sum() for w in want))] * 2


def test_a_pipeline_whose_stage_cannot_be_copied_refuses_a_second_stream_in_one_line():
    import threading

    class Locked:  # a stage of the user's own holding a lock: no copy of it as built
        def __init__(self):
            self.lock = threading.Lock()

        def __call__(self, chunk):
            return chunk

    pipe = evstream.Pipeline([Locked()])
    assert sum(len(b.events) for b in evstream.batches(pipe, evstream.open(BAR))) == 174_999
    with pytest.raises(ValueError, match="build a new pipeline for each stream"):
        list(evstream.batches(pipe, evstream.open(BAR)))


def test_represent_of_a_long_recording_is_capped_or_taken_one_window_at_a_time():
    """`Represent` stacked every window of a sample in memory: a long recording asked for all of it at
    once (an hour at 346x260, 5 bins, 50 ms windows: 130 GB). The array form stops, in one line, at
    `max_bytes` (before the window past it is kept); `windows()` gives the same arrays one at a time from a
    stream, in memory bounded by one window, however many windows the stream makes."""
    import tracemalloc

    from evstream.events import concat

    g = Geometry(346, 260)
    stream = [random_stream(s, 3000, g, t0_us=s * 50_000, mean_dt_us=15) for s in range(40)]  # ~2 s, ~200 windows
    whole = concat(stream, g)
    params = {"kind": "voxel", "bins": 5, "window_us": 10_000}
    window_bytes = 4 * 5 * 260 * 346
    want = evstream.Represent(sensor_size=(346, 260), max_bytes=None, **params)(whole)
    assert len(want) > 150

    capped = evstream.Represent(sensor_size=(346, 260), max_bytes=3 * window_bytes, **params)
    with pytest.raises(ValueError, match=r"^Represent: voxel of this sample is more than 3 windows of 5x260x346 "
                                         r"float32 \(0\.01 GiB with the next, over max_bytes=5,397,600\): take "
                                         r"them one at a time with Represent\.windows\(events\), or pass "
                                         r"max_bytes=None \(or a larger cap\)$"):
        capped(whole)
    assert np.array_equal(evstream.Represent(sensor_size=(346, 260), max_bytes=len(want) * window_bytes,
                                             **params)(whole), want)  # exactly at the cap: whole
    assert evstream.Represent(sensor_size=(346, 260), **params).max_bytes == 1 << 30

    to_voxels = evstream.Represent(sensor_size=(346, 260), **params)
    tracemalloc.start()
    try:
        n, peak_windows = 0, 0
        for rep in to_voxels.windows(iter(stream)):  # a generator, as evstream.open(path) is: read as it goes
            assert np.array_equal(rep.data, want[n])
            n += 1
            peak_windows = max(peak_windows, tracemalloc.get_traced_memory()[0] / window_bytes)
        peak = tracemalloc.get_traced_memory()[1] / window_bytes
    finally:
        tracemalloc.stop()
    assert n == len(want) and peak < 20, (n, peak)  # the framer's state and a window or two (9 here), not ~200
    with pytest.raises(ValueError, match=r"^Represent: the events are on a 40x30 sensor, the transform's "
                                         r"sensor_size is 346x260$"):
        to_voxels(random_stream(1, 100, G))
    with pytest.raises(ValueError, match="max_bytes=0: a whole number of bytes"):
        evstream.Represent(sensor_size=(346, 260), max_bytes=0, **params)
