"""`subscribe --flow block` under backpressure: does memory stay bounded when publishers outrun a slow subscriber?

Processes on loopback: `evstream router`, one slow `evstream subscribe --flow block --delay-ms D` (a stand-in
for a slow cascade: it takes one packet per D ms), and N publishers in this process (one Zenoh session
each, CongestionControl.BLOCK, as `evstream publish`), each putting P real EventPackets of the
recording as fast as it can. Measured, per run:

- the backlog when the publishers finish: the subscriber's take rate (packets / its active time) times
  the time it still needs after the last put returned — what sat between the publishers and the subscriber;
- the peak resident memory growth of the router and of the subscriber (sampled every 0.1 s) over their
  memory before the first put;
- whether every packet arrived (`missing` = 0).

If Block holds the publishers back, the backlog and the memory stay the same when P grows 4x; if a hop
buffered without bound, both would grow with P. Also run: a subscriber that takes nothing (SIGSTOP) for
7 s (longer than Zenoh's default `block/wait_before_close`, 5 s: nothing may be lost) and for 14 s
(longer than the link lease, 10 s: the link is closed, what was in flight is lost and, when the end
mark went with it, the subscriber stops by `--idle-s`).
Run on a 2-core machine shared with other work: numbers are noisy; the comparison within a run is not.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import zenoh
from evstream.sources import native
from evstream.sources.zenoh_session import open_session

from evstream.codecs.attachment import encode_attachment
from evstream.codecs.event_packet import encode_packet
from evstream.codecs.packets import to_packet

from .bench_viewer import make_recording
from .common import cli, free_port, wait_line


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024
    except (OSError, StopIteration):
        return float("nan")


def packets_of(recording: Path, packet_us: int) -> list:
    """The recording cut into EventPackets of `packet_us` (evt3, as `publish` sends them)."""
    src = native.open(recording)
    chunks = list(src)
    import numpy as np

    t = np.concatenate([c.t for c in chunks])
    x, y, p = (np.concatenate([getattr(c, a) for c in chunks]) for a in "xyp")
    edges = np.searchsorted(t, np.arange(0, int(t[-1]) + packet_us, packet_us))
    g = src.geometry
    return [to_packet(t[a:b], x[a:b], y[a:b], p[a:b], width=g.width, height=g.height)
            for a, b in zip(edges[:-1], edges[1:]) if b > a]


class Sampler(threading.Thread):
    """Peak RSS growth of some processes, sampled every 0.1 s."""

    def __init__(self, pids: dict[str, int]):
        super().__init__(daemon=True)
        self.pids = pids
        self.base = {k: _rss_mb(p) for k, p in pids.items()}
        self.peak = dict.fromkeys(pids, 0.0)
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            for k, pid in self.pids.items():
                self.peak[k] = max(self.peak[k], _rss_mb(pid) - self.base[k])
            time.sleep(0.1)


def run_case(packets: list, n_pub: int, n_packets: int, delay_ms: float, depth: int,
             stall_s: float = 0.0, packet_us: int = 50_000) -> dict:
    """N publishers x P packets into one slow subscriber through a router."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs = []
    sessions = []
    try:
        router = cli("router", "--listen", ep)
        procs.append(router)
        wait_line(router, "stdout", "listening on")
        sub = cli("subscribe", "evstream/*/events", "--denoise", "none", "--connect", ep, "--flow", "block",
                   "--depth", str(depth), "--delay-ms", str(delay_ms), "--until-end", str(n_pub),
                   "--idle-s", "20" if stall_s else "600", "--json")  # a lost link can take the end mark along
        procs.append(sub)
        wait_line(sub, "stderr", "subscribed to")
        pubs = []
        for i in range(n_pub):
            s = open_session(connect=[ep])
            sessions.append(s)
            pubs.append(s.declare_publisher(f"evstream/c{i}/events", congestion_control=zenoh.CongestionControl.BLOCK,
                                            priority=zenoh.Priority.DATA))
        while not all(p.matching_status.matching for p in pubs):
            time.sleep(0.01)
        time.sleep(1.0)
        sampler = Sampler({"router": router.pid, "subscriber": sub.pid})
        sampler.start()
        if stall_s:  # the subscriber takes nothing for stall_s
            os.kill(sub.pid, 19)  # SIGSTOP
            threading.Timer(stall_s, os.kill, (sub.pid, 18)).start()  # SIGCONT
        span_us = packets[-1].time_base // 1000 - packets[0].time_base // 1000 + packet_us
        put_bytes = [0] * n_pub
        done_s = [0.0] * n_pub
        t0 = time.monotonic()

        def publish(i: int) -> None:
            for k in range(n_packets):
                base = packets[k % len(packets)]
                off_ns = (k // len(packets)) * span_us * 1000
                data = encode_packet(replace(base, seq=k, time_base=base.time_base + off_ns,
                                             stamp_ns=base.stamp_ns + off_ns))
                pubs[i].put(data, attachment=encode_attachment(k, time.time_ns()))
                put_bytes[i] += len(data)
            pubs[i].delete(attachment=encode_attachment(n_packets, time.time_ns()))  # the end mark, as publish
            done_s[i] = time.monotonic() - t0

        threads = [threading.Thread(target=publish, args=(i,)) for i in range(n_pub)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        out = json.loads(sub.communicate(timeout=900)[0].strip().splitlines()[-1])
        sub_s = time.monotonic() - t0
        sampler.stop.set()
    finally:
        for s in sessions:
            s.close()
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    total = sum(put_bytes)
    rate = total / sub_s
    backlog = rate * max(sub_s - max(done_s), 0.0)
    return {"publishers": n_pub, "packets_each": n_packets, "put_mb": total / 1e6,
            "packet_kb": total / (n_pub * n_packets) / 1e3, "publishers_done_s": max(done_s),
            "subscriber_done_s": sub_s, "backlog_mb": backlog / 1e6, "router_mb": sampler.peak["router"],
            "subscriber_mb": sampler.peak["subscriber"], "packets_got": out["packets"],
            "missing": out["missing"], "malformed": out["malformed"]}


def _line(name: str, r: dict) -> None:
    print(f"{name:<52} backlog {r['backlog_mb']:6.1f} MB  router +{r['router_mb']:5.1f} MB  "
          f"subscriber +{r['subscriber_mb']:5.1f} MB  put {r['put_mb']:.0f} MB in {r['packet_kb']:.0f} KB packets, "
          f"publishers done {r['publishers_done_s']:.1f} s, subscriber {r['subscriber_done_s']:.1f} s, "
          f"got {r['packets_got']} missing {r['missing']} malformed {r['malformed']}", flush=True)


def run() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "live.npz"
        make_recording(rec)
        packets = packets_of(rec, 50_000)  # 50 ms packets of a ~1 M events/s recording: ~200 KB each
    for n_pub in (1, 4):
        for n_packets in (100, 400):
            r = run_case(packets, n_pub, n_packets, delay_ms=10, depth=64)
            _line(f"{n_pub} publisher(s) x {n_packets} packets, block, depth 64", r)
    for stall_s in (7, 14):  # under and over the link lease (10 s)
        r = run_case(packets, 1, 300, delay_ms=10, depth=64, stall_s=stall_s)
        _line(f"1 publisher x 300 packets, subscriber stopped {stall_s} s", r)


if __name__ == "__main__":
    run()
