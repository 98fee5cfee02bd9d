"""`evstream publish`: play a recording as a live camera (EventPackets over Zenoh, paced by --speed)."""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from ..events import EventChunk, concat
from ..pipeline import paced
from .common import StopOnSignal, UsageError, add_source_flags, check_numbers, counted, event_rate, open_recording
from .live import DEFAULT_KEY, add_zenoh_flags, check_endpoints, session_from_args, settle_memory


def packetize(chunks, packet_us: int):
    """Re-cut a stream into packets, one per cell of an event-time grid anchored at t = 0. A cell's end is
    found by binary search (not a division of every timestamp), and a packet within one chunk is a view
    of it: only a packet spanning chunks is copied together."""
    pending: list[EventChunk] = []
    cell = None
    for chunk in chunks:
        n = len(chunk)
        a = 0
        while a < n:
            c = int(chunk.t[a]) // packet_us
            if cell is not None and c != cell and pending:
                yield pending[0] if len(pending) == 1 else concat(pending, chunk.geometry)
                pending = []
            cell = c
            b = a + int(np.searchsorted(chunk.t[a:], (c + 1) * packet_us, side="left"))
            pending.append(chunk if a == 0 and b == n else chunk[a:b])
            a = b
    if pending:
        yield pending[0] if len(pending) == 1 else concat(pending, pending[0].geometry)


def warm_encoder(geometry, encoding: str) -> None:
    """Encode one made-up event into a packet: the encoder's numba kernels are loaded before the stream
    starts, so the first packet leaves at once and the rate is the stream's."""
    from evstream.codecs.event_packet import encode_packet
    from evstream.codecs.packets import to_packet

    one = np.zeros(1, np.int64)
    encode_packet(to_packet(one, one.astype(np.uint16), one.astype(np.uint16), one.astype(np.uint8),
                            width=geometry.width, height=geometry.height, encoding=encoding))


def cmd_publish(args) -> int:
    import signal

    from evstream.sinks.zenoh_pub import PacketPublisher, linger
    from evstream.sources.zenoh_session import drain
    from evstream.sources.zenoh_sub import camera_of


    check_numbers(args, at_least_zero=("speed", "wait_subscribers", "drain_s"))
    if any(c in args.key for c in "*$?#"):
        raise UsageError(f"--key {args.key}: a publisher needs a concrete key, no wildcards")
    if args.packet_us <= 0:
        raise UsageError(f"--packet-us {args.packet_us}: must be positive")
    check_endpoints(args)
    source = open_recording(args.source, args)
    g = source.geometry
    session = session_from_args(args)
    t_open = time.perf_counter()
    waited = drained = 0.0
    first = last = None  # when the first packet's put began and the last one's ended
    try:
        pub = PacketPublisher(session, args.key, congestion=args.congestion, frame_id=camera_of(args.key))
        warm_encoder(g, pub.encoding)  # the packet encoder's kernels load now (~0.5 s), not in the first packet's put
        if args.wait_subscribers > 0:
            t = time.perf_counter()
            matched = pub.wait_matching(args.wait_subscribers)
            waited = time.perf_counter() - t
            if not matched:
                print(f"evstream: warning: no subscriber on {args.key} after {args.wait_subscribers:g} s; "
                      "publishing anyway", file=sys.stderr)
        settle_memory()
        cpu0 = time.process_time()
        with StopOnSignal() as stop:
            for packet in stop.chunks(paced(packetize(source, args.packet_us), args.speed)):
                now = time.perf_counter()
                first = now if first is None else first
                pub.put_events(packet.t, packet.x, packet.y, packet.p, width=g.width, height=g.height)
                last = time.perf_counter()
        t = time.perf_counter()
        pub.end()
        drain(session, args.drain_s)
        if not linger([pub], args.drain_s) and pub.matching:
            print(f"evstream: note: subscribers still there after --drain-s {args.drain_s:g}; closing",
                  file=sys.stderr)
        pub.close()
        drained = time.perf_counter() - t
        cpu_s = time.process_time() - cpu0  # every thread's, Zenoh's too: publishing and draining
    finally:
        session.close()
    wall = time.perf_counter() - t_open
    stream_s = last - first if first is not None else 0.0
    unmatched_packets, unmatched_events = pub.unmatched_packets, pub.unmatched_events
    # the rate is over the streaming only: from the first packet's put to the end of the last one's, not the
    # wait for a subscriber before it nor the drain after it (both were counted in it once: a 1 s recording
    # published after a 10 s wait said 25 k ev/s)
    summary = {"key": args.key, "packets": pub.packets, "events": pub.events, "bytes": pub.bytes,
               "unmatched_packets": unmatched_packets, "unmatched_events": unmatched_events,
               "stream_s": stream_s, "events_per_s": pub.events / stream_s if stream_s > 0 else 0.0,
               "waited_s": waited, "drained_s": drained, "wall_s": wall, "cpu_s": cpu_s,
               "stopped_by": signal.Signals(stop.signum).name if stop.signum else None}
    if unmatched_packets:  # a router or the subscribers that went away must not look like a delivery
        print(f"evstream: warning: {unmatched_packets:,} of {counted(pub.packets, 'packet')} "
              f"({counted(unmatched_events, 'event')}) "
              f"went out while no subscriber matched {args.key} (none yet, or the subscribers or the router "
              "went away): nobody received them", file=sys.stderr)
    if args.json:
        print(json.dumps(summary), flush=True)
    else:
        paced_by = f", paced at --speed {args.speed:g}" if args.speed > 0 else ""
        not_counted = [f"{s:.1f} s {what}" for s, what in ((waited, "waiting for a subscriber"),
                                                           (drained, "draining")) if s >= 0.05]
        print(f"published {counted(pub.events, 'event')} in {counted(pub.packets, 'packet')} on {args.key}: "
              f"{event_rate(summary['events_per_s'])} over the {stream_s:.2f} s from the first packet to the "
              f"last{paced_by}" + (f" (not counted: {', '.join(not_counted)})" if not_counted else ""))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("publish", help="play a recording as a live camera over Zenoh")
    p.add_argument("source", metavar="REC", help="a recording, any format evstream reads (docs/formats.md)")
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
    add_zenoh_flags(p)
    p.add_argument("--json", action="store_true", help="print what was published as JSON")
    p.set_defaults(func=cmd_publish)
