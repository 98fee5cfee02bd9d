"""Opening Zenoh sessions the way evstream wants them: explicit endpoints, loopback by default.

Zenoh's own defaults listen on every interface and scout by multicast; a session opened here listens
and connects only where it is told (`tcp/127.0.0.1:7447` when nothing is said), multicast scouting
stays off unless asked, and the transport drops any message over `message_limit(max_packet_bytes)`
while reassembling it (Zenoh's `transport/link/rx/max_message_size`), so a huge put never reaches the
memory of a router or subscriber opened here. Shared by `sources.zenoh_sub`, `sinks.zenoh_pub` and `evstream router`.
"""

from __future__ import annotations

import json
import re
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: every command's parser names this module's defaults (start-up)
    import zenoh

__all__ = [
    "BLOCK_WAIT_BEFORE_CLOSE_S", "DEFAULT_ENDPOINT", "DEFAULT_MAX_PACKET_BYTES", "MESSAGE_OVERHEAD_BYTES", "MODES",
    "check_endpoint", "config", "drain", "endpoints", "message_limit", "open_session", "watch_transports",
]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_MAX_PACKET_BYTES = 64 << 20  # the largest EventPacket payload a subscriber or router takes
MESSAGE_OVERHEAD_BYTES = 64 << 10  # key, encoding, attachment and framing around a payload
# How long a BLOCK put may wait for room in a link's queue before Zenoh closes the link. Zenoh's default,
# 5 s, cut off a subscriber that paused 5 s and lost everything in flight. As long as the link lease
# (10 s), which ends the link of a peer that reads nothing for that long anyway: longer only held every
# publisher behind a router that long after a subscriber had gone (60 s measured with 60).
BLOCK_WAIT_BEFORE_CLOSE_S = 10.0
MODES = ("peer", "client", "router")
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/[^\s]+$")


def check_endpoint(endpoint: str) -> str:
    """`proto/address:port` (e.g. tcp/127.0.0.1:7447); ValueError naming what is wrong otherwise."""
    if not _ENDPOINT.match(endpoint):
        raise ValueError(f"Zenoh endpoint {endpoint!r}: expected PROTO/ADDRESS:PORT, e.g. {DEFAULT_ENDPOINT}")
    return endpoint


def message_limit(max_packet_bytes: int) -> int:
    """The largest Zenoh message (payload and its headers) a session takes for packets of `max_packet_bytes`."""
    return int(max_packet_bytes) + MESSAGE_OVERHEAD_BYTES


def config(*, mode: str = "peer", listen=(), connect=(), multicast: bool = False,
           max_packet_bytes: int = DEFAULT_MAX_PACKET_BYTES) -> zenoh.Config:
    """A Zenoh config with exactly these endpoints (none of Zenoh's all-interfaces defaults), refusing
    messages over `message_limit(max_packet_bytes)` (Zenoh's default is 1 GiB)."""
    import zenoh

    if mode not in MODES:
        raise ValueError(f"Zenoh mode {mode!r}: choose from {', '.join(MODES)}")
    listen = [check_endpoint(e) for e in listen]
    connect = [check_endpoint(e) for e in connect]
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("listen/endpoints", json.dumps(listen))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    c.insert_json5("transport/link/rx/max_message_size", json.dumps(message_limit(max_packet_bytes)))
    c.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close",
                   json.dumps(int(BLOCK_WAIT_BEFORE_CLOSE_S * 1e6)))
    return c


def endpoints(mode: str | None, listen=(), connect=()) -> tuple[str, list[str], list[str]]:
    """The mode and endpoints a session gets: with neither `listen` nor `connect`, a router listens on
    DEFAULT_ENDPOINT and anything else connects there as a client (so `evstream router`, `evstream
    subscribe`, `evstream publish` with no flags meet); a mode left open is client when only connecting,
    else peer."""
    listen, connect = list(listen), list(connect)
    if not listen and not connect:
        (listen if mode == "router" else connect).append(DEFAULT_ENDPOINT)
    if mode is None:
        mode = "client" if connect and not listen else "peer"
    return mode, listen, connect


def open_session(*, mode: str | None = None, listen=(), connect=(), multicast: bool = False,
                 max_packet_bytes: int = DEFAULT_MAX_PACKET_BYTES, config_json: dict | None = None) -> zenoh.Session:
    """Open a session. With neither `listen` nor `connect`: a router listens on DEFAULT_ENDPOINT, anything
    else is a client of the router there (where `evstream router` with no flags listens). `mode` defaults to
    client when only connecting (all traffic through the router), peer otherwise. `config_json`: more
    Zenoh config keys (path -> value), e.g. queue sizes. `max_packet_bytes`: larger messages are dropped
    by the transport while being reassembled (see `message_limit`).

    A client whose router is not there fails at once (Zenoh's client default: no retry), with an OSError
    naming the endpoint and how to start a router."""
    import zenoh

    mode, listen, connect = endpoints(mode, listen, connect)
    cfg = config(mode=mode, listen=listen, connect=connect, multicast=multicast,
                 max_packet_bytes=max_packet_bytes)
    for key, value in (config_json or {}).items():
        cfg.insert_json5(key, json.dumps(value))
    try:
        return zenoh.open(cfg)
    except zenoh.ZError as e:
        where = ", ".join([*(f"listen {x}" for x in listen), *(f"connect {x}" for x in connect)])
        reason = str(e).split(" at /")[0].strip().rstrip("!")  # drop the Rust source location
        hint = ""
        if mode == "client" and "connect" in reason.lower():
            hint = ("; is a Zenoh router running there? start one with `evstream router`"
                    + ("" if connect == [DEFAULT_ENDPOINT] else f" --listen {connect[0]}"))
        raise OSError(f"cannot open a Zenoh {mode} session ({where}): {reason}{hint}") from None


def drain(session: zenoh.Session, timeout_s: float = 10.0) -> bool:
    """Wait until the next hop (router or peer) has received everything this session queued.

    `put` returns once a message is in the session's transmit queue, and closing a session discards
    that queue. A query to the Zenoh admin space travels behind the data on the same priority, and the
    hop answers only after taking in what came before it; so when the query completes, the data left.
    True if it completed within `timeout_s`.
    """
    import zenoh

    t0 = time.monotonic()
    try:
        for _ in session.get("@/**", timeout=timeout_s, congestion_control=zenoh.CongestionControl.BLOCK,
                             priority=zenoh.Priority.DATA):
            pass
    except zenoh.ZError:
        return False
    return time.monotonic() - t0 < timeout_s


def watch_transports(session: zenoh.Session, warn) -> object:
    """Call `warn(message)` when a connection to a router or peer closes or comes back.

    Zenoh reconnects by itself, so a subscriber whose router died would otherwise wait in silence while
    whatever is published meanwhile is lost. Keep the returned listener alive for as long as you watch.
    """
    import zenoh

    def on_event(event) -> None:
        t = event.transport
        what = str(t.whatami).split(".")[-1].lower()
        if event.kind == zenoh.SampleKind.DELETE:
            warn(f"lost the connection to {what} {t.zid}; waiting for it to come back (events published "
                 "meanwhile do not arrive)")
        else:
            warn(f"connected to {what} {t.zid}")

    return session.info.declare_transport_events_listener(on_event, history=False)
