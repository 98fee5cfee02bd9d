"""Rerun sink: events as a 3D X-Y-T point cloud split by noise class, frames as images, stats as scalars.

One recording, timeline `event_time` (event-clock time since the first event). Entities:

- `events/signal`, `events/noise/background`, `events/noise/hot_pixel` — Points3D at (x, y, -t·scale),
  one row per `time_bin_us` of event time, class ids resolved by the AnnotationContext on `events`
  (colours, labels), so each class toggles in the viewer's tree and the visible time range of the
  3D view cuts a slab whose depth is `slab_ms`;
- `events` — a Transform3D moving with event time, so the newest events sit at depth 0 and older ones
  recede: the slab stays in front of the camera while the stream flows through it (the paper's
  Figure 1, animated); `slab` is a wireframe box marking it;
- with `classes_apart=False` (live viewers), `events/points` instead: the three classes' points, their
  class ids and the moving Transform3D in one entity, so each send is one chunk, not four;
- `frames/<framer>` — Image (OFF black, ON white, gray background: the paper's rendering);
- `representations/<kind>` — with a representation framer, its picture beside the frames (the time
  surface in viridis, the voxel grid's bins side by side: `framing.render.render_representation`);
- `stats/events/rate_hz`, `stats/noise_fraction/{background,hot_pixel}` per `stats_bin_us` of event
  time, `stats/frames/rate_hz`, `stats/frames/events_per_frame` per frame.

The 3D view may subsample to `point_budget_hz` (points per second of event time, a token bucket) and
to `wall_budget_hz` (points per second of wall-clock time: what a viewer must take in, whatever the
replay speed), and counts what it drops in `points_dropped`; frames and statistics always use every event.

What is logged is sent every `send_every_s` of wall-clock time as one column per entity (points, slab
transform, statistics; the statistics every `stats_every_s`), not as calls per packet: a viewer's cost
grows with the number of chunks it ingests, not with their size — the web viewer takes in about 10 ms of
chunks per frame; under software WebGL on two loaded cores a page that drew nothing fell behind at 28
chunks a second with 10 k points as with 100 k, and kept up at 5–7 (benchmarks/bench_viewer_lag.py,
docs/live.md). A `live` sink also drops, at each send, the points more
than `late_s` of event time behind the newest one (a following view shows only the last slab: they are
the backlog a viewer that fell behind would otherwise queue), counted in `points_late`.

A restarted stream (`restart()`) keeps the layout and colour table and continues the timeline after the
previous stream's last event (plus one slab), so the two are shown one after the other, never blended.
"""

from __future__ import annotations

import time

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from evstream.sinks.colours import CLASS_COLOURS

from evstream.events import N_CLASSES, EventChunk, Frame, Geometry, NoiseClass
from evstream.framing.render import render_representation
from evstream.framing.represent import REPRESENTATIONS
from evstream.jit import njit
from evstream.pipeline import Batch, RunStats

TIMELINE = "event_time"
CLASS_ENTITIES = {
    NoiseClass.SIGNAL: "events/signal",
    NoiseClass.BACKGROUND: "events/noise/background",
    NoiseClass.HOT_PIXEL: "events/noise/hot_pixel",
}
CLASS_LABELS = {NoiseClass.SIGNAL: "signal", NoiseClass.BACKGROUND: "background activity",
                NoiseClass.HOT_PIXEL: "hot pixel"}
VIEW_BACKGROUND = (14, 15, 18)
SLAB_COLOUR = (110, 110, 110)
NOW_COLOUR = (235, 235, 235)
STATS_BIN_US = 10_000
POINTS_ENTITY = "events/points"  # the three classes in one entity (classes_apart=False)
# A live viewer (subscribe --serve/--spawn/--viewer): what it must take in stays bounded whatever the event
# rate (benchmarks/bench_viewer_lag.py; docs/live.md): 100 k points per wall-clock second, the points (one
# entity, one chunk) sent twice a second and the statistics (three chunks) once a second — 5 chunks a second
# for the web viewer to take in —, rows of 10 ms of event time, the points that fell 1 s behind dropped, and
# the time series showing the last 10 s (what a page redraws each frame stays bounded).
LIVE_OPTIONS = {"live": True, "wall_budget_hz": 100_000.0, "send_every_s": 0.5, "stats_every_s": 1.0,
                "time_bin_us": 10_000, "classes_apart": False, "series_window_s": 10.0}
# Into an .rrd file: the points every 20 ms of wall-clock time (the statistics every 100 ms, as for a viewer).
# Rerun's file writer (Arrow encoding, LZ4, the write: ~0.4 s of CPU for 10 M points) starts on a send and
# works beside the sink; sent every 100 ms, it still had 0.08-0.17 s of a 10 M-event replay's last send to
# write when the run ended, and `replay --save` waited for it (0.02-0.03 s at 20 ms). The file holds the same
# rows, cut into more chunks (a row of `time_bin_us` cut by a send is two rows at the same time, as at a
# chunk's edge).
FILE_SENDS = {"send_every_s": 0.02, "stats_every_s": 0.1}


def _columns(archetype, lengths: np.ndarray, **fields) -> list[rr.ComponentColumn]:
    """`archetype.columns(**fields).partition(lengths)` without the detour through unit-length rows:
    `columns` first partitions every component one instance per row (an array of ones, a copy, a cast and
    a cumulative sum per point: ~30 % of the sink's own time at 10 M points), which `partition` then
    replaces. Here each component batch (the same descriptors and Arrow data as `columns` builds, by
    `from_fields`) is partitioned once, by int32 offsets of `lengths` (rows of that many instances)."""
    offsets = np.zeros(len(lengths) + 1, np.int32)
    np.cumsum(lengths, out=offsets[1:])
    return [rr.ComponentColumn(batch.component_descriptor(), batch, offsets=offsets)
            for batch in archetype.from_fields(**fields).as_component_batches()]


def _us(t_us) -> np.ndarray:
    """µs (scalar or array) -> a duration array Rerun stores exactly (ns)."""
    return np.asarray(t_us, np.int64).astype("timedelta64[us]")


# -- layout ---------------------------------------------------------------------------------------
EYE_OFFSET = (1.2, -0.7, -0.95)  # eye position: x in sensor widths, y in heights, z in slab depths


def _eye(geometry: Geometry) -> dict:
    """Eye above, right of and in front of the sensor plane, looking into the slab (image up is -y),
    so time recedes to the upper right."""
    w, h, depth = geometry.width, geometry.height, slab_depth(geometry)
    ox, oy, oz = EYE_OFFSET
    return {"position": (ox * w, oy * h, oz * depth), "look_target": (0.5 * w, 0.5 * h, 0.5 * depth)}


def slab_depth(geometry: Geometry) -> float:
    """Depth of the slab along T, in pixel units: 1.5 sensor widths reads well at any sensor size."""
    return 1.5 * max(geometry.width, geometry.height)


def blueprint(geometry: Geometry, slab_ms: float = 100.0, framer: str | None = None,
              play_state: str | None = None, series_window_s: float | None = None) -> rrb.Blueprint:
    """The default layout: 3D X-Y-T slab of the last `slab_ms`, the frame view, the time series.

    `play_state` "following" keeps the time cursor on the newest data (live streams, screenshots);
    None lets the viewer choose (it plays a file from the start). `series_window_s`: the time series
    show the last that many seconds before the cursor (None: the whole timeline) — a live page redraws
    them every frame, and a whole growing history costs it more each second.
    """
    slab = rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-slab_ms / 1000),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=(0.0, -1.0, 0.0), **_eye(geometry))
    events_view = rrb.Spatial3DView(
        origin="/", contents=["events/**", "slab/**"], name=f"events X-Y-T (last {slab_ms:g} ms)",
        time_ranges=slab, eye_controls=eye, line_grid=rrb.LineGrid3D(visible=False),
        background=VIEW_BACKGROUND,  # the class colours are chosen for a dark ground, in either UI theme
    )
    window = None if series_window_s is None else rrb.VisibleTimeRange(
        TIMELINE, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-series_window_s),
        end=rrb.TimeRangeBoundary.cursor_relative())
    series = [rrb.TimeSeriesView(origin="stats/events", name="event rate [events/s]", time_ranges=window),
              rrb.TimeSeriesView(origin="stats/noise_fraction", name="noise fraction", time_ranges=window)]
    if framer is None:  # no frames to show: the time series take the column
        side = rrb.Vertical(*series)
    else:
        series.append(rrb.Tabs(
            rrb.TimeSeriesView(origin="stats/frames/rate_hz", name="frame rate [Hz]", time_ranges=window),
            rrb.TimeSeriesView(origin="stats/frames/events_per_frame", name="events per frame", time_ranges=window),
        ))
        frames_view = rrb.Spatial2DView(origin=f"frames/{framer}", name=f"frames ({framer})")
        if framer in REPRESENTATIONS:  # the representation beside the counts of the same window
            frames_view = rrb.Horizontal(frames_view, rrb.Spatial2DView(origin=f"representations/{framer}",
                                                                         name=framer))
        side = rrb.Vertical(frames_view, rrb.Vertical(*series), row_shares=[2, 3])
    panel = rrb.TimePanel(timeline=TIMELINE, state="collapsed", play_state=play_state)
    return rrb.Blueprint(
        rrb.Horizontal(events_view, side, column_shares=[3, 2]),
        panel,
        collapse_panels=True,
    )


# -- kernels --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def points_by_class(t, x, y, cls, origin_us, bin_us, scale, n_classes):
    """The 3D points of events `t` (sorted), x, y grouped by class for one Rerun row per `bin_us` of
    timeline (timeline µs = t - origin_us; depth = -timeline µs · scale). Returns pos (n, 3) float32 —
    class 0's points, then class 1's, ..., each in stream order; classes >= n_classes are left out —,
    the count per class, per class its rows' lengths and last timeline µs (n_rows[c] of each row of
    `row_len`/`row_us`), and the last timeline µs of each row over all classes (the slab's rows).
    As `t` is sorted, an event starts a new bin when it reaches the next bin's first µs (`edge`): one
    integer division per bin, not per event (two per event were half the kernel's time)."""
    n = len(t)
    count = np.zeros(n_classes, np.int64)
    n_rows = np.zeros(n_classes, np.int64)
    last_bin = np.zeros(n_classes, np.int64)
    all_rows = 0
    b = np.int64(0)
    edge = np.int64(0)
    for i in range(n):  # pass 1: sizes
        rel = t[i] - origin_us
        if i == 0 or rel >= edge:
            b = rel // bin_us
            edge = (b + 1) * bin_us
            all_rows += 1
        c = np.intp(cls[i])
        if c >= n_classes:
            continue
        if count[c] == 0 or b != last_bin[c]:
            n_rows[c] += 1
            last_bin[c] = b
        count[c] += 1
    width = max(1, n_rows.max()) if n_classes else 1
    pos = np.empty((count.sum(), 3), np.float32)
    row_len = np.zeros((n_classes, width), np.int64)
    row_us = np.zeros((n_classes, width), np.int64)
    slab_us = np.zeros(all_rows, np.int64)
    at = np.zeros(n_classes, np.int64)  # next row of pos per class
    for c in range(1, n_classes):
        at[c] = at[c - 1] + count[c - 1]
    row = np.full(n_classes, -1, np.int64)
    k = -1
    for i in range(n):  # pass 2: fill
        rel = t[i] - origin_us
        if i == 0 or rel >= edge:
            b = rel // bin_us
            edge = (b + 1) * bin_us
            k += 1
        slab_us[k] = rel
        c = np.intp(cls[i])
        if c >= n_classes:
            continue
        if row[c] < 0 or b != last_bin[c]:
            row[c] += 1
            last_bin[c] = b
        row_len[c, row[c]] += 1
        row_us[c, row[c]] = rel
        j = at[c]
        pos[j, 0] = np.float32(x[i])
        pos[j, 1] = np.float32(y[i])
        pos[j, 2] = np.float32(np.float64(rel) * -scale)
        at[c] = j + 1
    return pos, count, n_rows, row_len, row_us, slab_us


@njit(cache=True, nogil=True)
def class_counts_per_bin(t, cls, t0, bin_us, open_bin, n_classes):
    """The distinct bins (t - t0) // bin_us - open_bin of events `t` (sorted), ascending, and the events
    per class in each (classes >= n_classes are not counted). One division per bin, not per event: a
    sorted event starts a new bin when it reaches the next bin's first µs (`edge`)."""
    n = len(t)
    distinct = 0
    edge = np.int64(0)
    for i in range(n):
        rel = t[i] - t0
        if i == 0 or rel >= edge:
            edge = (rel // bin_us + 1) * bin_us
            distinct += 1
    bins = np.empty(distinct, np.int64)
    per = np.zeros((distinct, n_classes), np.int64)
    k = -1
    for i in range(n):
        rel = t[i] - t0
        if i == 0 or rel >= edge:
            q = rel // bin_us
            edge = (q + 1) * bin_us
            k += 1
            bins[k] = q - open_bin
        c = np.intp(cls[i])
        if c < n_classes:
            per[k, c] += 1
    return bins, per


# -- pieces that keep state across chunks --------------------------------------------------------
class _TokenBucket:
    """What the two point budgets share: `rate_hz` tokens a second, a burst of `burst_s` worth, and the
    spending of them on evenly spaced points; `dropped` counts what was left out."""

    def __init__(self, rate_hz: float | None, burst_s: float):
        self.rate_hz = rate_hz
        self.capacity = None if rate_hz is None else max(1.0, rate_hz * burst_s)
        self.tokens = self.capacity
        self.t_last = None
        self.dropped = 0

    def _spend(self, n: int) -> np.ndarray | None:
        """Spend whole tokens on `n` points: None when all fit, else the indices of evenly spaced ones."""
        k = min(n, int(self.tokens))
        self.tokens -= k
        if k == n:
            return None
        self.dropped += n - k
        return (np.arange(k, dtype=np.int64) * n) // k


class PointBudget(_TokenBucket):
    """Token bucket over event time: at most `rate_hz` points per second of events (plus a saved-up
    burst of at most `burst_s` worth); picks evenly spaced events within a chunk."""

    def __init__(self, rate_hz: float | None, burst_s: float = 0.1):
        super().__init__(rate_hz, burst_s)

    def select(self, t: np.ndarray) -> np.ndarray | None:
        """Indices of the events to draw, or None for all of them."""
        n = len(t)
        if self.rate_hz is None or n == 0:
            return None
        t_prev = int(t[0]) if self.t_last is None else self.t_last
        # saved-up tokens are capped; this chunk's own span of event time is not
        self.tokens = min(self.capacity, self.tokens) + self.rate_hz * (int(t[-1]) - t_prev) * 1e-6
        self.t_last = int(t[-1])
        return self._spend(n)


class WallBudget(_TokenBucket):
    """Token bucket over wall-clock time: at most `rate_hz` points per second of wall-clock time (plus a
    saved-up burst of `burst_s` worth), evenly spaced within a chunk."""

    def __init__(self, rate_hz: float | None, burst_s: float = 0.2, clock=time.monotonic):
        super().__init__(rate_hz, burst_s)
        self.clock = clock

    def select(self, n: int) -> np.ndarray | None:
        """Indices of the `n` points to draw, or None for all of them."""
        if self.rate_hz is None or n == 0:
            return None
        now = self.clock()
        if self.t_last is not None:
            self.tokens = min(self.capacity, self.tokens + self.rate_hz * (now - self.t_last))
        self.t_last = now
        return self._spend(n)


class StatsBins:
    """Events per class in fixed bins of event time (`bin_us`, anchored at `t0`).

    `push` returns the bins that closed — a bin closes when a later event or the watermark passes
    its end — as (bin end µs, counts[k, 3]). A run of empty bins yields its first and last bin only,
    so a long gap costs two rows. `flush` closes the open bin at the end of the stream.
    """

    def __init__(self, t0: int, bin_us: int = STATS_BIN_US):
        self.t0 = t0
        self.bin_us = bin_us
        self.open_bin = 0
        self.open_counts = np.zeros(N_CLASSES, np.int64)

    def push(self, t: np.ndarray, cls: np.ndarray, t_end: int) -> tuple[np.ndarray, np.ndarray]:
        ends: list[np.ndarray] = []
        counts: list[np.ndarray] = []
        if len(t):
            first = (int(t[0]) - self.t0) // self.bin_us
            if first > self.open_bin:  # the open bin closed before this chunk
                self._close_through(first, ends, counts)
            last = (int(t[-1]) - self.t0) // self.bin_us
            # counts of the bins that hold events only (local to the open bin): a pause of days inside
            # one chunk must not allocate a row per empty bin (2^42 µs took 9.8 GiB)
            bins, per = class_counts_per_bin(t, cls, self.t0, self.bin_us, self.open_bin, N_CLASSES)
            per[0] += self.open_counts
            idx = self._with_gap_edges(bins[:-1], int(bins[-1]))  # every bin but the last closed
            if len(idx):
                rows = np.zeros((len(idx), N_CLASSES), np.int64)
                at = np.searchsorted(bins, idx)
                held = bins[np.minimum(at, len(bins) - 1)] == idx
                rows[held] = per[at[held]]
                ends.append((self.open_bin + idx + 1) * self.bin_us + self.t0)
                counts.append(rows)
            self.open_bin = last
            self.open_counts = per[-1].copy()
        wm_bin = (t_end - self.t0) // self.bin_us if t_end > self.t0 else 0
        if wm_bin > self.open_bin and t_end - self.t0 >= (self.open_bin + 1) * self.bin_us:
            self._close_through(wm_bin, ends, counts)
        if not ends:
            return np.zeros(0, np.int64), np.zeros((0, N_CLASSES), np.int64)
        return np.concatenate(ends), np.concatenate(counts)

    def _with_gap_edges(self, nonempty: np.ndarray, next_bin: int) -> np.ndarray:
        """Nonempty bin indices plus the first and last empty bin of each gap before `next_bin`."""
        if len(nonempty) == 0:
            return nonempty
        bounds = np.append(nonempty, next_bin)
        gap_start = bounds[:-1] + 1
        gap_stop = bounds[1:] - 1
        has_gap = gap_start <= gap_stop
        out = np.concatenate((nonempty, gap_start[has_gap], gap_stop[has_gap]))
        return np.unique(out)

    def _close_through(self, new_open: int, ends: list, counts: list) -> None:
        """Close the open bin (and the empty ones up to `new_open`), make `new_open` the open bin."""
        idx = [self.open_bin]
        if new_open - self.open_bin > 1:
            idx += sorted({self.open_bin + 1, new_open - 1})
        rows = np.zeros((len(idx), N_CLASSES), np.int64)
        rows[0] = self.open_counts
        ends.append((np.asarray(idx, np.int64) + 1) * self.bin_us + self.t0)
        counts.append(rows)
        self.open_bin = int(new_open)
        self.open_counts = np.zeros(N_CLASSES, np.int64)

    def flush(self, t_last: int) -> tuple[np.ndarray, np.ndarray]:
        """Close the open bin, ending it at the last event (a partial bin keeps an honest rate)."""
        end = min(t_last + 1, self.t0 + (self.open_bin + 1) * self.bin_us)
        return np.array([end], np.int64), self.open_counts[None, :].copy()


# -- the sink ---------------------------------------------------------------------------------------
class RerunSink:
    """Logs batches to a `rr.RecordingStream` (already saving to a file or connected to a viewer).

    `time_bin_us`: event time per logged row of points (how smoothly the slab slides);
    `point_budget_hz`: most 3D points per second of event time (None: every event);
    `slab_ms`: depth of the visible time range; `framer`: name of the frame entity;
    `play_state`: passed to the blueprint ("following" for live viewing);
    `wall_budget_hz`: most 3D points per second of wall-clock time (None: no bound);
    `send_every_s`: wall-clock time between sends (0: each batch as it comes);
    `stats_every_s`: wall-clock time between sends of the statistics (None: with every send);
    `series_window_s`: the time series show the last that many seconds (None: all; see `blueprint`);
    `classes_apart`: one entity per class (toggled apart in the viewer's tree), else all points, their
    class ids and the slab's transform in `events/points` (one chunk per send: a live viewer's cost);
    `live`: drop, at each send, points more than `late_s` (at least the slab) of event time behind the
    newest one (see the module docstring).
    """

    def __init__(self, stream: rr.RecordingStream, *, geometry: Geometry | None = None,
                 slab_ms: float = 100.0, time_bin_us: int = 1000, point_budget_hz: float | None = 1e6,
                 framer: str | None = None, play_state: str | None = None,
                 stats_bin_us: int = STATS_BIN_US, point_radius_ui: float = 1.5,
                 wall_budget_hz: float | None = None, send_every_s: float = 0.1, live: bool = False,
                 late_s: float = 1.0, stats_every_s: float | None = None, classes_apart: bool = True,
                 series_window_s: float | None = None):
        if slab_ms <= 0 or time_bin_us <= 0 or stats_bin_us <= 0:
            raise ValueError("slab_ms, time_bin_us and stats_bin_us must be positive")
        if point_budget_hz is not None and point_budget_hz <= 0:
            raise ValueError(f"point budget must be positive, got {point_budget_hz}")
        if wall_budget_hz is not None and wall_budget_hz <= 0:
            raise ValueError(f"wall-clock point budget must be positive, got {wall_budget_hz}")
        if send_every_s < 0 or (stats_every_s is not None and stats_every_s < 0):
            raise ValueError(f"send_every_s and stats_every_s must be >= 0, got {send_every_s}, {stats_every_s}")
        self.rec = stream
        self.slab_ms = slab_ms
        self.time_bin_us = int(time_bin_us)
        self.stats_bin_us = int(stats_bin_us)
        self.framer = framer
        self.play_state = play_state
        self.point_radius_ui = point_radius_ui
        self.budget = PointBudget(point_budget_hz)
        self.wall = WallBudget(wall_budget_hz)
        self.send_every_s = float(send_every_s)
        self.stats_every_s = self.send_every_s if stats_every_s is None else float(stats_every_s)
        self.classes_apart = classes_apart
        self.series_window_s = series_window_s
        self.live = live
        self.late_s = float(late_s)
        self.geometry: Geometry | None = None
        self.t0: int | None = None
        self.t_last: int | None = None
        self.offset_us = 0  # timeline position of t0: a restarted stream continues after the previous one
        self.points_logged = 0
        self.points_late = 0
        self.frames_logged = 0
        self.restarts = 0
        self._stats: StatsBins | None = None
        self._last_frame_end: int | None = None
        self._pending: list[tuple[np.ndarray, ...]] = []  # (t, x, y, cls) of points not sent yet
        self._pending_stats: list[tuple[np.ndarray, np.ndarray]] = []
        self._pending_frames: list[Frame] = []  # live: frames wait for the next send, as columns
        self._pending_frame_stats: list[tuple[int, int, float]] = []  # (t_end µs, events, rate Hz or nan)
        self._last_send = self._last_stats_send = time.monotonic()
        if geometry is not None:
            self._start(geometry, None)

    @property
    def points_dropped(self) -> int:
        """Points not drawn: over either budget, or too late for a live view."""
        return self.budget.dropped + self.wall.dropped + self.points_late

    # -- setup ---------------------------------------------------------------------------------
    def _start(self, geometry: Geometry, t0: int | None) -> None:
        """Blueprint and static entities, once the sensor geometry is known."""
        self.geometry = geometry
        self.scale = slab_depth(geometry) / (self.slab_ms * 1000.0)  # depth units per µs
        rec = self.rec
        rec.send_blueprint(blueprint(geometry, self.slab_ms, self.framer, self.play_state, self.series_window_s))
        rec.log("/", rr.ViewCoordinates.RDF, static=True)  # x right, y down (image rows), z away
        rec.log("events", rr.AnnotationContext([
            rr.AnnotationInfo(id=int(c), label=CLASS_LABELS[c], color=CLASS_COLOURS[c]) for c in NoiseClass
        ]), static=True)
        radius = rr.Radius.ui_points(self.point_radius_ui)
        if self.classes_apart:
            for c, entity in CLASS_ENTITIES.items():
                rec.log(entity, rr.Points3D.from_fields(class_ids=[int(c)], radii=[radius], show_labels=False),
                        static=True)
        else:
            rec.log(POINTS_ENTITY, rr.Points3D.from_fields(radii=[radius], show_labels=False), static=True)
        self._log_slab_outline(geometry)
        rec.log("stats/noise_fraction/background", rr.SeriesLines(
            colors=[CLASS_COLOURS[NoiseClass.BACKGROUND]], names=["background activity"]), static=True)
        rec.log("stats/noise_fraction/hot_pixel", rr.SeriesLines(
            colors=[CLASS_COLOURS[NoiseClass.HOT_PIXEL]], names=["hot pixel"]), static=True)
        rec.log("stats/events/rate_hz", rr.SeriesLines(colors=[(220, 220, 220)], names=["events/s"]),
                static=True)
        if self.framer is not None:
            rec.log("stats/frames/rate_hz", rr.SeriesLines(colors=[(170, 120, 255)], names=["frames/s"]),
                    static=True)
            rec.log("stats/frames/events_per_frame", rr.SeriesLines(colors=[(120, 220, 160)],
                                                                    names=["events per frame"]), static=True)
        if t0 is not None:
            self.t0 = t0

    def _log_slab_outline(self, geometry: Geometry) -> None:
        """A wireframe box around the slab; its front face (the newest events) drawn brighter."""
        w, h, depth = geometry.width, geometry.height, slab_depth(geometry)
        self.rec.log("slab", rr.Boxes3D(centers=[(w / 2, h / 2, depth / 2)], half_sizes=[(w / 2, h / 2, depth / 2)],
                                        colors=[SLAB_COLOUR], radii=rr.Radius.ui_points(0.75),
                                        fill_mode="majorwireframe"), static=True)
        self.rec.log("slab/now", rr.LineStrips3D([[(0, 0, 0), (w, 0, 0), (w, h, 0), (0, h, 0), (0, 0, 0)]],
                                                 colors=[NOW_COLOUR], radii=rr.Radius.ui_points(1.25)),
                     static=True)
        self.rec.log("slab/axes", rr.Points3D(
            [(0, -0.04 * h, 0), (w, -0.04 * h, 0), (0, -0.04 * h, depth), (-0.04 * w, h, 0)],
            labels=["now", f"x {w}", f"-{self.slab_ms:g} ms", f"y {h}"], colors=[NOW_COLOUR],
            radii=rr.Radius.ui_points(0.1)), static=True)

    # -- Sink protocol ---------------------------------------------------------------------------
    def write(self, batch: Batch) -> None:
        ev = batch.events
        if self.geometry is None:
            self._start(ev.geometry, None)
        if len(ev):
            if self.t0 is None:
                self.t0 = int(ev.t[0])
                self._stats = StatsBins(self.t0, self.stats_bin_us)
            self.t_last = int(ev.t[-1])
            self._keep_points(ev)
            self._pending_stats.append(self._stats.push(ev.t, ev.classes(), ev.t_end))
        elif self._stats is not None and ev.t_end > (self.t_last or ev.t_end):
            self._pending_stats.append(self._stats.push(ev.t, ev.classes(), ev.t_end))
        self._log_frames(batch.frames)
        if time.monotonic() - self._last_send >= self.send_every_s:
            self.send()

    def close(self, stats: RunStats) -> None:
        if self._stats is not None and self.t_last is not None:
            self._pending_stats.append(self._stats.flush(self.t_last))
            self._stats = None
        self.send(stats=True)
        self.rec.flush(timeout_sec=0)  # started here; its owner waits for it (`rerun_viewer.wait_flushed`)

    def restart(self) -> None:
        """A new stream (its publisher restarted, its clock back to 0) after `close`: same recording, layout
        and colours; its timeline continues one slab after the previous stream's last event."""
        if self._stats is not None and self.t_last is not None:  # not closed: the open bin goes out first
            self._pending_stats.append(self._stats.flush(self.t_last))
        self.send(stats=True)
        if self.t0 is not None and self.t_last is not None:
            self.offset_us += self.t_last - self.t0 + int(self.slab_ms * 1000)
        self.t0 = self.t_last = None
        self._stats = None
        self._last_frame_end = None
        self.budget = PointBudget(self.budget.rate_hz)
        self.restarts += 1

    def send(self, stats: bool = False) -> None:
        """Log what waits: every entity's rows as one column each (the statistics when `stats_every_s`
        has passed, or `stats`)."""
        self._last_send = now = time.monotonic()
        if self._pending:
            parts, self._pending = self._pending, []
            t, x, y, cls = (np.concatenate([p[k] for p in parts]) for k in range(4))
            if self.live:  # more than `late_s` behind the newest: a following view shows them no more
                late = int(np.searchsorted(t, t[-1] - int(max(self.late_s, self.slab_ms / 1000) * 1e6), side="left"))
                if late:
                    self.points_late += late
                    t, x, y, cls = t[late:], x[late:], y[late:], cls[late:]
            self._log_points(t, x, y, cls)
        if self._pending_frames:
            frames, self._pending_frames = self._pending_frames, []
            self._send_frames(frames)
        if (self._pending_stats or self._pending_frame_stats) and (
                stats or now - self._last_stats_send >= self.stats_every_s):
            self._last_stats_send = now
            if self._pending_stats:
                parts, self._pending_stats = self._pending_stats, []
                self._log_stats(np.concatenate([e for e, _ in parts]), np.concatenate([c for _, c in parts]))
            if self._pending_frame_stats:
                rows, self._pending_frame_stats = self._pending_frame_stats, []
                self._send_frame_stats(*(np.array(col) for col in zip(*rows)))

    # -- logging ---------------------------------------------------------------------------------
    def _rel(self, t) -> np.ndarray:
        """Timeline position (µs) of event times `t`."""
        return np.asarray(t, np.int64) - self.t0 + self.offset_us

    def _keep_points(self, ev: EventChunk) -> None:
        """The chunk's points within both budgets, waiting for the next send."""
        keep = self.budget.select(ev.t)
        t, x, y, cls = ev.t, ev.x, ev.y, ev.classes()
        if keep is not None:
            t, x, y, cls = t[keep], x[keep], y[keep], cls[keep]
        keep = self.wall.select(len(t))
        if keep is not None:
            t, x, y, cls = t[keep], x[keep], y[keep], cls[keep]
        if len(t):
            self._pending.append((t, x, y, cls))

    def _log_points(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, cls: np.ndarray) -> None:
        if not len(t):
            return
        if self.classes_apart:
            self._log_points_apart(t, x, y, cls)
            return
        rel = self._rel(t)
        bins = rel // self.time_bin_us
        # Slab transform: one row per bin, newest events at depth 0.
        change = np.flatnonzero(np.diff(bins)) + 1
        ends_idx = np.append(change, len(t)) - 1
        row_t = rel[ends_idx]
        slab = rr.Transform3D.columns(translation=np.column_stack(
            (np.zeros(len(row_t)), np.zeros(len(row_t)), row_t * self.scale)).astype(np.float32))
        pos = np.empty((len(t), 3), np.float32)
        pos[:, 0] = x
        pos[:, 1] = y
        pos[:, 2] = rel * -self.scale
        self.points_logged += len(t)
        # one chunk: every class's points, their ids and the slab's transform
        points = _columns(rr.Points3D, np.diff(ends_idx, prepend=-1), positions=pos, class_ids=cls)
        self.rec.send_columns(POINTS_ENTITY, indexes=[rr.TimeColumn(TIMELINE, duration=_us(row_t))],
                              columns=[*points, *slab])

    def _log_points_apart(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, cls: np.ndarray) -> None:
        """Each class's points in its entity, one row per `time_bin_us`, and the slab's transform on
        `events` (one row per bin holding any event); grouped by one kernel pass (4x numpy's masks)."""
        pos, count, n_rows, row_len, row_us, slab_us = points_by_class(
            t, x, y, cls, self.t0 - self.offset_us, self.time_bin_us, self.scale, N_CLASSES)
        depth = (slab_us * self.scale).astype(np.float32)
        zero = np.zeros_like(depth)
        slab = rr.Transform3D.columns(translation=np.column_stack((zero, zero, depth)))
        self.rec.send_columns("events", indexes=[rr.TimeColumn(TIMELINE, duration=_us(slab_us))], columns=slab)
        self.points_logged += len(t)
        start = 0
        for c in range(N_CLASSES):
            stop = start + int(count[c])
            if stop > start and c in CLASS_ENTITIES:
                k = int(n_rows[c])
                self.rec.send_columns(
                    CLASS_ENTITIES[c], indexes=[rr.TimeColumn(TIMELINE, duration=_us(row_us[c, :k]))],
                    columns=_columns(rr.Points3D, row_len[c, :k], positions=pos[start:stop]),
                )
            start = stop

    def _log_stats(self, ends_us: np.ndarray, counts: np.ndarray) -> None:
        if not len(ends_us):
            return
        starts = self.t0 + (ends_us - 1 - self.t0) // self.stats_bin_us * self.stats_bin_us  # bin starts
        span_s = np.maximum(ends_us - starts, 1) * 1e-6
        total = counts.sum(axis=1)
        times = [rr.TimeColumn(TIMELINE, duration=_us(self._rel(ends_us)))]
        self.rec.send_columns("stats/events/rate_hz", indexes=times,
                              columns=rr.Scalars.columns(scalars=total / span_s))
        some = total > 0
        if some.any():
            t_some = [rr.TimeColumn(TIMELINE, duration=_us(self._rel(ends_us[some])))]
            for c in (NoiseClass.BACKGROUND, NoiseClass.HOT_PIXEL):
                self.rec.send_columns(f"stats/noise_fraction/{c.name.lower()}", indexes=t_some,
                                      columns=rr.Scalars.columns(scalars=counts[some, c] / total[some]))

    def _log_frames(self, frames: list[Frame]) -> None:
        for frame in frames:
            if self.t0 is None:
                self.t0 = frame.t_start
            if self.live:  # with the next send, as columns: a chunk per entity per send, not per frame
                rate = np.nan
                if self._last_frame_end is not None and frame.t_end > self._last_frame_end:
                    rate = 1e6 / (frame.t_end - self._last_frame_end)
                self._pending_frames.append(frame)
                self._pending_frame_stats.append((frame.t_end, frame.n_events, rate))
                self._last_frame_end = frame.t_end
                continue
            self.rec.set_time(TIMELINE, duration=np.timedelta64(int(self._rel(frame.t_end)), "us"))
            self.rec.log(f"frames/{self.framer or 'frames'}", rr.Image(render_frame(frame.image)))
            if getattr(frame, "data", None) is not None:  # a representation (time surface, voxel grid, ...)
                self.rec.log(f"representations/{frame.kind}", rr.Image(render_representation(frame)))
            self.rec.log("stats/frames/events_per_frame", rr.Scalars(frame.n_events))
            if self._last_frame_end is not None and frame.t_end > self._last_frame_end:
                self.rec.log("stats/frames/rate_hz", rr.Scalars(1e6 / (frame.t_end - self._last_frame_end)))
            self._last_frame_end = frame.t_end
            self.frames_logged += 1


    def _send_frames(self, frames: list[Frame]) -> None:
        """Frames (and the representations among them) as one Image column per entity."""
        groups = {f"frames/{self.framer or 'frames'}": [(f, render_frame(f.image)) for f in frames]}
        for f in frames:
            if getattr(f, "data", None) is not None:
                groups.setdefault(f"representations/{f.kind}", []).append((f, render_representation(f)))
        for entity, items in groups.items():
            images = np.stack([img for _, img in items])
            model = "L" if images.ndim == 3 else {3: "RGB", 4: "RGBA"}[images.shape[-1]]
            fmt = rr.components.ImageFormat(width=images.shape[2], height=images.shape[1], color_model=model,
                                            channel_datatype="U8")
            self.rec.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=_us(
                self._rel([f.t_end for f, _ in items])))], columns=rr.Image.columns(
                buffer=images.reshape(len(items), -1), format=[fmt] * len(items)))
        self.frames_logged += len(frames)

    def _send_frame_stats(self, t_end: np.ndarray, n_events: np.ndarray, rate_hz: np.ndarray) -> None:
        self.rec.send_columns("stats/frames/events_per_frame", indexes=[rr.TimeColumn(
            TIMELINE, duration=_us(self._rel(t_end)))], columns=rr.Scalars.columns(scalars=n_events.astype(float)))
        has = ~np.isnan(rate_hz)
        if has.any():
            self.rec.send_columns("stats/frames/rate_hz", indexes=[rr.TimeColumn(
                TIMELINE, duration=_us(self._rel(t_end[has])))], columns=rr.Scalars.columns(scalars=rate_hz[has]))


def render_frame(signed: np.ndarray) -> np.ndarray:
    """Signed counts -> gray image with ON white, OFF black (the paper's figures)."""
    img = np.full(signed.shape, 128, np.uint8)
    img[signed > 0] = 255
    img[signed < 0] = 0
    return img
