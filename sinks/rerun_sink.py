"""Rerun sink: events as a 3D X-Y-T point cloud split by noise class, frames as images, stats as scalars.

Entities: `events/signal`, `events/noise/background`, `events/noise/hot_pixel` (Points3D with class
ids resolved by an AnnotationContext, so each class toggles in the viewer's tree), `frames` (Image),
`stats/*` (Scalars). Time: the `event_time` timeline, in event-clock µs from the first event.
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from evstream.events import NoiseClass
from evstream.pipeline import Batch, RunStats

CLASS_ENTITIES = {
    NoiseClass.SIGNAL: "events/signal",
    NoiseClass.BACKGROUND: "events/noise/background",
    NoiseClass.HOT_PIXEL: "events/noise/hot_pixel",
}
CLASS_COLOURS = {  # RGB: signal in light blue, background activity in orange, hot pixels in magenta
    NoiseClass.SIGNAL: (80, 170, 255),
    NoiseClass.BACKGROUND: (255, 150, 30),
    NoiseClass.HOT_PIXEL: (240, 40, 200),
}
TIMELINE = "event_time"


def blueprint(slab_ms: float = 100.0) -> rrb.Blueprint:
    """3D X-Y-T view showing a sliding slab of the last `slab_ms`, a frame view and time series."""
    slab = rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-slab_ms / 1000),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/", contents="events/**", name="events X-Y-T", time_ranges=slab),
            rrb.Vertical(
                rrb.Spatial2DView(origin="frames", name="frames"),
                rrb.TimeSeriesView(origin="stats", name="stats"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunSink:
    """Logs batches to a `rr.RecordingStream` (already connected to a viewer, file or server).

    `t_scale_px_per_ms` sets how far 1 ms of event time reaches along the T axis; `point_budget`
    caps the 3D points logged per batch (uniform subsampling, counted in `points_dropped`) — frames
    and statistics always use every event.
    """

    def __init__(self, stream: rr.RecordingStream, *, t_scale_px_per_ms: float = 2.0,
                 point_budget: int | None = 200_000, slab_ms: float = 100.0, seed: int = 0):
        self.rec = stream
        self.t_scale = t_scale_px_per_ms / 1000.0
        self.point_budget = point_budget
        self.points_dropped = 0
        self.t0: int | None = None
        self._rng = np.random.default_rng(seed)
        self.rec.send_blueprint(blueprint(slab_ms))
        self.rec.log(
            "events",
            rr.AnnotationContext([
                rr.AnnotationInfo(id=int(c), label=c.name.lower(), color=CLASS_COLOURS[c]) for c in NoiseClass
            ]),
            static=True,
        )
        self.rec.log("events", rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)

    def write(self, batch: Batch) -> None:
        ev = batch.events
        if len(ev):
            if self.t0 is None:
                self.t0 = int(ev.t[0])
            ev = self._subsample(ev)
            self.rec.set_time(TIMELINE, duration=(int(batch.events.t[-1]) - self.t0) * 1e-6)
            cls = ev.classes()
            for c, entity in CLASS_ENTITIES.items():
                sel = np.flatnonzero(cls == c)
                if len(sel):
                    pos = np.column_stack((ev.x[sel], ev.y[sel], (ev.t[sel] - self.t0) * self.t_scale))
                    points = rr.Points3D(pos.astype(np.float32), class_ids=np.full(len(sel), int(c)),
                                         radii=rr.Radius.ui_points(1.5))
                    self.rec.log(entity, points)
            self._log_stats(batch)
        for frame in batch.frames:
            if self.t0 is None:
                self.t0 = frame.t_start
            self.rec.set_time(TIMELINE, duration=(frame.t_end - self.t0) * 1e-6)
            self.rec.log("frames", rr.Image(_render(frame.image)))

    def _subsample(self, ev):
        if self.point_budget is None or len(ev) <= self.point_budget:
            return ev
        keep = np.sort(self._rng.choice(len(ev), self.point_budget, replace=False))
        self.points_dropped += len(ev) - self.point_budget
        return ev[keep]

    def _log_stats(self, batch: Batch) -> None:
        ev = batch.events
        span_s = max(ev.duration_us, 1) * 1e-6
        self.rec.log("stats/event_rate_hz", rr.Scalars(len(ev) / span_s))
        counts = np.bincount(ev.classes(), minlength=3)[:3]
        for c in (NoiseClass.BACKGROUND, NoiseClass.HOT_PIXEL):
            self.rec.log(f"stats/noise_fraction/{c.name.lower()}", rr.Scalars(counts[c] / len(ev)))

    def close(self, stats: RunStats) -> None:
        self.rec.flush()


def _render(signed: np.ndarray) -> np.ndarray:
    """Signed counts -> gray image with ON white, OFF black (the paper's figures)."""
    img = np.full(signed.shape, 128, np.uint8)
    img[signed > 0] = 255
    img[signed < 0] = 0
    return img


def open_stream(*, save: str | None = None, spawn: bool = False, connect: str | None = None,
                application_id: str = "evstream") -> rr.RecordingStream:
    """A recording stream writing to a file (`save`), a spawned viewer, or a running viewer's URL."""
    rec = rr.RecordingStream(application_id)
    if save:
        rec.save(save)
    elif spawn:
        rec.spawn()
    elif connect:
        rec.connect_grpc(connect)
    else:
        raise ValueError("choose where Rerun output goes: save, spawn or connect")
    return rec
