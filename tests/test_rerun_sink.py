"""The Rerun sink for real: write .rrd files, read them back with the rerun SDK's own reader and check
entity paths, per-class point counts and positions, the `event_time` timeline, statistics and frames."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest
from evstream.sinks.rerun_sink import CLASS_ENTITIES, TIMELINE, PointBudget, RerunSink, StatsBins, slab_depth
from evstream.sinks.rerun_viewer import open_output
from hypothesis import given
from hypothesis import strategies as st
from rerun.chunk import RrdReader

from evstream.cli import main
from evstream.events import N_CLASSES, EventChunk, Frame, Geometry, NoiseClass, concat
from evstream.pipeline import Batch, Pipeline, RunStats
from evstream.testing import random_stream

G = Geometry(64, 48)


def classified(n: int, seed: int, duration_us: int = 300_000) -> EventChunk:
    """A random stream whose `cls` holds all three classes (as a denoiser would write them)."""
    rng = np.random.default_rng(seed)
    s = random_stream(seed, n, G)
    t = np.sort(rng.integers(0, duration_us, n)).astype(np.int64) + 1_000_000  # not starting at 0
    cls = rng.choice(3, size=n, p=[0.6, 0.3, 0.1]).astype(np.uint8)
    return EventChunk.from_arrays(t, s.x, s.y, s.p, G, cls_=cls)


def split(ev: EventChunk, n_parts: int, seed: int) -> list[EventChunk]:
    cuts = np.sort(np.random.default_rng(seed).integers(0, len(ev), n_parts - 1))
    bounds = [0, *cuts.tolist(), len(ev)]
    return [ev[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def read_rrd(path) -> dict[str, list]:
    """entity path -> list of (times in ns or None for static, record batch)."""
    out = defaultdict(list)
    for chunk in RrdReader(path).stream():
        rb = chunk.to_record_batch()
        times = None if chunk.is_static else rb.column(rb.schema.names.index(TIMELINE)).cast("int64").to_numpy()
        out[chunk.entity_path].append((times, rb))
    return out


def column_rows(entries, name: str):
    """All non-static rows of one component: (times_ns, list of per-row numpy arrays)."""
    times, rows = [], []
    for t, rb in entries:
        if t is None or name not in rb.schema.names:
            continue
        col = rb.column(rb.schema.names.index(name)).to_pylist()
        times.append(t)
        rows += col
    return (np.concatenate(times) if times else np.zeros(0, np.int64)), rows


def write(path, chunks, **kwargs) -> RerunSink:
    out = open_output(save=str(path))
    sink = RerunSink(out.rec, **kwargs)
    Pipeline([]).run(chunks, [sink])
    out.finish()
    return sink


def test_rrd_round_trip_entities_counts_positions_timeline(tmp_path):
    ev = classified(20_000, seed=1)
    path = tmp_path / "a.rrd"
    sink = write(path, split(ev, 7, seed=2), point_budget_hz=None, time_bin_us=2000)
    assert sink.points_logged == len(ev) and sink.points_dropped == 0
    data = read_rrd(path)
    for entity in ["/events/signal", "/events/noise/background", "/events/noise/hot_pixel", "/events",
                   "/slab", "/stats/events/rate_hz", "/stats/noise_fraction/background"]:
        assert entity in data, f"{entity} missing; have {sorted(data)}"
    # the annotation context (static, on /events) names and colours the three classes
    ctx = [rb for t, rb in data["/events"] if t is None and "AnnotationContext:context" in rb.schema.names]
    assert len(ctx) == 1 and "hot pixel" in str(ctx[0].column(1).to_pylist())
    t0 = int(ev.t[0])
    scale = slab_depth(G) / 100_000.0  # default slab 100 ms
    for c, entity in CLASS_ENTITIES.items():
        times, rows = column_rows(data["/" + entity], "Points3D:positions")
        pos = np.array([p for row in rows for p in row], np.float64)
        want = ev[ev.cls == c]
        assert len(pos) == len(want) > 0, entity  # every event of the class, once
        # rows are stamped with the time of their last event, binned by time_bin_us
        assert times.max() == (int(want.t[-1]) - t0) * 1000
        n_bins = len(np.unique((want.t - t0) // 2000))  # one row per bin, a bin cut by a chunk edge twice
        assert n_bins <= len(times) <= n_bins + 6
        got = np.lexsort((pos[:, 1], pos[:, 0], -pos[:, 2]))
        exp_z = -(want.t - t0) * scale
        ref = np.lexsort((want.y, want.x, -exp_z))
        np.testing.assert_array_equal(pos[got, 0], want.x[ref])
        np.testing.assert_array_equal(pos[got, 1], want.y[ref])
        np.testing.assert_allclose(pos[got, 2], exp_z[ref], rtol=1e-6, atol=1e-3)
        # each class carries its class id once, statically (splatted over every point)
        static = [rb for t, rb in data["/" + entity] if t is None]
        assert static[0].column(static[0].schema.names.index("Points3D:class_ids")).to_pylist() == [[int(c)]]
    # the slab transform moves with event time: newest row's translation = its time * scale
    times, rows = column_rows(data["/events"], "Transform3D:translation")
    last = int(np.argmax(times))
    assert rows[last][0][2] == pytest.approx(times[last] / 1000 * scale, rel=1e-6)
    # a blueprint travels in the same file
    assert RrdReader(path).blueprints()



def test_one_entity_layout_holds_every_class_its_ids_and_the_slab_in_one_chunk_per_send(tmp_path):
    """`classes_apart=False` (live viewers): `events/points` carries every point with its class id and
    the slab's transform, one chunk per send; the statistics, sent less often, still cover every event."""
    from evstream.sinks.rerun_sink import POINTS_ENTITY

    ev = classified(20_000, seed=5)
    path = tmp_path / "one.rrd"
    sink = write(path, split(ev, 9, seed=6), point_budget_hz=None, time_bin_us=2000, classes_apart=False,
                 send_every_s=0.0, stats_every_s=3600.0)
    data = read_rrd(path)
    assert not any(e in data for e in ("/events/signal", "/events/noise/background", "/events/noise/hot_pixel"))
    chunks = [rb for t, rb in data["/" + POINTS_ENTITY] if t is not None]
    assert len(chunks) == 9  # a send per chunk written (send_every_s=0), one chunk each
    times, rows = column_rows(data["/" + POINTS_ENTITY], "Points3D:positions")
    _, ids = column_rows(data["/" + POINTS_ENTITY], "Points3D:class_ids")
    pos = np.array([p for row in rows for p in row], np.float64)
    cls = np.array([c for row in ids for c in row])
    assert len(pos) == len(cls) == sink.points_logged == len(ev)
    t0, scale = int(ev.t[0]), slab_depth(G) / 100_000.0
    order = np.lexsort((pos[:, 1], pos[:, 0], -pos[:, 2]))
    exp_z = -(ev.t - t0) * scale
    ref = np.lexsort((ev.y, ev.x, -exp_z))
    np.testing.assert_array_equal(pos[order, 0], ev.x[ref])
    np.testing.assert_array_equal(pos[order, 1], ev.y[ref])
    np.testing.assert_array_equal(cls[order], ev.cls[ref])  # each point keeps its own class id
    # the slab's transform is in the same rows: translation = the row's time * scale
    t_tr, tr = column_rows(data["/" + POINTS_ENTITY], "Transform3D:translation")
    np.testing.assert_array_equal(t_tr, times)
    np.testing.assert_allclose([r[0][2] for r in tr], times / 1000 * scale, rtol=1e-6)
    # statistics held back by stats_every_s go out at close: the rate still sums to every event
    t_rate, rates = column_rows(data["/stats/events/rate_hz"], "Scalars:scalars")
    assert len([rb for t, rb in data["/stats/events/rate_hz"] if t is not None]) == 1  # one send, at close
    ends_us = np.sort(t_rate) // 1000 + t0
    starts_us = t0 + (ends_us - 1 - t0) // 10_000 * 10_000
    rates = np.array([r[0] for r in rates])[np.argsort(t_rate)]
    assert np.sum(rates * (ends_us - starts_us) * 1e-6) == pytest.approx(len(ev), rel=1e-9)

def _drawn(data, entity: str, bin_us: int) -> list[tuple]:
    """Every point of `entity` as (its row's time bin, x, y, z), sorted: what the 3D view draws when."""
    times, rows = column_rows(data[entity], "Points3D:positions")
    return sorted((int(t) // (bin_us * 1000), *map(float, p)) for t, row in zip(times, rows) for p in row)


def test_how_often_the_sink_sends_cuts_rows_not_what_is_drawn(tmp_path):
    """Sent after every chunk (a file's FILE_SENDS cadence, at its finest) or once at the end: the same points
    at the same positions in the same time bins of the same entities, the same slab bins, the same statistics
    rows. (A send cuts the row of the bin it falls in into two, each stamped with its own last event.)"""
    from evstream.sinks.rerun_sink import FILE_SENDS

    assert FILE_SENDS["send_every_s"] < FILE_SENDS["stats_every_s"]
    ev = classified(20_000, seed=7)
    chunks = split(ev, 12, seed=8)
    write(tmp_path / "each.rrd", chunks, point_budget_hz=None, time_bin_us=2000, send_every_s=0.0)
    write(tmp_path / "once.rrd", chunks, point_budget_hz=None, time_bin_us=2000, send_every_s=3600.0)
    each, once = read_rrd(tmp_path / "each.rrd"), read_rrd(tmp_path / "once.rrd")
    chunks_of = [len([rb for t, rb in data["/events/signal"] if t is not None]) for data in (each, once)]
    assert chunks_of[0] > chunks_of[1] == 1
    assert sorted(each) == sorted(once)
    for entity in CLASS_ENTITIES.values():
        drawn = _drawn(each, "/" + entity, 2000)
        assert drawn == _drawn(once, "/" + entity, 2000) and len(drawn) > 0
    assert sum(len(_drawn(each, "/" + e, 2000)) for e in CLASS_ENTITIES.values()) == len(ev)
    t_each, _ = column_rows(each["/events"], "Transform3D:translation")
    t_once, _ = column_rows(once["/events"], "Transform3D:translation")
    assert set(t_each // 2_000_000) == set(t_once // 2_000_000) and t_each.max() == t_once.max()
    for entity in ("/stats/events/rate_hz", "/stats/noise_fraction/background", "/stats/noise_fraction/hot_pixel"):
        (ta, va), (tb, vb) = column_rows(each[entity], "Scalars:scalars"), column_rows(once[entity], "Scalars:scalars")
        assert sorted(zip(ta.tolist(), va)) == sorted(zip(tb.tolist(), vb)) and len(ta) > 0


def test_statistics_use_every_event_even_when_points_are_dropped(tmp_path):
    ev = classified(30_000, seed=3)
    path = tmp_path / "b.rrd"
    sink = write(path, split(ev, 5, seed=4), point_budget_hz=20_000, stats_bin_us=10_000)
    assert sink.points_dropped > 0
    assert sink.points_logged + sink.points_dropped == len(ev)
    data = read_rrd(path)
    n_drawn = sum(len(r) for e in CLASS_ENTITIES.values() for r in column_rows(data["/" + e], "Points3D:positions")[1])
    assert n_drawn == sink.points_logged
    # rate x bin span summed over bins gives back every event
    times, rows = column_rows(data["/stats/events/rate_hz"], "Scalars:scalars")
    order = np.argsort(times)
    t0 = int(ev.t[0])
    ends_us = times[order] // 1000 + t0
    starts_us = t0 + (ends_us - 1 - t0) // 10_000 * 10_000  # the last bin ends at the last event
    rates = np.array([r[0] for r in rows])[order]
    assert np.sum(rates * (ends_us - starts_us) * 1e-6) == pytest.approx(len(ev), rel=1e-9)
    # noise fraction per class matches the class counts bin by bin
    for c in (NoiseClass.BACKGROUND, NoiseClass.HOT_PIXEL):
        t_nf, nf = column_rows(data[f"/stats/noise_fraction/{c.name.lower()}"], "Scalars:scalars")
        nf = np.array([r[0] for r in nf])
        ends = t_nf // 1000 + t0
        assert len(ends) > 10
        for end, value in zip(ends, nf):
            in_bin = (ev.t >= t0 + (end - 1 - t0) // 10_000 * 10_000) & (ev.t < end)
            assert value == pytest.approx(np.mean(ev.cls[in_bin] == c)), end


def test_point_budget_is_a_rate_over_event_time():
    b = PointBudget(rate_hz=1000, burst_s=0.1)
    kept = 0
    for i in range(100):  # 1 s of events at 100 k events/s, in 10 ms chunks
        t = np.linspace(i * 10_000, i * 10_000 + 9_999, 1000).astype(np.int64)
        sel = b.select(t)
        kept += 1000 if sel is None else len(sel)
        if sel is not None:
            assert np.all(np.diff(sel) > 0) and sel[-1] < 1000
    assert kept == pytest.approx(1000 * 1.0 + 100, abs=15)  # the rate over 1 s plus the first burst
    assert b.dropped == 100_000 - kept
    assert PointBudget(None).select(np.arange(5)) is None


def _bins_reference(t: np.ndarray, cls: np.ndarray, t0: int, bin_us: int):
    """Plain Python: per-bin class counts over the whole stream; rows for nonempty bins and for the
    first and last bin of each empty run between them; the last bin left open."""
    counts: dict[int, list[int]] = {}
    for ti, ci in zip(t.tolist(), cls.tolist()):
        counts.setdefault((ti - t0) // bin_us, [0] * N_CLASSES)[ci] += 1
    keys = sorted(counts)
    rows = []
    for a, b in zip(keys[:-1], keys[1:]):
        rows.append((a, counts[a]))
        if b - a > 1:
            rows.append((a + 1, [0] * N_CLASSES))
            if b - a > 2:
                rows.append((b - 1, [0] * N_CLASSES))
    rows.append((keys[-1], counts[keys[-1]]))
    return [((k + 1) * bin_us + t0, c) for k, c in rows]


@given(st.integers(0, 10_000), st.integers(1, 40), st.integers(1, 5_000), st.booleans())
def test_stats_bins_are_chunk_invariant_and_match_reference(seed, n_parts, n, gappy):
    rng = np.random.default_rng(seed)
    gaps = rng.integers(0, 200_000 if gappy else 3_000, n)
    t = np.cumsum(gaps).astype(np.int64) + 500
    cls = rng.integers(0, 3, n).astype(np.uint8)
    ev = EventChunk.from_arrays(t, np.zeros(n), np.zeros(n), np.zeros(n), G, cls_=cls)
    bins = StatsBins(int(t[0]), 10_000)
    ends, counts = [], []
    for part in split(ev, min(n_parts, n), seed):
        e, c = bins.push(part.t, part.classes(), part.t_end)
        ends += e.tolist()
        counts += c.tolist()
    e, c = bins.flush(int(t[-1]))
    ref = _bins_reference(t, cls, int(t[0]), 10_000)
    assert [(a, b) for a, b in zip(ends, counts)] == ref[:-1]
    assert c.tolist() == [ref[-1][1]]
    assert e[0] == min(ref[-1][0], int(t[-1]) + 1)


def test_watermark_closes_a_quiet_bin():
    bins = StatsBins(0, 10_000)
    ends, counts = bins.push(np.array([100, 200], np.int64), np.array([0, 1], np.uint8), 200)
    assert len(ends) == 0  # still open
    empty = np.zeros(0, np.int64)
    ends, counts = bins.push(empty, np.zeros(0, np.uint8), 35_000)  # nothing happens until 35 ms
    assert ends.tolist() == [10_000, 20_000, 30_000] and counts[0].tolist() == [1, 1, 0]
    assert counts[1:].sum() == 0


@pytest.mark.parametrize("live", [False, True])
def test_frames_and_frame_statistics(tmp_path, live):
    """Frames as images, their statistics; a live sink sends them with its sends, one chunk per entity."""
    ev = classified(5_000, seed=5, duration_us=50_000)
    frames = []
    for i in range(5):  # 10 ms frames with known counts
        counts = np.zeros((2, G.height, G.width), np.uint16)
        counts[1, i, :5] = 1
        counts[0, 10, i] = 2
        frames.append(Frame(t_start=1_000_000 + i * 10_000, t_end=1_000_000 + (i + 1) * 10_000,
                            n_events=100 * (i + 1), counts=counts))
    path = tmp_path / "f.rrd"
    out = open_output(save=str(path))
    sink = RerunSink(out.rec, geometry=G, framer="fw", live=live, send_every_s=3600.0 if live else 0.1)
    stats = RunStats()
    sink.write(Batch(ev, frames[:2], stats))
    sink.write(Batch(EventChunk.empty(G, with_cls=True), frames[2:], stats))
    sink.close(stats)
    out.finish()
    assert sink.frames_logged == 5
    data = read_rrd(path)
    times, images = column_rows(data["/frames/fw"], "Image:buffer")
    assert len(images) == 5
    assert sorted(times // 1000) == [f.t_end - int(ev.t[0]) for f in frames]
    img = np.asarray(images[int(np.argmax(times))], np.uint8).reshape(G.height, G.width)
    assert img[4, 0] == 255 and img[10, 4] == 0 and img[0, 0] == 128  # ON white, OFF black, gray
    _, per_frame = column_rows(data["/stats/frames/events_per_frame"], "Scalars:scalars")
    assert sorted(r[0] for r in per_frame) == [100, 200, 300, 400, 500]
    _, rate = column_rows(data["/stats/frames/rate_hz"], "Scalars:scalars")
    assert [r[0] for r in rate] == pytest.approx([100.0] * 4)
    if live:  # everything waited for the one send at close: a chunk per entity
        for entity in ("/frames/fw", "/stats/frames/events_per_frame", "/stats/frames/rate_hz"):
            assert len([t for t, _ in data[entity] if t is not None]) == 1, entity


def test_cli_replay_save_json_counts_dropped_points(tmp_path, capsys):
    from evstream.sources import native

    ev = classified(40_000, seed=6, duration_us=200_000)
    src = tmp_path / "r.npz"
    native.save(src, ev.replace(label=ev.cls, cls=None))
    rrd = tmp_path / "r.rrd"
    code = main(["replay", str(src), "--save", str(rrd), "--json", "--denoise", "truth",
                 "--point-budget", "50000"])
    assert code == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["points_dropped"] > 0 and out["points_logged"] + out["points_dropped"] == 40_000
    data = read_rrd(rrd)
    drawn = sum(len(r) for e in CLASS_ENTITIES.values() for r in column_rows(data["/" + e], "Points3D:positions")[1])
    assert drawn == out["points_logged"]


def test_cli_default_without_display_writes_rrd_and_says_how_to_open(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    from evstream.sources import native

    src = tmp_path / "quiet.npz"
    native.save(src, concat([classified(2_000, seed=7)]).replace(cls=None))
    monkeypatch.chdir(tmp_path)
    assert main(["replay", str(src), "--denoise", "none"]) == 0
    text = capsys.readouterr().out
    assert (tmp_path / "out" / "quiet.rrd").is_file()
    assert "rerun out/quiet.rrd" in text and "earlier" not in text


def test_cli_default_rrd_keeps_an_earlier_one_and_says_so(tmp_path, monkeypatch, capsys):
    """Without --save (no display), replay wrote out/STEM.rrd over an earlier one without a word: a user's
    `--save out/STEM.rrd` of another pipeline was gone. The default name is the program's choice, so an
    earlier file there is kept and the new one goes to out/STEM.1.rrd, .2, ..., said in the output;
    --save names a file the user wants replaced."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    from evstream.sources import native

    src = tmp_path / "rec.npz"
    native.save(src, concat([classified(2_000, seed=7)]).replace(cls=None))
    monkeypatch.chdir(tmp_path)
    assert main(["replay", str(src), "--denoise", "stcf", "--save", "out/rec.rrd"]) == 0
    earlier = (tmp_path / "out" / "rec.rrd").read_bytes()
    capsys.readouterr()
    for n in (1, 2):
        assert main(["replay", str(src), "--denoise", "none"]) == 0
        text = capsys.readouterr().out
        assert (tmp_path / "out" / "rec.rrd").read_bytes() == earlier
        assert f"wrote out/rec.{n}.rrd" in text and f"rerun out/rec.{n}.rrd" in text
        assert "out/rec.rrd (an earlier file) is left as it was; --save out/rec.rrd would replace it" in text
        assert read_rrd(tmp_path / "out" / f"rec.{n}.rrd")
    assert main(["replay", str(src), "--denoise", "none", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (summary["rrd"], summary["kept"]) == ("out/rec.3.rrd", "out/rec.rrd")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["rec.1.rrd", "rec.2.rrd", "rec.3.rrd", "rec.rrd"]
    assert main(["replay", str(src), "--denoise", "none", "--save", "out/rec.rrd"]) == 0  # asked for: replaced
    assert (tmp_path / "out" / "rec.rrd").read_bytes() != earlier


def test_cli_two_outputs_is_a_usage_error(tmp_path, capsys):
    assert main(["replay", "whatever.npz", "--save", str(tmp_path / "x.rrd"), "--spawn"]) == 2
    assert "choose one" in capsys.readouterr().err


def test_cli_viewer_url_nothing_listens_at_is_a_clear_error(tmp_path, capsys):
    from evstream.sinks.rerun_viewer import free_port
    from evstream.sources import native

    src = tmp_path / "r.npz"
    native.save(src, random_stream(1, 100))
    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"
    assert main(["replay", str(src), "--denoise", "none", "--viewer", url]) == 1  # our check, not the SDK's retries
    assert capsys.readouterr().err.strip() == (f"evstream: error: no Rerun viewer listening at {url} "
                                               "(start one with `rerun`, or use --spawn)")
    assert main(["replay", str(src), "--connect", "http://nowhere"]) == 1
    assert "expected rerun+http://HOST:PORT/proxy" in capsys.readouterr().err
