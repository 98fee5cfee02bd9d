"""Live chain on loopback: publisher -> router -> denoise node (paper's cascade, --republish) -> subscriber of
the cleaned stream, each a separate process, at 1 M and 10 M events/s of offered load.

Offered load: a ~1 M events/s recording (turntable + injected noise, as bench_viewer) published at
`--speed` = load / recording rate. Reported: events/s sustained end to end (cleaned-stream input events
over the time from the first publication to the last cleaned packet's arrival), and p50/p99 latency from
a raw packet's publication (its source time) to the arrival of the cleaned packet made from it, over the
whole run and after its first second (the chain's start-up costs a few tens of ms for ~0.3 s).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from .bench_viewer import make_recording
from .common import cli, free_port, report, wait_line

LOADS_HZ = (1_000_000, 10_000_000)


def run_chain(recording: Path, n_events: int, rate_hz: float, load_hz: float) -> dict:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs = []
    try:
        router = cli("router", "--listen", ep)
        procs.append(router)
        wait_line(router, "stdout", "listening on")
        final = cli("subscribe", "evstream/*/events/clean", "--denoise", "none", "--connect", ep, "--until-end",
                     "--idle-s", "120", "--depth", "256", "--json")
        procs.append(final)
        wait_line(final, "stderr", "subscribed to")
        node = cli("subscribe", "evstream/*/events", "--republish", "--wait-subscribers", "10", "--connect", ep,
                    "--until-end", "--idle-s", "120", "--depth", "256", "--json")
        procs.append(node)
        wait_line(node, "stderr", "subscribed to")
        pub = cli("publish", str(recording), "--key", "evstream/cam/events", "--connect", ep, "--speed",
                   str(load_hz / rate_hz), "--wait-subscribers", "10", "--packet-us", "5000", "--json")
        procs.append(pub)
        outs = [json.loads(p.communicate(timeout=300)[0].strip().splitlines()[-1]) for p in (pub, node, final)]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    sent, cleaned, got = outs[0], outs[1]["cameras"]["cam"], outs[2]["cameras"]["cam"]
    span_s = sent["wall_s"] + got["latency_max_ms"] * 1e-3
    return {"offered_hz": load_hz, "published": sent["events"], "node_events": cleaned["events"],
            "node_missing": cleaned["missing"], "clean_events": got["events"],
            "sustained_hz": cleaned["events"] / span_s, "p50_ms": got["latency_p50_ms"],
            "p99_ms": got["latency_p99_ms"], "warm_p50_ms": got.get("latency_warm_p50_ms", float("nan")),
            "warm_p99_ms": got.get("latency_warm_p99_ms", float("nan")), "publish_hz": sent["events_per_s"]}


def run() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "live.npz"
        n = make_recording(rec)
        rate_hz = n / 4.0
        for load in LOADS_HZ:
            r = run_chain(rec, n, rate_hz, load)
            report(f"live chain, offered {load / 1e6:.0f} M ev/s (sustained)", r["sustained_hz"],
                   p50_ms=f"{r['p50_ms']:.1f}", p99_ms=f"{r['p99_ms']:.1f}",
                   after_1s_p50_ms=f"{r['warm_p50_ms']:.1f}", after_1s_p99_ms=f"{r['warm_p99_ms']:.1f}",
                   published=r["published"], node_in=r["node_events"], node_missing=r["node_missing"],
                   publisher_hz=f"{r['publish_hz'] / 1e6:.2f}M")


if __name__ == "__main__":
    run()
