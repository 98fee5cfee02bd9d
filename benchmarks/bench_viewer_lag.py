"""How far the live web viewer lags behind the stream: a synthetic live stream (346x260, random events in
the three classes, 10-ms chunks released at real time) at 0.1, 1 and 5 M events/s offered goes through
the Rerun sink into `--serve` (the `rerun --serve-web` process on 127.0.0.1), and the web viewer runs in
headless Chromium (software WebGL, SwiftShader), as a user of `evstream subscribe ... --serve` sees it.

The lag is the viewer's time cursor against the stream's clock, every second: the page's viewer handle
(`window._handle.viewer_state()`, the ViewerState protobuf that `rerun.experimental.ViewerClient.get_state`
reads from a native viewer) gives the cursor on the `event_time` timeline, which follows the newest data
the viewer has taken in; lag = now - the wall-clock time at which that event time was live. Also per
second: frames the page drew (requestAnimationFrame), and CPU of this process (the SDK's logging), of the
serve process and of Chromium's processes.

    .venv/bin/python -m benchmarks.bench_viewer_lag [--seconds 60] [--rates 0.1,1,5]
        [--modes before,batched,after] [--viewers web,native] [--layouts full,none]

It prints each run's curve as it ends and a table at the end (lag at 5, 10, ... s; median and max after
10 s; points drawn; the page's frames per second; CPU; the load average during the run: the machine's
other work slows a software renderer most).

`--layouts none`: the same page and stream, but a layout with no view, so the page takes the data in and
draws nothing: the lag of ingestion alone (against `full`, what drawing adds).

`native`: the same streams into the native viewer (`--spawn`'s), headless on the CPU (llvmpipe), its
state read through `rerun.experimental.ViewerClient.get_state` every second (lag = now - the wall-clock
time of the newest event time it has taken in): the `rerun` binary of the installed wheel.

The page size is EVSTREAM_VIEWPORT (default 1600x1000; docs/live.md's numbers: 1024x640).
`before` is the sink as it was before issue 23 (a call per entity per packet, no wall-clock budget,
nothing dropped), `batched` the first fix (one column per entity every 0.25 s: 7 chunks per send, 28 a
second), `after` the defaults of `evstream subscribe --serve` (LIVE_OPTIONS: the points in one chunk
every 0.5 s, the statistics every second: 5 chunks a second). `before` into the web viewer runs at
0.1 M events/s only: above, its logging stalls inside the SDK and may not return (`--stalls` runs it).
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from evstream.sinks.rerun_sink import LIVE_OPTIONS, TIMELINE, RerunSink
from evstream.sinks.rerun_viewer import free_port, open_output, rerun_binary

from evstream.chromium import CHROMIUM, VIEWPORT, HeadlessChromium, viewer_times
from evstream.events import EventChunk, Geometry
from evstream.pipeline import Batch, RunStats

G = Geometry(346, 260)
FRAME_COUNTER = "window.__frames = 0; (function f() { window.__frames++; requestAnimationFrame(f); })()"
STATE = "window.__frames + ' ' + btoa(String.fromCharCode(...window._handle.viewer_state()))"
CHUNK_US = 10_000
TAIL_S = float(os.environ.get("EVSTREAM_LAG_TAIL_S", "5"))
# `before` into the web viewer above this rate is skipped unless asked for (--stalls): its logging blocks
# inside the SDK (at 1 M events/s it fell 429 s behind in a 60-s stream and its final flush had not
# returned 5 min later), and a blocked log call cannot be interrupted from here
BEFORE_MAX_RATE_HZ = 0.1e6
# a mode may set sink options after its name, in this order (- for None): before:50000, after:::::-
KNOBS = ("wall_budget_hz", "time_bin_us", "send_every_s", "stats_bin_us", "stats_every_s", "series_window_s")
MODES = {
    "before": dict(send_every_s=0.0, wall_budget_hz=None, live=False),
    # last session's live sink: one column per entity (4 for the points, 3 statistics) every 0.25 s
    "batched": dict(live=True, wall_budget_hz=100_000.0, send_every_s=0.25, time_bin_us=10_000),
    "after": dict(LIVE_OPTIONS),  # what `subscribe --serve` uses
}


def mode_options(mode: str) -> dict:
    """Sink options of a mode, with knobs after its name (e.g. after:50000::1.0: a wall-clock budget of
    50 k points/s, sends every second)."""
    name, *knobs = mode.split(":")
    options = dict(MODES[name])
    for key, value in zip(KNOBS, knobs):
        if value == "-":
            options[key] = None
        elif value:
            options[key] = float(value) if key.endswith("_s") or key.endswith("_hz") else int(value)
    return options


def cpu_s(pids: list[int]) -> float:
    """User + system CPU seconds of processes so far (their threads included)."""
    total = 0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])
        except (OSError, IndexError):
            pass
    return total / os.sysconf("SC_CLK_TCK")


def group_pids(pgid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if int((d / "stat").read_text().rsplit(")", 1)[1].split()[2]) == pgid:
                    out.append(int(d.name))
            except (OSError, IndexError, ValueError):
                pass
    return out


def stream(rate_hz: float, seconds: float, seed: int = 0):
    """10-ms chunks of random events (70 % signal, 25 % background, 5 % hot pixels) at `rate_hz`."""
    rng = np.random.default_rng(seed)
    n = max(1, int(rate_hz * CHUNK_US * 1e-6))
    pool = 16
    xs = rng.integers(0, G.width, (pool, n)).astype(np.uint16)
    ys = rng.integers(0, G.height, (pool, n)).astype(np.uint16)
    ps = rng.integers(0, 2, (pool, n)).astype(np.int8)
    cs = rng.choice(3, (pool, n), p=[0.7, 0.25, 0.05]).astype(np.uint8)
    offs = np.sort(rng.integers(0, CHUNK_US, (pool, n)), axis=1)
    for i in range(int(seconds * 1e6 / CHUNK_US)):
        k = i % pool
        t = offs[k] + i * CHUNK_US
        yield EventChunk(t=t, x=xs[k], y=ys[k], p=ps[k], geometry=G, cls=cs[k], t_end=(i + 1) * CHUNK_US)


def no_views() -> rrb.Blueprint:
    """A layout that draws nothing (one empty text log view), the time cursor following the newest data."""
    return rrb.Blueprint(rrb.TextLogView(origin="/no_such_entity", name="nothing drawn"),
                         rrb.TimePanel(timeline=TIMELINE, state="collapsed", play_state="following"),
                         collapse_panels=True)


def run_one(mode: str, rate_hz: float, seconds: float, workdir: Path, layout: str = "full") -> dict:
    out = open_output(serve=True, memory_limit="1GiB", log_dir=workdir, grpc_port=free_port(), web_port=free_port())
    rec = out.rec
    sink = RerunSink(rec, geometry=G, play_state="following", **mode_options(mode))
    if layout == "none":
        rec.send_blueprint(no_views())
    browser = HeadlessChromium(workdir / f"profile-{mode}-{rate_hz:g}", workdir / "chromium.log")
    samples: list[dict] = []
    started = {"t": time.time()}
    t0_wall = {"t": time.time()}
    stop = threading.Event()
    try:
        session = browser.open(out.web_url, 120)
        time.sleep(15)  # the wasm viewer loads and compiles (slow under software rendering and load)
        chromium_pids = group_pids(browser.process.pid)
        serve_pid = out.process.pid

        browser.call("Runtime.evaluate", {"expression": FRAME_COUNTER}, session)

        def sample():
            last = (time.monotonic(), cpu_s([os.getpid()]), cpu_s([serve_pid]), cpu_s(chromium_pids), 0)
            while not stop.is_set():
                t_req = time.time()
                try:
                    reply = browser.call("Runtime.evaluate", {"expression": STATE, "returnByValue": True},
                                         session, timeout_s=30)["result"]["value"]
                    frames, state = reply.split(" ", 1)
                    cursor, newest = viewer_times(base64.b64decode(state))
                    frames = int(frames)
                except Exception:  # noqa: BLE001 - a missed sample is recorded as such
                    cursor, newest, frames = None, None, last[4]
                t_got = time.time()
                now = (time.monotonic(), cpu_s([os.getpid()]), cpu_s([serve_pid]), cpu_s(chromium_pids), frames)
                dt = max(now[0] - last[0], 1e-6)
                def wall(ns):  # when that event time was live
                    return None if ns is None or sink.t0 is None else t0_wall["t"] + (sink.t0 + ns / 1000) * 1e-6

                samples.append({
                    "t_s": t_got - started["t"],
                    "lag_s": None if wall(cursor) is None else t_got - wall(cursor),
                    "ingest_lag_s": None if wall(newest) is None else t_got - wall(newest),
                    "query_s": t_got - t_req, "fps": (now[4] - last[4]) / dt,
                    "cpu_sdk": (now[1] - last[1]) / dt, "cpu_serve": (now[2] - last[2]) / dt,
                    "cpu_chromium": (now[3] - last[3]) / dt,
                })
                last = now
                stop.wait(max(0.0, 1.0 - (time.time() - t_req)))

        load_before = os.getloadavg()[0]
        started["t"] = time.time()
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        t0_wall["t"] = time.time()
        stats = RunStats()
        behind_s = 0.0
        for chunk in stream(rate_hz, seconds):
            due = t0_wall["t"] + chunk.t_end * 1e-6
            behind_s = max(behind_s, time.time() - due)
            if time.time() > t0_wall["t"] + 2 * seconds + 30:  # the logging itself cannot keep up: stop
                print(f"  {mode} {rate_hz / 1e6:g} M ev/s: logging stalled, {behind_s:.0f} s behind; stopped",
                      flush=True)
                break
            delay = due - time.time()
            if delay > 0:
                time.sleep(delay)
            sink.write(Batch(chunk, [], stats))
        sink.close(stats)
        load = (load_before + os.getloadavg()[0]) / 2
        time.sleep(TAIL_S)  # how the lag ends
        stop.set()
        sampler.join(timeout=60)
    finally:
        stop.set()
        browser.close()
        out.finish()
        out.stop()
    lags = [s["lag_s"] for s in samples if s["lag_s"] is not None and 10 < s["t_s"] < seconds]
    return {"mode": mode, "viewer": "web", "layout": layout, "load": load, "rate_Mev_s": rate_hz / 1e6,
            "seconds": seconds, "samples": samples, "offered": int(rate_hz * seconds),
            "lag_median_s": float(np.median(lags)) if lags else None,
            "lag_p90_s": float(np.percentile(lags, 90)) if lags else None,
            "lag_max_s": float(max(lags)) if lags else None,
            "points_logged": sink.points_logged, "points_dropped": sink.points_dropped,
            "points_late": sink.points_late, "sdk_behind_max_s": behind_s}


def run_native(mode: str, rate_hz: float, seconds: float) -> dict:
    """The same stream into the native viewer (what `--spawn` opens), headless on the CPU (llvmpipe), its
    state read every second through `rerun.experimental.ViewerClient.get_state`."""
    from rerun.experimental import ViewerClient

    port = free_port()
    load_before = os.getloadavg()[0]
    client = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True, executable_path=rerun_binary())
    samples = []
    try:
        rec = rr.RecordingStream("evstream")
        rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy")
        sink = RerunSink(rec, geometry=G, play_state="following", **mode_options(mode))
        t0_wall = time.time()
        last = 0.0
        for chunk in stream(rate_hz, seconds):
            delay = t0_wall + chunk.t_end * 1e-6 - time.time()
            if delay > 0:
                time.sleep(delay)
            sink.write(Batch(chunk, [], RunStats()))
            if time.time() - last >= 1.0:
                last = time.time()
                state = client.get_state()
                recs = [r for r in state.recordings if any(t.name == TIMELINE for t in r.timelines)]
                if recs and sink.t0 is not None:
                    end = next(t.end for t in recs[0].timelines if t.name == TIMELINE)
                    samples.append({"t_s": last - t0_wall, "lag_s": last - (t0_wall + (sink.t0 + end / 1000) * 1e-6)})
            if time.time() > t0_wall + 2 * seconds + 30:
                break
        sink.close(RunStats())
        rec.disconnect()
    finally:
        client.quit()
    lags = [x["lag_s"] for x in samples if 10 < x["t_s"] < seconds]
    return {"mode": mode, "viewer": "native", "layout": "full", "load": (load_before + os.getloadavg()[0]) / 2,
            "rate_Mev_s": rate_hz / 1e6, "seconds": seconds, "samples": samples, "offered": int(rate_hz * seconds),
            "lag_median_s": float(np.median(lags)) if lags else None,
            "lag_max_s": float(max(lags)) if lags else None, "points_logged": sink.points_logged}


def curve(r: dict) -> str:
    return " ".join("-" if x["lag_s"] is None else f"{x['lag_s']:.2f}" for x in r["samples"])


def lag_at(r: dict, t_s: float) -> str:
    """The lag sampled nearest to `t_s` s into the stream (within 1 s)."""
    near = [x for x in r["samples"] if abs(x["t_s"] - t_s) <= 1.0 and x["lag_s"] is not None]
    return f"{min(near, key=lambda x: abs(x['t_s'] - t_s))['lag_s']:.2f}" if near else "-"


def _s(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def table(results: list[dict], seconds: float) -> str:
    marks = [t for t in (5, 10, 20, 30, 40, 50, 60) if t <= seconds]
    head = ["viewer", "layout", "sink", "M ev/s", *(f"{t} s" for t in marks), "median > 10 s", "max > 10 s",
            "points drawn / offered", "page fps", "Chromium cores", "load"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        fps = np.mean([x["fps"] for x in r["samples"]]) if r["viewer"] == "web" and r["samples"] else None
        cpu = np.mean([x["cpu_chromium"] for x in r["samples"]]) if r["viewer"] == "web" and r["samples"] else None
        rows.append("| " + " | ".join([
            r["viewer"], r["layout"], r["mode"], f"{r['rate_Mev_s']:g}", *(lag_at(r, t) for t in marks),
            _s(r["lag_median_s"]), _s(r["lag_max_s"]), f"{r['points_logged'] / 1e6:.1f} M / {r['offered'] / 1e6:g} M",
            "-" if fps is None else f"{fps:.1f}", "-" if cpu is None else f"{cpu:.2f}", f"{r['load']:.1f}"]) + " |")
    return "\n".join(rows)


def run(seconds: float = 60.0, rates=(0.1e6, 1e6, 5e6), modes=("before", "after"), json_out: str | None = None,
        web: bool = True, native: bool = True, layouts=("full",), stalls: bool = False):
    results = []

    def skip(mode: str, rate: float) -> bool:
        if mode.split(":")[0] == "before" and rate > BEFORE_MAX_RATE_HZ and not stalls:
            print(f"web before {rate / 1e6:g} M ev/s: skipped, its logging stalls inside the SDK (--stalls runs it)")
            return True
        return False

    print(f"bench_viewer_lag: {seconds:g}-s streams, page {VIEWPORT[0]}x{VIEWPORT[1]}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f} at the start", flush=True)
    if web and CHROMIUM is None:
        print("bench_viewer_lag: web viewer skipped, no Chromium (apt-get install chromium)")
    with tempfile.TemporaryDirectory() as d:
        for rate in rates if web and CHROMIUM else ():
            for layout in layouts:
                for mode in modes:  # interleaved: before and after under the same load
                    if skip(mode, rate):
                        continue
                    r = run_one(mode, rate, seconds, Path(d), layout)
                    results.append(r)
                    cpu = {k: np.mean([s[k] for s in r["samples"]]) for k in ("cpu_sdk", "cpu_serve", "cpu_chromium")}
                    print(f"web {layout} {mode} {rate / 1e6:g} M ev/s: points drawn {r['points_logged']:,} dropped "
                          f"{r['points_dropped']:,}; CPU cores sdk {cpu['cpu_sdk']:.2f} serve {cpu['cpu_serve']:.2f} "
                          f"chromium {cpu['cpu_chromium']:.2f}; logging behind the stream by up to "
                          f"{r['sdk_behind_max_s']:.1f} s; load {r['load']:.1f}", flush=True)
                    print(f"  lag per second (s): {curve(r)}", flush=True)
    for rate in rates if native else ():
        for mode in modes:  # (the native viewer takes `before` in at every rate)
            r = run_native(mode, rate, seconds)
            results.append(r)
            print(f"native {mode} {rate / 1e6:g} M ev/s: points drawn {r['points_logged']:,}; load {r['load']:.1f}",
                  flush=True)
            print(f"  lag per second (s): {curve(r)}", flush=True)
    print(table(results, seconds), flush=True)
    if json_out:
        Path(json_out).write_text(json.dumps(results, indent=1))
    return results


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rates", default="0.1,1,5", help="M events/s offered, comma-separated")
    ap.add_argument("--modes", default="before,batched,after", help=f"of {', '.join(MODES)} (knobs: see KNOBS)")
    ap.add_argument("--json", help="write every sample here")
    ap.add_argument("--viewers", default="web,native", help="web (headless Chromium), native (headless)")
    ap.add_argument("--layouts", default="full", help="full (the sink's), none (no view: ingestion alone)")
    ap.add_argument("--stalls", action="store_true", help="also run `before` above 0.1 M ev/s (it stalls)")
    a = ap.parse_args()
    run(a.seconds, [float(r) * 1e6 for r in a.rates.split(",")], a.modes.split(","), a.json,
        web="web" in a.viewers, native="native" in a.viewers, layouts=a.layouts.split(","), stalls=a.stalls)
