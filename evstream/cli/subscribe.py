"""`evstream subscribe`: clean a live Zenoh stream (one pipeline per camera) into the viewer, MCAP or Zenoh."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
from pathlib import Path

from ..events import NoiseClass
from ..framing import options as framer_options
from .common import (
    StopOnSignal,
    UsageError,
    add_pipeline_flags,
    check_numbers,
    geometry_flag,
)
from .live import CLEAN_KEY, add_zenoh_flags, check_endpoints, session_from_args, settle_memory
from .rerun_file import check_rrd_name, rerun_command
from .subscriber import Camera, Status, Subscriber, print_summary, wait_readers, warm_up

# At most this many events of a republishing node's backlog are cleaned and republished as one packet
# (`ZenohSubscription.batches`): 20 ms at 10 M events/s.
REPUBLISH_BATCH_EVENTS = 200_000


def cmd_subscribe(args) -> int:
    import signal

    from evstream.sources.zenoh_sub import End, ZenohSubscription


    check_endpoints(args)
    check_numbers(args, at_least_zero=("wait_subscribers", "drain_s"), positive=("slab_ms", "flush_s"))
    viewer_flags = [o for o in ("save", "spawn", "serve", "viewer") if getattr(args, o)]
    if len(viewer_flags) > 1:
        raise UsageError(f"--{viewer_flags[0]} and --{viewer_flags[1]}: choose one place for the Rerun output")
    check_rrd_name(args.save)
    if args.archive and not args.archive.endswith(".mcap"):
        raise UsageError(f"--archive {args.archive}: the archive's name must end in .mcap")
    if args.archive:  # its folder now, not at the first packet (which ended the node mid-stream)
        parts = Path(args.archive).parent.parts
        folder = Path(*parts[: next((i for i, q in enumerate(parts) if "{camera}" in q), len(parts))] or ".")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OSError(f"--archive {args.archive}: cannot create {folder}: {e.strerror or e}") from None
        try:  # and writable: a read-only folder was found at the first camera, its stream lost
            tempfile.TemporaryFile(dir=folder).close()
        except OSError as e:
            raise OSError(f"--archive {args.archive}: cannot write in {folder}: {e.strerror or e}") from None
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
        geometry = geometry_flag(args.geometry)
    node = Subscriber(args)
    if viewer_flags:
        from evstream.sinks.rerun_viewer import open_output

        node.viewer = open_output(save=args.save, spawn=args.spawn, serve=args.serve, connect=args.viewer,
                                  bind=args.bind, memory_limit=args.memory_limit)
        if node.viewer.web_url:
            print(f"web viewer: {node.viewer.web_url}", flush=True)
    session = session_from_args(args)
    node.session = session
    from evstream.sources.zenoh_session import watch_transports

    node.transports = watch_transports(session, lambda m: print(f"evstream: {m}", file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
    status = Status()
    stop_reason = None
    try:
        with StopOnSignal() as stop, (node.viewer.guard() if node.viewer else contextlib.nullcontext()):
            def should_stop() -> bool:
                return stop.signum is not None or (deadline is not None and time.monotonic() > deadline)

            warm_up(args)
            settle_memory()
            if args.republish and args.wait_subscribers > 0:
                wait_readers(session, args.republish.replace("{camera}", "*"), args.wait_subscribers)
            sub = ZenohSubscription(args.keyexpr, session=session, flow=flow, depth=args.depth,
                                    max_packet_bytes=args.max_packet_bytes, geometry=geometry,
                                    idle_s=args.idle_s, should_stop=should_stop)
            print(f"subscribed to {args.keyexpr} ({flow})", file=sys.stderr, flush=True)
            try:
                # a node republishing takes a backlog as one batch (per-packet costs once); what a viewer or
                # an archive gets stays packet by packet
                for item in (sub.batches(REPUBLISH_BATCH_EVENTS) if args.republish else sub):
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
                        cam = node.cameras[item.camera] = Camera(item.camera, node, item.chunk.geometry)
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
        node.finish_recordings()
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
                     published_unmatched_packets=cam.published_unmatched_packets,
                     archives=cam.archives)
            if cam.viewer_sink is not None:
                d.update(points_drawn=cam.viewer_sink.points_logged, points_dropped=cam.viewer_sink.points_dropped,
                         points_late=cam.viewer_sink.points_late)
        cams[name] = d
    summary = {"keyexpr": args.keyexpr, "flow": flow, "cameras": cams, **totals, "wall_s": wall,
               "events_per_s": totals["events"] / wall if wall > 0 else 0.0, "stopped_by": stop_reason}
    if node.viewer is not None:
        summary.update(output=node.viewer.mode, rrd=args.save, web_url=node.viewer.web_url)
    if args.json:
        print(json.dumps(summary), flush=True)
    else:
        print_summary(summary)
        if args.save:

            print(f"wrote {', '.join([args.save, *node.saved])} — open with:  {rerun_command()} FILE", flush=True)
    if node.viewer is not None and node.viewer.mode == "serve":
        print(f"serving {node.viewer.web_url} until Ctrl-C", file=sys.stderr, flush=True)
        try:
            node.viewer.process.wait()
        except KeyboardInterrupt:
            pass
        node.viewer.stop()
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("subscribe", help="clean a live Zenoh stream into the viewer, an archive or Zenoh")
    p.add_argument("keyexpr", help="Zenoh key expression, e.g. evstream/*/events (one pipeline per camera)")
    add_pipeline_flags(p)
    framer_options.add_framer_flags(p)
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
    add_zenoh_flags(p)
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.set_defaults(func=cmd_subscribe)
