"""`evstream router`: a Zenoh router that cameras and nodes on several machines meet through."""

from __future__ import annotations

import argparse
import json
import time

from .common import StopOnSignal
from .live import add_zenoh_flags, check_endpoints, session_from_args


def cmd_router(args) -> int:
    import signal

    from evstream.sources.zenoh_session import DEFAULT_ENDPOINT


    check_endpoints(args)
    session = session_from_args(args, mode="router")
    try:
        listen = args.listen or [DEFAULT_ENDPOINT]
        print(f"evstream router {session.zid()} listening on {', '.join(listen)}"
              + (f", connected to {', '.join(args.connect)}" if args.connect else ""), flush=True)
        with StopOnSignal() as stop:
            deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
            while stop.signum is None and (deadline is None or time.monotonic() < deadline):
                time.sleep(0.1)
    finally:
        session.close()
    if args.json:
        print(json.dumps({"listen": listen, "connect": args.connect,
                          "stopped_by": signal.Signals(stop.signum).name if stop.signum else "duration"}))
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("router", help="run a Zenoh router (cameras and nodes on several machines meet here)")
    add_zenoh_flags(p, router=True)
    p.add_argument("--max-packet-bytes", type=int, default=64 << 20,
                   help="larger messages are dropped before they fill the router's memory (default 64 MiB)")
    p.add_argument("--duration-s", type=float, help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true", help="print the endpoints as JSON at exit")
    p.set_defaults(func=cmd_router)
