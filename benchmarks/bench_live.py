"""Live chain on loopback: publisher -> router -> denoise node (paper's cascade, --republish) -> subscriber of
the cleaned stream, each a separate process, at 1 M and 10 M events/s of offered load.

Offered load: a ~1 M events/s recording (turntable + injected noise, as bench_viewer; 4 s, repeated in time
to EVSTREAM_BENCH_LIVE_S seconds, default 30, for the 10 M run) published at `--speed` = load / recording
rate. Reported: events/s sustained end to end (the node's input events over the time from the first
publication to the last cleaned packet's arrival), p50/p99 latency from a raw packet's publication (its
source time) to the arrival of the cleaned packet made from it, over the whole run and after its first
second, and each process's CPU time per published event (ns): the publisher's publishing loop (its own
`--json` cpu_s), the router's, the node's and the final subscriber's from when the publisher starts to
their exit (/proc and wait4: every thread, Zenoh's included). CPU time, not wall time: other work on the
machine does not count in it (it does in the latencies).

`python -m benchmarks live`.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from .bench_viewer import make_recording
from .common import cli, free_port, report, wait_line

# (offered events/s, the publisher's --packet-us): 5 ms of event time per packet, which at 10x speed is
# 0.5 ms of wall time (2,000 packets/s: a camera would not send packets that small), and 50 ms of event
# time = 5 ms of wall time at 10 M events/s (as a 10 M events/s camera sending 5-ms packets)
RUNS = ((1_000_000, 5_000), (10_000_000, 5_000), (10_000_000, 50_000))
BASE_S = 4.0  # the generated recording; longer ones repeat it in time
TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def repeat_recording(src: Path, dst: Path, times: int) -> int:
    """`src` played `times` times one after the other (event times shifted), as one native recording."""
    import dataclasses

    from evstream.sources import native

    from evstream import api
    from evstream.events import concat

    base = api.read(src)
    span = int(base.t[-1]) + 1
    parts = [dataclasses.replace(base, t=base.t + i * span, t_end=None) for i in range(times)]
    native.save(dst, concat(parts, base.geometry), {"repeated": times}, compress=False)
    return len(base) * times


def cpu_s(pid: int) -> float:
    """utime + stime of a live process (every thread), from /proc."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) * TICK_S


def finish(p) -> tuple[str, float]:
    """Read `p`'s stdout and stderr to the end and reap it: (stdout, its total CPU s from wait4); a process
    that failed raises with its stderr."""
    import threading

    err: list[str] = []
    reader = threading.Thread(target=lambda: err.append(p.stderr.read()))
    reader.start()
    out = p.stdout.read()
    reader.join()
    _, status, usage = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode not in (0, -15):
        raise RuntimeError(f"{p.args[3:6]} exited with {p.returncode}: {err[0][-2000:]}")
    return out, usage.ru_utime + usage.ru_stime


def last_json(p) -> tuple[dict, float]:
    """`finish(p)`, its stdout's last line (the command's --json summary) parsed: (summary, CPU s)."""
    text, total = finish(p)
    return json.loads(text.strip().splitlines()[-1]), total


def start(procs: list, stream: str, ready: str, *args: str):
    """`evstream ARGS`, added to `procs` (killed at the end if still running), once `ready` is on `stream`."""
    p = cli(*args)
    procs.append(p)
    wait_line(p, stream, ready)
    return p


def router_and_reader(procs: list, ep: str, *until_end: str):
    """A router listening on `ep` and a reader of every cleaned stream (`--until-end` [N cameras])."""
    router = start(procs, "stdout", "listening on", "router", "--listen", ep, "--json")
    final = start(procs, "stderr", "subscribed to", "subscribe", "evstream/*/events/clean", "--denoise", "none",
                  "--connect", ep, "--until-end", *until_end, "--idle-s", "120", "--depth", "256", "--json")
    return router, final


def denoise_node(procs: list, ep: str, keyexpr: str):
    """A denoise node republishing `keyexpr` cleaned."""
    return start(procs, "stderr", "subscribed to", "subscribe", keyexpr, "--republish", "--wait-subscribers", "10",
                 "--connect", ep, "--until-end", "--idle-s", "120", "--depth", "256", "--json")


def kill_left(procs: list) -> None:
    for p in procs:
        if p.returncode is None and p.poll() is None:
            p.kill()
            p.wait()


def run_chain(recording: Path, n_events: int, rate_hz: float, load_hz: float, packet_us: int) -> dict:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs = []
    try:
        router, final = router_and_reader(procs, ep)
        node = denoise_node(procs, ep, "evstream/*/events")
        before = {name: cpu_s(p.pid) for name, p in (("router", router), ("node", node), ("subscriber", final))}
        pub = cli("publish", str(recording), "--key", "evstream/cam/events", "--connect", ep, "--speed",
                  str(load_hz / rate_hz), "--wait-subscribers", "10", "--packet-us", str(packet_us), "--json")
        procs.append(pub)
        outs, cpu = {}, {}
        for name, p in (("publisher", pub), ("node", node), ("subscriber", final)):
            outs[name], cpu[name] = last_json(p)
        cpu["router"] = cpu_s(router.pid)
        router.terminate()
        _, total = finish(router)
        cpu["router"] = max(cpu["router"], total) - before["router"]
        for name in ("node", "subscriber"):
            cpu[name] -= before[name]
        cpu["publisher"] = outs["publisher"]["cpu_s"]
    finally:
        kill_left(procs)
    sent, cleaned, got = outs["publisher"], outs["node"]["cameras"]["cam"], outs["subscriber"]["cameras"]["cam"]
    span_s = sent["stream_s"] + got["latency_max_ms"] * 1e-3
    return {"offered_hz": load_hz, "published": sent["events"], "packets": sent["packets"],
            "node_events": cleaned["events"], "node_missing": cleaned["missing"], "clean_events": got["events"],
            "sustained_hz": cleaned["events"] / span_s, "p50_ms": got["latency_p50_ms"],
            "p99_ms": got["latency_p99_ms"], "warm_p50_ms": got.get("latency_warm_p50_ms", float("nan")),
            "warm_p99_ms": got.get("latency_warm_p99_ms", float("nan")), "publish_hz": sent["events_per_s"],
            "ns_per_event": {k: 1e9 * v / max(sent["events"], 1) for k, v in cpu.items()},
            "cores": sum(cpu.values()) / span_s}


def run_cameras(recording: Path, n_cams: int, packet_us: int) -> dict:
    """`n_cams` publishers (each the recording, as fast as the chain takes it: --speed 0, BLOCK) -> one router
    -> one denoise node per camera (its own process and key) -> one reader of every cleaned stream. Total
    events/s = events through the nodes / (the slowest publisher's publishing time + the last packet's
    latency), and each process kind's CPU ns per event."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    cams = [f"cam{i}" for i in range(n_cams)]
    procs = []
    try:
        router, final = router_and_reader(procs, ep, str(n_cams))
        nodes = [denoise_node(procs, ep, f"evstream/{cam}/events") for cam in cams]
        before = {p.pid: cpu_s(p.pid) for p in (router, final, *nodes)}
        pubs = [cli("publish", str(recording), "--key", f"evstream/{cam}/events", "--connect", ep, "--speed", "0",
                    "--wait-subscribers", "10", "--packet-us", str(packet_us), "--json") for cam in cams]
        procs += pubs
        sent, cpu = [], {"publisher": 0.0, "node": 0.0}
        for p in pubs:
            sent.append(last_json(p)[0])
            cpu["publisher"] += sent[-1]["cpu_s"]
        node_events = 0
        for cam, p in zip(cams, nodes):
            summary, total = last_json(p)
            node_events += summary["cameras"][cam]["events"]
            cpu["node"] += total - before[p.pid]
        got, total = last_json(final)
        cpu["subscriber"] = total - before[final.pid]
        cpu["router"] = cpu_s(router.pid) - before[router.pid]
        router.terminate()
        finish(router)
    finally:
        kill_left(procs)
    published = sum(s["events"] for s in sent)
    span_s = max(s["stream_s"] for s in sent) + max(c["latency_max_ms"] for c in got["cameras"].values()) * 1e-3
    return {"cameras": n_cams, "published": published, "node_events": node_events,
            "cores": sum(cpu.values()) / span_s, "missing": got["missing"], "total_hz": node_events / span_s,
            "p99_ms": max(c["latency_p99_ms"] for c in got["cameras"].values()),
            "ns_per_event": {k: 1e9 * v / max(published, 1) for k, v in cpu.items()}}


def cameras(max_cams: int = 3, packet_us: int = 10_000) -> None:
    """Total events/s against the number of cameras (= denoise nodes), each publisher as fast as it goes."""
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "live.npz"
        n = make_recording(rec, duration_us=int(BASE_S * 1e6))
        print(f"  each camera: {n:,} events (a {BASE_S:g}-s recording) at --speed 0, {packet_us / 1e3:g}-ms packets; "
              f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
        print("  cameras = nodes | total events/s | p99 latency | cores used | CPU ns/event: publishers, router, "
              "nodes, subscriber")
        for k in range(1, max_cams + 1):
            r = run_cameras(rec, k, packet_us)
            ns = r["ns_per_event"]
            print(f"  {k:15d} | {r['total_hz'] / 1e6:8.2f} M/s   | {r['p99_ms']:8.0f} ms | {r['cores']:10.2f} | "
                  f"{ns['publisher']:.0f}, {ns['router']:.0f}, {ns['node']:.0f}, {ns['subscriber']:.0f}"
                  f"{'' if r['node_events'] == r['published'] and not r['missing'] else '  LOST EVENTS'}", flush=True)


def run() -> None:
    long_s = float(os.environ.get("EVSTREAM_BENCH_LIVE_S", "30"))
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "live.npz"
        n = make_recording(rec, duration_us=int(BASE_S * 1e6))
        rate_hz = n / BASE_S
        long_rec = Path(tmp) / "live_long.npz"
        times = max(1, round(long_s / BASE_S))
        n_long = repeat_recording(rec, long_rec, times) if times > 1 else n
        print(f"  recording {n:,} events over {BASE_S:g} s ({rate_hz / 1e6:.2f} M events/s); the 10 M run plays "
              f"it {times}x ({n_long:,} events); load average "
              f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
        rows = []
        for load, packet_us in RUNS:
            r = run_chain(long_rec if load >= 5e6 else rec, n, rate_hz, load, packet_us)
            wall_ms = packet_us * rate_hz / load / 1e3
            report(f"live chain, {load / 1e6:.0f} M ev/s offered, {wall_ms:g}-ms packets", r["sustained_hz"],
                   p50_ms=f"{r['p50_ms']:.1f}", p99_ms=f"{r['p99_ms']:.1f}",
                   after_1s_p50_ms=f"{r['warm_p50_ms']:.1f}", after_1s_p99_ms=f"{r['warm_p99_ms']:.1f}",
                   published=r["published"], node_in=r["node_events"], node_missing=r["node_missing"],
                   publisher_hz=f"{r['publish_hz'] / 1e6:.2f}M")
            rows.append((load, wall_ms, r))
        print("  CPU ns per published event          | publisher | router | node | subscriber | sum | cores used")
        for load, wall_ms, r in rows:
            ns = r["ns_per_event"]
            parts = [ns[k] for k in ("publisher", "router", "node", "subscriber")]
            print(f"  {load / 1e6:2.0f} M ev/s offered, {wall_ms:3g}-ms packets | "
                  + " | ".join(f"{v:9.0f}" for v in parts) + f" | {sum(parts):4.0f} | {r['cores']:.2f}", flush=True)

    cameras()


if __name__ == "__main__":
    import sys

    cameras() if sys.argv[1:] == ["cameras"] else run()
