"""`evstream publish | subscribe | router` — live streams over Zenoh (publish.py, subscribe.py, router.py).

publish   plays a recording as a live camera: EventPackets on `evstream/<camera>/events`, paced by `--speed`.
subscribe takes `KEYEXPR` (wildcards: one pipeline per camera) into any sink: the Rerun viewer, an MCAP
          archive, or `--republish` (a denoise node: raw in, cleaned stream out on `.../events/clean`).
router    runs a Zenoh router that cameras and nodes on several machines meet through.

Every session listens and connects only where told (loopback by default), multicast scouting off.
`--connect` here names a Zenoh endpoint; a running Rerun viewer is `--viewer URL` (as in `replay`).
This module holds what the three share (Zenoh flags, the session, endpoint checks).
"""

from __future__ import annotations

import gc

from .common import UsageError

DEFAULT_KEY = "evstream/camera/events"
CLEAN_KEY = "evstream/{camera}/events/clean"


def add_zenoh_flags(p, *, router: bool = False) -> None:
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


def session_from_args(args, mode=None):
    from evstream.sources.zenoh_session import open_session

    return open_session(mode=mode or getattr(args, "mode", None), listen=args.listen, connect=args.connect,
                        multicast=args.multicast, **({"max_packet_bytes": args.max_packet_bytes}
                                                     if getattr(args, "max_packet_bytes", None) else {}))


def check_endpoints(args) -> None:
    from evstream.sources.zenoh_session import check_endpoint


    for e in [*args.listen, *args.connect]:
        try:
            check_endpoint(e)
        except ValueError as err:
            raise UsageError(str(err)) from None


def settle_memory() -> None:
    """Before a live process starts streaming: what exists by now (imports, numba's and Zenoh's objects,
    warmed kernels: several hundred thousand objects that live as long as the process) is moved out of
    the cyclic garbage collector's sight (`gc.freeze`), so its collections during the stream walk only
    what the stream makes. Measured in benchmarks/bench_live.py: the collector's walks had taken 10-25 %
    of a node's and a subscriber's CPU. (No collection first: it cost ~0.1 s of start-up, for garbage
    of a few objects.)"""
    gc.freeze()
