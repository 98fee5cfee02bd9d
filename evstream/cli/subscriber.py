"""The subscribing node: one pipeline and set of sinks per camera, the viewer's recordings, the status line."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from .. import threads
from ..events import EventChunk, NoiseClass
from .common import attach_framer, counted, pipeline_from_args


def archive_path(template: str, camera: str, wildcard: bool, segment: int) -> str:
    if "{camera}" in template:
        path = template.replace("{camera}", camera)
    elif wildcard:
        path = str(Path(template).with_suffix(f".{camera}.mcap"))
    else:
        path = template
    if segment:
        path = str(Path(path).with_suffix(f".{segment}.mcap"))
    return path


def topic_camera(camera: str) -> str:
    """A camera name the MCAP topics accept (letters, digits, '_', starting with a letter)."""
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in camera)
    return name if name[:1].isalpha() else "c" + name


class Camera:
    """One camera's pipeline and sinks (opened on its first packet, reopened when its publisher restarts)."""

    def __init__(self, name: str, node: Subscriber, geometry):
        self.name = name
        self.node = node
        self.segment = 0
        self.per_class = np.zeros(len(NoiseClass), np.int64)
        self.frames = 0
        self.published_events = 0
        self.published_packets = 0
        self.published_unmatched_packets = 0  # republished while nobody read the cleaned stream
        self.archives: list[str] = []
        self.viewer_sink = None  # kept across restarts: one layout and colour table, the timeline continued
        self.said_late = False
        self.open(geometry)

    def open(self, geometry) -> None:

        args, node = self.node.args, self.node
        self.pipeline = pipeline_from_args(args, None)
        attach_framer(self.pipeline, args)
        self.sinks = []
        self.pub = None
        self.writer = None
        if threads.enabled():
            self.writer = threads.WriteBehind(self._deliver, name=f"evstream-{self.name}-writer")
        if args.archive:
            from evstream.sinks.mcap_sink import McapSink

            path = archive_path(args.archive, self.name, node.wildcard, self.segment)
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            meta = {"source": f"zenoh:{node.keyexpr}", "camera_key_name": self.name,
                    "pipeline": self.pipeline.describe(), "command": sys.argv[1:] or None}
            self.sinks.append(McapSink(path, camera=topic_camera(self.name), keep_noise=args.keep_noise,
                                       frames=self.pipeline.framer is not None, metadata=meta, geometry=geometry,
                                       flush_s=args.flush_s))
            self.archives.append(path)
        if node.viewer is not None and self.viewer_sink is not None:
            self.viewer_sink.restart()
            self.sinks.append(self.viewer_sink)
        elif node.viewer is not None:
            from evstream.sinks.rerun_sink import LIVE_OPTIONS, RerunSink

            live = LIVE_OPTIONS if node.viewer.mode != "save" else {}  # a file keeps every point
            self.viewer_sink = RerunSink(node.viewer_rec(self.name), geometry=geometry,
                                         framer=getattr(self.pipeline.framer, "kind", None),
                                         point_budget_hz=args.point_budget or None, slab_ms=args.slab_ms,
                                         play_state=None if node.viewer.mode == "save" else "following", **live)
            self.sinks.append(self.viewer_sink)
        if args.republish:
            from evstream.sinks.zenoh_pub import ZenohSink, frames_key_for

            key = args.republish.replace("{camera}", self.name)
            self.pub = ZenohSink(node.session, key, congestion="block", frame_id=self.name,
                                 frames_key=frames_key_for(key) if self.pipeline.framer is not None else None)

    def process(self, packet) -> None:
        """The stages here; the sinks and the republishing on the camera's writer thread (`evstream.threads`:
        the next packet's stages overlap this one's encoding and sending), in order. A packet from which the
        framer would close many frames comes in several batches (`Pipeline.feed`)."""
        for batch in self.pipeline.feed(packet.chunk):
            if self.writer is not None:
                self.writer.put((batch, packet.source_time_ns))
            else:
                self._deliver((batch, packet.source_time_ns))

    def _deliver(self, item) -> None:
        batch, source_time_ns = item
        for sink in self.sinks:
            sink.write(batch)
        if self.viewer_sink is not None and self.viewer_sink.points_late and not self.said_late:
            self.said_late = True
            print(f"evstream: {self.name}: the viewer fell behind: points more than {self.viewer_sink.late_s:g} s "
                  "behind the newest are dropped, not queued (frames and statistics stay complete)",
                  file=sys.stderr, flush=True)
        if self.pub is not None:
            self.pub.write(batch, source_time_ns=source_time_ns)

    def close(self) -> None:
        """Finish the pipeline (frames still open), close the sinks (files complete, end mark sent)."""
        sinks = self.sinks + ([self.pub] if self.pub is not None else [])
        try:
            if self.writer is not None:
                self.writer, writer = None, self.writer
                writer.close()  # what was handed to it is written and sent; its error raised here
            batch = self.pipeline.finish(self.node.geometry_of[self.name])
            if batch.frames:
                for sink in sinks:
                    sink.write(batch)
        finally:
            for sink in sinks:
                sink.close(self.pipeline.stats)
        self.per_class += self.pipeline.stats.per_class
        self.frames += self.pipeline.stats.frames
        if self.pub is not None:
            self.published_events += self.pub.publisher.events
            self.published_packets += self.pub.publisher.packets
            self.published_unmatched_packets += self.pub.publisher.unmatched_packets
        self.sinks, self.pub = [], None

    def restart(self, geometry) -> None:
        self.close()
        self.segment += 1
        self.open(geometry)


class Subscriber:
    """`evstream subscribe`: a subscription, a camera table, the viewer, and the stop conditions."""

    def __init__(self, args):
        self.args = args
        self.keyexpr = args.keyexpr
        self.wildcard = any(c in args.keyexpr for c in "*$")
        self.cameras: dict[str, Camera] = {}
        self.geometry_of: dict = {}
        self.viewer = None
        self._recs: dict = {}
        self.saved: list[str] = []  # the .rrd files written (with --save)
        self._outputs: dict = {}  # camera: its AtomicOutput, committed by `finish_recordings`

    def finish_recordings(self) -> None:
        """End the other cameras' recordings (the first camera's is the viewer's) and put their files in
        place: a live recording ends whole when the subscriber stops, as the first camera's does. Without a
        viewer there is nothing to do, and Rerun is not imported (its import cost a denoise node or an
        archiver 0.3 s of CPU at the end of every stream: 10-20 ns per event of a 30-s bench run)."""
        if not self._recs and not self._outputs:
            return
        from evstream.sinks.rerun_viewer import wait_flushed

        for camera, rec in list(self._recs.items())[1:]:
            output = self._outputs.get(camera)
            wait_flushed(rec, output.part if output is not None else None)
            rec.disconnect()
        for output in self._outputs.values():
            output.commit()

    def viewer_rec(self, camera: str):
        """The first camera logs into the viewer's recording; others get recordings of their own."""
        if camera in self._recs:
            return self._recs[camera]
        if not self._recs:
            rec = self.viewer.rec
        else:
            import rerun as rr

            rec = rr.RecordingStream("evstream", recording_id=f"evstream-{camera}")
            if self.viewer.mode == "save":  # beside its name until the end, as the first camera's (safe_write)
                from evstream.safe_write import AtomicOutput

                path = str(Path(self.viewer.path).with_suffix(f".{camera}.rrd"))
                output = AtomicOutput(path)
                rec.save(str(output.part))
                self._outputs[camera] = output
                self.saved.append(path)
            else:
                rec.connect_grpc(self.viewer.grpc_url)
        self._recs[camera] = rec
        return rec


def warm_up(args) -> None:
    """Load the numba kernels (decoder, stages, encoder) before packets arrive, so the first packets do
    not wait behind compilation and the FIFO does not start with a backlog."""
    from evstream.sources.zenoh_sub import ZenohSubscription  # noqa: F401 - imports the decoders

    from ..codecs.event_packet import decode_packet, encode_packet
    from ..codecs.packets import PacketDecoder, to_packet
    from ..events import Geometry

    rng = np.random.default_rng(0)
    n, g = 2000, Geometry(64, 64)
    t = np.sort(rng.integers(0, 50_000, n)).astype(np.int64)
    x, y, p = rng.integers(0, 64, n), rng.integers(0, 64, n), rng.integers(0, 2, n)
    data = encode_packet(to_packet(t, x, y, p, width=g.width, height=g.height))
    t, x, y, p = PacketDecoder(absolute=True).decode(decode_packet(data))
    PacketDecoder(absolute=False).decode(decode_packet(data))
    pipeline = pipeline_from_args(args, None)
    attach_framer(pipeline, args)
    pipeline.process(EventChunk.from_arrays(t, x, y, p, g)).events.of_class(0)
    pipeline.finish(g)
    # the sinks a camera opens on its first packet (their imports alone take ~50 ms each)
    if getattr(args, "republish", None):
        import evstream.sinks.zenoh_pub  # noqa: F401
    if getattr(args, "archive", None):
        import evstream.sinks.mcap_sink  # noqa: F401


def wait_readers(session, keyexpr: str, timeout_s: float) -> bool:
    """Wait for a subscriber of the cleaned stream before subscribing to the raw one: once packets fill the
    FIFO, Zenoh's receive thread is blocked and would not hear of new subscribers until the FIFO drains."""
    probe = session.declare_publisher(keyexpr)
    deadline = time.monotonic() + timeout_s
    while not probe.matching_status.matching:
        if time.monotonic() > deadline:
            print(f"evstream: warning: no subscriber on {keyexpr} after {timeout_s:g} s", file=sys.stderr)
            return False
        time.sleep(0.01)
    return True


class Status:
    """A status line on a terminal (events, events/s, gaps, bad packets); silent when piped."""

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.enabled = stream.isatty()
        self._last = 0.0
        self._t0 = time.monotonic()

    def __call__(self, sub) -> None:
        now = time.monotonic()
        if not self.enabled or now - self._last < 0.25:
            return
        self._last = now
        t = sub.totals()
        rate = t["events"] / max(now - self._t0, 1e-9)
        self.stream.write(f"\r{t['events']:,} events  {rate / 1e6:.2f} M ev/s  {len(sub.cameras)} camera(s)  "
                          f"missing {t['missing']:,}  bad {t['malformed'] + t['oversized']:,}\x1b[K")
        self.stream.flush()

    def done(self) -> None:
        if self.enabled:
            self.stream.write("\r\x1b[K")
            self.stream.flush()


def print_summary(s: dict) -> None:
    print(f"{counted(s['events'], 'event')} in {counted(s['packets'], 'packet')} from {len(s['cameras'])} camera(s) "
          f"in {s['wall_s']:.2f} s; stopped by {s['stopped_by']}")
    for name, c in s["cameras"].items():
        line = (f"  {name}: {counted(c['events'], 'event')}, {counted(c['packets'], 'packet')}; "
                f"missing {c['missing']:,} in {c['gaps']:,} gap(s); malformed {c['malformed']:,}, "
                f"oversized {c['oversized']:,}; "
                f"restarts {c['restarts']}")
        if "events_signal" in c:
            line += (f"; signal {c['events_signal']:,}, background {c['events_background']:,}, "
                     f"hot pixel {c['events_hot_pixel']:,}")
        if "latency_p50_ms" in c:
            line += f"; latency p50 {c['latency_p50_ms']:.1f} ms, p99 {c['latency_p99_ms']:.1f} ms"
            if "latency_warm_p99_ms" in c:
                line += f" (after the first second: p99 {c['latency_warm_p99_ms']:.1f} ms)"
        print(line)
        if "points_drawn" in c:
            print(f"    viewer: {counted(c['points_drawn'], 'point')} drawn, {c['points_dropped']:,} dropped "
                  f"({c['points_late']:,} of them because the viewer fell behind; the rest by the point budgets); "
                  "frames and statistics use every event")
        if c.get("published_packets"):
            print(f"    republished {counted(c['published_events'], 'event')} in "
                  f"{counted(c['published_packets'], 'packet')}"
                  + (f"; {c['published_unmatched_packets']:,} of them while no subscriber matched: nobody "
                     "received those" if c.get("published_unmatched_packets") else ""))
        for path in c.get("archives", []):
            print(f"    wrote {path}")
