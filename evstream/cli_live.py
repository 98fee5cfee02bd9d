"""`evstream publish | subscribe | router` — live streams over Zenoh (part of the CLI's composition root).

publish   plays a recording as a live camera: EventPackets on `evstream/<camera>/events`, paced by `--speed`.
subscribe takes `KEYEXPR` (wildcards: one pipeline per camera) into any sink: the Rerun viewer, an MCAP
          archive, or `--republish` (a denoise node: raw in, cleaned stream out on `.../events/clean`).
router    runs a Zenoh router that cameras and nodes on several machines meet through.

Every session listens and connects only where told (loopback by default), multicast scouting off.
`--connect` here names a Zenoh endpoint; a running Rerun viewer is `--viewer URL` (as in `replay`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from .events import EventChunk, NoiseClass, concat
from .pipeline import paced

DEFAULT_KEY = "evstream/camera/events"
CLEAN_KEY = "evstream/{camera}/events/clean"


# -- shared flags ---------------------------------------------------------------------------------
def _add_zenoh_flags(p, *, router: bool = False) -> None:
    from evstream.sources.zenoh_session import DEFAULT_ENDPOINT

    p.add_argument("--listen", metavar="ENDPOINT", action="append", default=[],
                   help=f"Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)"
                        f"{'; default ' + DEFAULT_ENDPOINT if router else ''}")
    p.add_argument("--connect", metavar="ENDPOINT", action="append", default=[],
                   help="Zenoh endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)"
                        + ("" if router else f"; default {DEFAULT_ENDPOINT} when neither is given"))
    if not router:
        p.add_argument("--mode", choices=["client", "peer"],
                       help="Zenoh mode (default: client when only connecting, else peer)")
    p.add_argument("--multicast", action="store_true", help="enable Zenoh multicast scouting (off by default)")


def _session(args, mode=None):
    from evstream.sources.zenoh_session import open_session

    return open_session(mode=mode or getattr(args, "mode", None), listen=args.listen, connect=args.connect,
                        multicast=args.multicast)


def _check_endpoints(args) -> None:
    from evstream.sources.zenoh_session import check_endpoint

    from .cli import UsageError

    for e in [*args.listen, *args.connect]:
        try:
            check_endpoint(e)
        except ValueError as err:
            raise UsageError(str(err)) from None


# -- publish ----------------------------------------------------------------------------------------
def packetize(chunks, packet_us: int):
    """Re-cut a stream into packets, one per cell of an event-time grid anchored at t = 0."""
    pending: list[EventChunk] = []
    cell = None
    for chunk in chunks:
        if not len(chunk):
            continue
        cells = chunk.t // packet_us
        edges = [0, *(np.flatnonzero(np.diff(cells)) + 1).tolist(), len(chunk)]
        for a, b in zip(edges[:-1], edges[1:]):
            c = int(cells[a])
            if cell is not None and c != cell and pending:
                yield concat(pending, chunk.geometry)
                pending = []
            cell = c
            pending.append(chunk[a:b])
    if pending:
        yield concat(pending, pending[0].geometry)


def cmd_publish(args) -> int:
    import signal

    from evstream.sinks.zenoh_pub import PacketPublisher, linger
    from evstream.sources.zenoh_session import drain
    from evstream.sources.zenoh_sub import camera_of

    from .cli import UsageError, _check_numbers, _open, _StopOnSignal, event_rate

    _check_numbers(args, at_least_zero=("speed", "wait_subscribers", "drain_s"))
    if any(c in args.key for c in "*$?#"):
        raise UsageError(f"--key {args.key}: a publisher needs a concrete key, no wildcards")
    if args.packet_us <= 0:
        raise UsageError(f"--packet-us {args.packet_us}: must be positive")
    _check_endpoints(args)
    source = _open(args.source, args)
    g = source.geometry
    session = _session(args)
    try:
        pub = PacketPublisher(session, args.key, congestion=args.congestion, frame_id=camera_of(args.key))
        if args.wait_subscribers > 0 and not pub.wait_matching(args.wait_subscribers):
            print(f"evstream: warning: no subscriber on {args.key} after {args.wait_subscribers:g} s; "
                  "publishing anyway", file=sys.stderr)
        t0 = time.perf_counter()
        unmatched_packets = unmatched_events = 0  # put while no subscriber matched: they went to no one
        with _StopOnSignal() as stop:
            for packet in stop.chunks(paced(packetize(source, args.packet_us), args.speed)):
                matched, before = pub.matching, pub.packets
                pub.put_events(packet.t, packet.x, packet.y, packet.p, width=g.width, height=g.height)
                if not matched:
                    unmatched_packets += pub.packets - before
                    unmatched_events += len(packet)
        wall = time.perf_counter() - t0
        pub.end()
        drain(session, args.drain_s)
        if not linger([pub], args.drain_s) and pub.matching:
            print(f"evstream: note: subscribers still there after --drain-s {args.drain_s:g}; closing",
                  file=sys.stderr)
        pub.close()
    finally:
        session.close()
    summary = {"key": args.key, "packets": pub.packets, "events": pub.events, "bytes": pub.bytes,
               "unmatched_packets": unmatched_packets, "unmatched_events": unmatched_events,
               "wall_s": wall, "events_per_s": pub.events / wall if wall > 0 else 0.0,
               "stopped_by": signal.Signals(stop.signum).name if stop.signum else None}
    if unmatched_packets:  # a router or the subscribers that went away must not look like a delivery
        print(f"evstream: warning: {unmatched_packets:,} of {pub.packets:,} packets ({unmatched_events:,} events) "
              f"went out while no subscriber matched {args.key} (none yet, or the subscribers or the router "
              "went away): nobody received them", file=sys.stderr)
    if args.json:
        print(json.dumps(summary), flush=True)
    else:
        print(f"published {pub.events:,} events in {pub.packets:,} packets on {args.key} "
              f"({event_rate(summary['events_per_s'])})")
    return 0


# -- subscribe --------------------------------------------------------------------------------------
def _archive_path(template: str, camera: str, wildcard: bool, segment: int) -> str:
    if "{camera}" in template:
        path = template.replace("{camera}", camera)
    elif wildcard:
        path = str(Path(template).with_suffix(f".{camera}.mcap"))
    else:
        path = template
    if segment:
        path = str(Path(path).with_suffix(f".{segment}.mcap"))
    return path


def _topic_camera(camera: str) -> str:
    """A camera name the MCAP topics accept (letters, digits, '_', starting with a letter)."""
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in camera)
    return name if name[:1].isalpha() else "c" + name


class _Camera:
    """One camera's pipeline and sinks (opened on its first packet, reopened when its publisher restarts)."""

    def __init__(self, name: str, node: Subscriber, geometry):
        self.name = name
        self.node = node
        self.segment = 0
        self.per_class = np.zeros(len(NoiseClass), np.int64)
        self.frames = 0
        self.published_events = 0
        self.published_packets = 0
        self.archives: list[str] = []
        self.open(geometry)

    def open(self, geometry) -> None:
        from .cli import _attach_framer, _pipeline

        args, node = self.node.args, self.node
        self.pipeline = _pipeline(args, None)
        _attach_framer(self.pipeline, args)
        self.sinks = []
        self.pub = None
        if args.archive:
            from evstream.sinks.mcap_sink import McapSink

            path = _archive_path(args.archive, self.name, node.wildcard, self.segment)
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            meta = {"source": f"zenoh:{node.keyexpr}", "camera_key_name": self.name,
                    "pipeline": self.pipeline.describe(), "command": sys.argv[1:] or None}
            self.sinks.append(McapSink(path, camera=_topic_camera(self.name), keep_noise=args.keep_noise,
                                       frames=self.pipeline.framer is not None, metadata=meta, geometry=geometry,
                                       flush_s=args.flush_s))
            self.archives.append(path)
        if node.viewer is not None:
            from evstream.sinks.rerun_sink import RerunSink

            self.sinks.append(RerunSink(node.viewer_rec(self.name), geometry=geometry,
                                        framer=getattr(self.pipeline.framer, "kind", None),
                                        point_budget_hz=args.point_budget or None, slab_ms=args.slab_ms,
                                        play_state=None if node.viewer.mode == "save" else "following"))
        if args.republish:
            from evstream.sinks.zenoh_pub import ZenohSink, frames_key_for

            key = args.republish.replace("{camera}", self.name)
            self.pub = ZenohSink(node.session, key, congestion="block", frame_id=self.name,
                                 frames_key=frames_key_for(key) if self.pipeline.framer is not None else None)

    def process(self, packet) -> None:
        batch = self.pipeline.process(packet.chunk)
        for sink in self.sinks:
            sink.write(batch)
        if self.pub is not None:
            self.pub.write(batch, source_time_ns=packet.source_time_ns)

    def close(self) -> None:
        """Finish the pipeline (frames still open), close the sinks (files complete, end mark sent)."""
        batch = self.pipeline.finish(self.node.geometry_of[self.name])
        sinks = self.sinks + ([self.pub] if self.pub is not None else [])
        try:
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
        self.cameras: dict[str, _Camera] = {}
        self.geometry_of: dict = {}
        self.viewer = None
        self._recs: dict = {}
        self.saved: list[str] = []  # the .rrd files written (with --save)

    def viewer_rec(self, camera: str):
        """The first camera logs into the viewer's recording; others get recordings of their own."""
        if camera in self._recs:
            return self._recs[camera]
        if not self._recs:
            rec = self.viewer.rec
        else:
            import rerun as rr

            rec = rr.RecordingStream("evstream", recording_id=f"evstream-{camera}")
            if self.viewer.mode == "save":
                path = str(Path(self.viewer.path).with_suffix(f".{camera}.rrd"))
                rec.save(path)
                self.saved.append(path)
            else:
                rec.connect_grpc(self.viewer.grpc_url)
        self._recs[camera] = rec
        return rec


def cmd_subscribe(args) -> int:
    import signal

    from evstream.sources.zenoh_sub import End, ZenohSubscription

    from .cli import UsageError, _check_numbers, _geometry_flag, _StopOnSignal

    _check_endpoints(args)
    _check_numbers(args, at_least_zero=("wait_subscribers", "drain_s"), positive=("slab_ms", "flush_s"))
    viewer_flags = [o for o in ("save", "spawn", "serve", "viewer") if getattr(args, o)]
    if len(viewer_flags) > 1:
        raise UsageError(f"--{viewer_flags[0]} and --{viewer_flags[1]}: choose one place for the Rerun output")
    if args.archive and not args.archive.endswith(".mcap"):
        raise UsageError(f"--archive {args.archive}: the archive's name must end in .mcap")
    if args.archive:  # its folder now, not at the first packet (which ended the node mid-stream)
        parts = Path(args.archive).parent.parts
        folder = Path(*parts[: next((i for i, q in enumerate(parts) if "{camera}" in q), len(parts))] or ".")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OSError(f"--archive {args.archive}: cannot create {folder}: {e.strerror or e}") from None
    if args.republish and any(c in args.republish.replace("{camera}", "") for c in "*$?#"):
        raise UsageError(f"--republish {args.republish}: a concrete key (with {{camera}}), no wildcards")
    for name in ("depth", "max_packet_bytes"):
        if getattr(args, name) < 1:
            raise UsageError(f"--{name.replace('_', '-')} {getattr(args, name)}: must be >= 1")
    for name in ("idle_s", "duration_s"):
        if getattr(args, name) is not None and getattr(args, name) <= 0:
            raise UsageError(f"--{name.replace('_', '-')} {getattr(args, name)}: must be positive")
    flow = args.flow or ("ring" if viewer_flags and not (args.archive or args.republish) else "block")
    geometry = None
    if args.geometry:
        geometry = _geometry_flag(args.geometry)
    node = Subscriber(args)
    if viewer_flags:
        from evstream.sinks.rerun_viewer import open_output

        node.viewer = open_output(save=args.save, spawn=args.spawn, serve=args.serve, connect=args.viewer,
                                  bind=args.bind, memory_limit=args.memory_limit)
        if node.viewer.web_url:
            print(f"web viewer: {node.viewer.web_url}", flush=True)
    session = _session(args)
    node.session = session
    from evstream.sources.zenoh_session import watch_transports

    node.transports = watch_transports(session, lambda m: print(f"evstream: {m}", file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
    status = _Status()
    stop_reason = None
    try:
        with _StopOnSignal() as stop:
            def should_stop() -> bool:
                return stop.signum is not None or (deadline is not None and time.monotonic() > deadline)

            _warm_up(args)
            if args.republish and args.wait_subscribers > 0:
                _wait_readers(session, args.republish.replace("{camera}", "*"), args.wait_subscribers)
            sub = ZenohSubscription(args.keyexpr, session=session, flow=flow, depth=args.depth,
                                    max_packet_bytes=args.max_packet_bytes, geometry=geometry,
                                    idle_s=args.idle_s, should_stop=should_stop)
            print(f"subscribed to {args.keyexpr} ({flow})", file=sys.stderr, flush=True)
            try:
                for item in sub:
                    cam = node.cameras.get(item.camera)
                    if isinstance(item, End):
                        # cameras that sent anything count, even if every packet was malformed (no
                        # pipeline was made for those, and waiting for one would never end)
                        seen = [s for s in sub.cameras.values() if s.packets or s.malformed or s.oversized]
                        if (args.until_end and any(s is sub.cameras[item.camera] for s in seen)
                                and len(seen) >= args.until_end and all(s.ended for s in seen)):
                            stop_reason = "end of stream"
                            break
                        continue
                    node.geometry_of[item.camera] = item.chunk.geometry
                    if cam is None:
                        cam = node.cameras[item.camera] = _Camera(item.camera, node, item.chunk.geometry)
                    elif item.restart:
                        print(f"evstream: {item.key}: publisher restarted (sequence {item.seq}); "
                              f"pipeline state reset", file=sys.stderr, flush=True)
                        cam.restart(item.chunk.geometry)
                    cam.process(item)
                    status(sub)
                    if args.delay_ms:
                        time.sleep(args.delay_ms * 1e-3)
            finally:
                publishers = [c.pub.publisher for c in node.cameras.values() if c.pub is not None]
                for cam in node.cameras.values():
                    cam.close()  # end marks sent
                totals = sub.totals()
                stats = {name: s.as_dict() for name, s in sub.cameras.items()}
                sub.close()  # upstream publishers see this reader leave
                if publishers:  # keep the session until the cleaned stream's readers have it all
                    from evstream.sinks.zenoh_pub import linger
                    from evstream.sources.zenoh_session import drain

                    drain(session, args.drain_s)
                    linger(publishers, args.drain_s)
            if stop.signum is not None:
                stop_reason = signal.Signals(stop.signum).name
            elif stop_reason is None:
                stop_reason = "duration" if deadline is not None and time.monotonic() > deadline else "idle"
    finally:
        status.done()
        for rec in list(node._recs.values())[1:]:
            rec.flush()
            rec.disconnect()
        if node.viewer is not None:
            node.viewer.finish()
        session.close()
    wall = time.perf_counter() - t0
    cams = {}
    for name, st in stats.items():
        cam = node.cameras.get(name)
        d = dict(st)
        if cam is not None:
            d.update(events_signal=int(cam.per_class[NoiseClass.SIGNAL]),
                     events_background=int(cam.per_class[NoiseClass.BACKGROUND]),
                     events_hot_pixel=int(cam.per_class[NoiseClass.HOT_PIXEL]), frames=cam.frames,
                     published_events=cam.published_events, published_packets=cam.published_packets,
                     archives=cam.archives)
        cams[name] = d
    summary = {"keyexpr": args.keyexpr, "flow": flow, "cameras": cams, **totals, "wall_s": wall,
               "events_per_s": totals["events"] / wall if wall > 0 else 0.0, "stopped_by": stop_reason}
    if node.viewer is not None:
        summary.update(output=node.viewer.mode, rrd=args.save, web_url=node.viewer.web_url)
    if args.json:
        print(json.dumps(summary), flush=True)
    else:
        _print_summary(summary)
        if args.save:
            from .cli import _rerun_command

            print(f"wrote {', '.join([args.save, *node.saved])} — open with:  {_rerun_command()} FILE", flush=True)
    if node.viewer is not None and node.viewer.mode == "serve":
        print(f"serving {node.viewer.web_url} until Ctrl-C", file=sys.stderr, flush=True)
        try:
            node.viewer.process.wait()
        except KeyboardInterrupt:
            pass
        node.viewer.stop()
    return 0


def _warm_up(args) -> None:
    """Load the numba kernels (decoder, stages, encoder) before packets arrive, so the first packets do
    not wait behind compilation and the FIFO does not start with a backlog."""
    from evstream.sources.zenoh_sub import ZenohSubscription  # noqa: F401 - imports the decoders

    from .cli import _attach_framer, _pipeline
    from .codecs.event_packet import decode_packet, encode_packet
    from .codecs.packets import PacketDecoder, to_packet
    from .events import Geometry

    rng = np.random.default_rng(0)
    n, g = 2000, Geometry(64, 64)
    t = np.sort(rng.integers(0, 50_000, n)).astype(np.int64)
    x, y, p = rng.integers(0, 64, n), rng.integers(0, 64, n), rng.integers(0, 2, n)
    data = encode_packet(to_packet(t, x, y, p, width=g.width, height=g.height))
    t, x, y, p = PacketDecoder(absolute=True).decode(decode_packet(data))
    PacketDecoder(absolute=False).decode(decode_packet(data))
    pipeline = _pipeline(args, None)
    _attach_framer(pipeline, args)
    pipeline.process(EventChunk.from_arrays(t, x, y, p, g)).events.of_class(0)
    pipeline.finish(g)
    # the sinks a camera opens on its first packet (their imports alone take ~50 ms each)
    if getattr(args, "republish", None):
        import evstream.sinks.zenoh_pub  # noqa: F401
    if getattr(args, "archive", None):
        import evstream.sinks.mcap_sink  # noqa: F401


def _wait_readers(session, keyexpr: str, timeout_s: float) -> bool:
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


class _Status:
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


def _print_summary(s: dict) -> None:
    print(f"{s['events']:,} events in {s['packets']:,} packets from {len(s['cameras'])} camera(s) "
          f"in {s['wall_s']:.2f} s; stopped by {s['stopped_by']}")
    for name, c in s["cameras"].items():
        line = (f"  {name}: {c['events']:,} events, {c['packets']:,} packets; missing {c['missing']:,} "
                f"in {c['gaps']:,} gap(s); malformed {c['malformed']:,}, oversized {c['oversized']:,}; "
                f"restarts {c['restarts']}")
        if "events_signal" in c:
            line += (f"; signal {c['events_signal']:,}, background {c['events_background']:,}, "
                     f"hot pixel {c['events_hot_pixel']:,}")
        if "latency_p50_ms" in c:
            line += f"; latency p50 {c['latency_p50_ms']:.1f} ms, p99 {c['latency_p99_ms']:.1f} ms"
            if "latency_warm_p99_ms" in c:
                line += f" (after the first second: p99 {c['latency_warm_p99_ms']:.1f} ms)"
        print(line)
        if c.get("published_packets"):
            print(f"    republished {c['published_events']:,} events in {c['published_packets']:,} packets")
        for path in c.get("archives", []):
            print(f"    wrote {path}")


# -- router -----------------------------------------------------------------------------------------
def cmd_router(args) -> int:
    import signal

    from evstream.sources.zenoh_session import DEFAULT_ENDPOINT

    from .cli import _StopOnSignal

    _check_endpoints(args)
    session = _session(args, mode="router")
    try:
        listen = args.listen or [DEFAULT_ENDPOINT]
        print(f"evstream router {session.zid()} listening on {', '.join(listen)}"
              + (f", connected to {', '.join(args.connect)}" if args.connect else ""), flush=True)
        with _StopOnSignal() as stop:
            deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
            while stop.signum is None and (deadline is None or time.monotonic() < deadline):
                time.sleep(0.1)
    finally:
        session.close()
    if args.json:
        print(json.dumps({"listen": listen, "connect": args.connect,
                          "stopped_by": signal.Signals(stop.signum).name if stop.signum else "duration"}))
    return 0


# -- parsers ----------------------------------------------------------------------------------------
def add_parsers(sub, add_source_flags, add_pipeline_flags, add_framer_flags) -> None:
    p = sub.add_parser("publish", help="play a recording as a live camera over Zenoh")
    p.add_argument("source")
    add_source_flags(p)
    p.add_argument("--key", default=DEFAULT_KEY, help=f"Zenoh key (default {DEFAULT_KEY})")
    p.add_argument("--speed", type=float, default=1.0, help="1 = real time (default), 0 = as fast as possible")
    p.add_argument("--packet-us", type=int, default=10_000, help="event time per packet (default 10000)")
    p.add_argument("--congestion", choices=["block", "drop"], default="block",
                   help="when the network is full: block (default, no loss) or drop")
    p.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                   help="wait up to S seconds for a subscriber before publishing")
    p.add_argument("--drain-s", type=float, default=10.0, metavar="S",
                   help="at the end, wait up to S seconds for subscribers to take the stream and leave "
                        "(default 10)")
    _add_zenoh_flags(p)
    p.add_argument("--json", action="store_true", help="print what was published as JSON")
    p.set_defaults(func=cmd_publish)

    p = sub.add_parser("subscribe", help="clean a live Zenoh stream into the viewer, an archive or Zenoh")
    p.add_argument("keyexpr", help="Zenoh key expression, e.g. evstream/*/events (one pipeline per camera)")
    add_pipeline_flags(p)
    add_framer_flags(p)
    p.add_argument("--geometry", metavar="WxH", help="sensor size for packets that give none")
    p.add_argument("--save", metavar="OUT.rrd", help="write a Rerun recording")
    p.add_argument("--spawn", action="store_true", help="open the desktop viewer")
    p.add_argument("--serve", action="store_true", help="serve the web viewer until Ctrl-C")
    p.add_argument("--viewer", metavar="URL", help="log to a running Rerun viewer (rerun+http://HOST:PORT/proxy)")
    p.add_argument("--bind", metavar="ADDR", default="127.0.0.1", help="address --serve/--spawn listen on")
    p.add_argument("--memory-limit", metavar="SIZE", default="25%", help="viewer memory (--spawn/--serve)")
    p.add_argument("--point-budget", type=int, default=1_000_000, metavar="N",
                   help="most 3D points per second of event time (0 = every event)")
    p.add_argument("--slab-ms", type=float, default=100.0, help="depth of the 3D view's time slab")
    p.add_argument("--archive", metavar="OUT.mcap",
                   help="write an MCAP archive ({camera} in the name: one per camera)")
    p.add_argument("--keep-noise", action="store_true", help="archive the removed events too")
    p.add_argument("--flush-s", type=float, default=1.0, help="archive chunk at least this often")
    p.add_argument("--republish", metavar="KEY", nargs="?", const=CLEAN_KEY,
                   help=f"publish the cleaned stream (default key {CLEAN_KEY})")
    p.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                   help="with --republish: wait up to S seconds for a subscriber of the cleaned stream")
    p.add_argument("--drain-s", type=float, default=10.0, metavar="S",
                   help="with --republish: at the end, wait up to S seconds for the cleaned stream's "
                        "subscribers to take it and leave (default 10)")
    p.add_argument("--flow", choices=["block", "ring"],
                   help="block: FIFO, no loss, backpressure (default for --archive/--republish); "
                        "ring: newest packets only, counted drops (default for the viewer alone)")
    p.add_argument("--depth", type=int, default=64, help="packets the FIFO or ring holds (default 64)")
    p.add_argument("--max-packet-bytes", type=int, default=64 << 20, help="larger packets are skipped")
    p.add_argument("--until-end", nargs="?", const=1, type=int, metavar="N",
                   help="stop when every camera's publisher has ended (and at least N cameras were seen)")
    p.add_argument("--idle-s", type=float, help="stop after this long without a packet")
    p.add_argument("--duration-s", type=float, help="stop after this long")
    p.add_argument("--delay-ms", type=float, default=0.0, help=argparse.SUPPRESS)  # emulate a slow consumer
    _add_zenoh_flags(p)
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.set_defaults(func=cmd_subscribe)

    p = sub.add_parser("router", help="run a Zenoh router (cameras and nodes on several machines meet here)")
    _add_zenoh_flags(p, router=True)
    p.add_argument("--duration-s", type=float, help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true", help="print the endpoints as JSON at exit")
    p.set_defaults(func=cmd_router)
