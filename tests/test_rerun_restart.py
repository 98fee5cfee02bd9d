"""A restarted publisher (its sequence back to 0) in the live viewer: the colour table and layout stay,
and the new stream's timeline continues after the previous one's (never drawn over it). Read back from
the .rrd that `subscribe --save` writes, through a real router and two real publishers (issue 23)."""

from __future__ import annotations

import numpy as np
from evstream.sinks.colours import CLASS_COLOURS
from evstream.sinks.rerun_sink import CLASS_ENTITIES, CLASS_LABELS, RerunSink
from evstream.sinks.rerun_viewer import open_output
from evstream.sources import open_source
from rerun.chunk import RrdReader
from test_rerun_sink import column_rows, read_rrd
from test_zenoh_live import BAR, TIMEOUT_S, Procs, free_port  # noqa: F401 - the fixture's helpers

from evstream.events import NoiseClass


def test_restarted_publisher_keeps_colours_and_continues_the_timeline(tmp_path):
    procs = Procs(tmp_path)
    try:
        port = free_port()
        ep = f"tcp/127.0.0.1:{port}"
        procs.router(port)
        rrd = tmp_path / "live.rrd"
        sub = procs.subscriber(port, "evstream/*/events", "--save", str(rrd), "--idle-s", "8")
        for _ in range(2):  # the same key twice: the second publisher starts again at sequence 0
            pub = procs.start("publish", str(BAR), "--key", "evstream/front/events", "--connect", ep, "--speed", "0",
                              "--wait-subscribers", "10", "--drain-s", "0")
            assert pub.wait(timeout=TIMEOUT_S) == 0, procs.stderr(pub)
        out = procs.result(sub)
    finally:
        procs.kill_all()
    cam = out["cameras"]["front"]
    assert cam["restarts"] == 1, cam
    data = read_rrd(rrd)
    # the colour table: one static AnnotationContext on /events, never logged again, with our colours
    ctx = [rb for t, rb in data["/events"] if t is None and "AnnotationContext:context" in rb.schema.names]
    assert len(ctx) == 1
    (infos,), = ctx[0].column(ctx[0].schema.names.index("AnnotationContext:context")).to_pylist()
    by_id = {row["class_id"]: row["class_description"]["info"] for row in infos}
    for c in NoiseClass:
        assert by_id[int(c)]["label"] == CLASS_LABELS[c]
        r, g, b = CLASS_COLOURS[c]
        assert by_id[int(c)]["color"] == (r << 24) | (g << 16) | (b << 8) | 0xFF
    # each class entity keeps its one static class id, so its points resolve to its colour
    for c, entity in CLASS_ENTITIES.items():
        static = [rb for t, rb in data["/" + entity] if t is None]
        assert len(static) == 1
        assert static[0].column(static[0].schema.names.index("Points3D:class_ids")).to_pylist() == [[int(c)]]
    # one layout for the whole recording
    assert len(RrdReader(rrd).blueprints()) >= 1
    # two streams one after the other: the second's points all come after the first's last one
    bar = open_source(str(BAR))
    duration_us = bar.duration_us if hasattr(bar, "duration_us") else None
    times, rows = column_rows(data["/events/signal"], "Points3D:positions")
    n = np.array([len(r) for r in rows])
    order = np.argsort(times)
    times, n = times[order], n[order]
    gaps = np.diff(times)
    cut = int(np.argmax(gaps)) + 1  # the restart: the largest step of the timeline
    assert gaps[cut - 1] >= 100_000_000  # at least one slab (100 ms) between the streams
    assert n[:cut].sum() > 0 and n[cut:].sum() > 0  # both streams drawn (the ring may drop packets)
    if duration_us is not None:
        assert times[cut] >= duration_us * 1000


def test_sink_restart_continues_time_after_the_previous_stream(tmp_path):
    from test_rerun_sink import G, classified

    ev = classified(5_000, seed=7)
    out = open_output(save=str(tmp_path / "r.rrd"))
    sink = RerunSink(out.rec, geometry=G)
    from evstream.pipeline import Pipeline

    Pipeline([]).run([ev], [sink])
    first_end_us = int(ev.t[-1] - ev.t[0])
    sink.restart()
    Pipeline([]).run([ev], [sink])
    out.finish()
    times, _ = column_rows(read_rrd(tmp_path / "r.rrd")["/stats/events/rate_hz"], "Scalars:scalars")
    times = np.sort(times) // 1000
    second = times[times > first_end_us + 1]
    assert len(second) and second.min() >= first_end_us + 100_000  # one slab (100 ms) apart
    assert sink.restarts == 1
