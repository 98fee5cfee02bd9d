"""Live streams over real Zenoh sessions in separate processes on 127.0.0.1: publisher -> router -> denoise
node -> subscriber with counts conserved, a publisher restarted mid-stream, slow subscribers (no loss under
BLOCK, counted drops under a ring), garbage payloads, Ctrl-C, and a ROS 2 rmw_zenoh-shaped publisher."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
import zenoh.ext as zext
from evstream.sources import open_source
from evstream.sources.zenoh_session import drain, open_session
from mcap_ros2._dynamic import serialize_dynamic

from evstream.codecs import evt3
from evstream.codecs.attachment import encode_attachment
from evstream.codecs.event_packet import DATATYPE, MSGDEF, encode_packet
from evstream.codecs.packets import to_packet

ROOT = Path(__file__).resolve().parents[1]
TURNTABLE = ROOT / "recordings" / "turntable.npz"
BAR = ROOT / "recordings" / "bar.npz"
TIMEOUT_S = 60
PEAK = ("import sys; from evstream.cli import main; code = main(sys.argv[1:]); "
        "print([ln for ln in open('/proc/self/status') if ln.startswith('VmHWM')][0], file=sys.stderr); "
        "sys.exit(code)")


def _events(path):
    src = open_source(path)
    chunks = list(src)
    return (np.concatenate([c.t for c in chunks]), np.concatenate([c.x for c in chunks]),
            np.concatenate([c.y for c in chunks]), np.concatenate([c.p for c in chunks]), src.geometry)


def _numbered_packets(ev, count: int) -> list[bytes]:
    """`count` EventPackets of 1000 of the events `ev` (as `_events` gives them) each, seq 0..count-1."""
    t, x, y, p, g = ev
    return [encode_packet(to_packet(t[i:i + 1000], x[i:i + 1000], y[i:i + 1000], p[i:i + 1000],
                                    width=g.width, height=g.height, seq=k))
            for k, i in enumerate(range(0, 1000 * count, 1000))]


def _end_stream(session, pub) -> None:
    """Let what was put arrive, mark the end of the camera's stream (a delete) and let that arrive too."""
    drain(session)
    pub.delete()
    drain(session)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def matched_publisher(session, key: str, timeout_s: float = 10):
    """A BLOCK publisher on `key`, once a subscriber matches it (or `timeout_s` passed)."""
    pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    deadline = time.monotonic() + timeout_s
    while not pub.matching_status.matching and time.monotonic() < deadline:
        time.sleep(0.01)
    return pub


class PacketCount:
    """Counts the packets the router forwards on `key` to a subscriber of the test's own: what a test
    waits on (bounded) instead of sleeping a fixed time while a stream flows."""

    def __init__(self, port: int, key: str):
        self.n = 0
        self.session = open_session(connect=[f"tcp/127.0.0.1:{port}"])
        self.session.declare_subscriber(key, self._seen)

    def _seen(self, sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.n += 1

    def wait(self, n: int, timeout_s: float = 60) -> None:
        deadline = time.monotonic() + timeout_s
        while self.n < n:
            assert time.monotonic() < deadline, f"{self.n} packets within {timeout_s} s, waited for {n}"
            time.sleep(0.01)

    def __enter__(self) -> PacketCount:
        return self

    def __exit__(self, *exc) -> None:
        self.session.close()


class Procs:
    """Child processes of one test: started with pipes, always killed at teardown (a test never hangs)."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.procs: list[subprocess.Popen] = []

    def start(self, *args: str, peak: bool = False) -> subprocess.Popen:
        """`evstream ARGS`; `peak`: the process prints its own peak resident memory (VmHWM) on stderr at
        the end (wait4's ru_maxrss would count the forking pytest's high-water mark)."""
        n = len(self.procs)
        runner = ["-c", PEAK] if peak else ["-m", "evstream.cli"]
        p = subprocess.Popen([sys.executable, *runner, *args], cwd=ROOT,
                             stdout=open(self.tmp / f"out{n}.txt", "wb"), stderr=open(self.tmp / f"err{n}.txt", "wb"))
        p.n = n
        self.procs.append(p)
        return p

    def stderr(self, p) -> str:
        return (self.tmp / f"err{p.n}.txt").read_text()

    def wait_for(self, p, text: str, timeout_s: float = 30) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            out = (self.tmp / f"out{p.n}.txt").read_text() + self.stderr(p)
            if text in out:
                return
            if p.poll() is not None:
                raise AssertionError(f"process exited ({p.returncode}) before {text!r}: {out}")
            time.sleep(0.05)
        raise AssertionError(f"no {text!r} within {timeout_s} s: {self.stderr(p)}")

    def result(self, p, timeout_s: float = TIMEOUT_S) -> dict:
        rc = p.wait(timeout=timeout_s)
        out = (self.tmp / f"out{p.n}.txt").read_text()
        assert rc == 0, f"exit {rc}: {self.stderr(p)}"
        return json.loads(out.strip().splitlines()[-1])

    def router(self, port: int) -> subprocess.Popen:
        r = self.start("router", "--listen", f"tcp/127.0.0.1:{port}")
        self.wait_for(r, "listening on")
        return r

    def subscriber(self, port: int, *args: str, peak: bool = False) -> subprocess.Popen:
        s = self.start("subscribe", *args, "--connect", f"tcp/127.0.0.1:{port}", "--json", peak=peak)
        self.wait_for(s, "subscribed to")
        return s

    def kill_all(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)


@pytest.fixture
def procs(tmp_path):
    ps = Procs(tmp_path)
    yield ps
    ps.kill_all()


def test_chain_publisher_router_denoise_subscriber_conserves_events(procs, tmp_path):
    """Two cameras on one router; the denoise node has a pipeline per camera; nothing is lost anywhere."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    final = procs.subscriber(port, "evstream/*/events/clean", "--denoise", "none", "--until-end", "2", "--idle-s", "40",
                             "--archive", str(tmp_path / "clean_{camera}.mcap"))
    raw = procs.subscriber(port, "evstream/*/events", "--denoise", "none", "--archive",
                           str(tmp_path / "raw_{camera}.mcap"), "--until-end", "2", "--idle-s", "40")
    # a node slower than the publishers (--delay-ms after each item): it takes its backlog in batches
    node = procs.subscriber(port, "evstream/*/events", "--republish", "--wait-subscribers", "10", "--drain-s", "30",
                            "--until-end", "2", "--idle-s", "40", "--delay-ms", "20")
    pubs = {cam: procs.start("publish", str(path), "--key", f"evstream/{cam}/events", "--connect", ep,
                             "--speed", "0", "--wait-subscribers", "10", "--drain-s", "30", "--json")
            for cam, path in (("cam1", TURNTABLE), ("cam2", BAR))}
    sent = {cam: procs.result(p) for cam, p in pubs.items()}
    node_out, raw_out, final_out = procs.result(node), procs.result(raw), procs.result(final)
    for cam, path in (("cam1", TURNTABLE), ("cam2", BAR)):
        n = len(_events(path)[0])
        assert sent[cam]["events"] == n
        got = node_out["cameras"][cam]
        assert got["events"] == n and got["missing"] == 0 and got["malformed"] == 0 and got["restarts"] == 0
        assert got["events_signal"] + got["events_background"] + got["events_hot_pixel"] == n
        assert 0 < got["events_signal"] < n  # the paper's cascade removed noise, kept signal
        assert got["published_events"] == got["events_signal"]
        assert got["published_packets"] * 2 < sent[cam]["packets"] == got["packets"]  # the backlog in batches
        clean = final_out["cameras"][cam]
        assert clean["events"] == got["events_signal"] and clean["missing"] == 0
        assert clean["latency_p99_ms"] >= clean["latency_p50_ms"] > 0
        assert raw_out["cameras"][cam]["events"] == n
        archived = list(open_source(tmp_path / f"raw_{cam}.mcap"))
        t = np.concatenate([c.t for c in archived])
        assert np.array_equal(t, _events(path)[0])  # the archive holds exactly the published stream
        # separate state per camera: what the node kept of this camera, event for event, and its class
        # counts, are those of the same denoiser run on this camera alone (two cameras interleaved
        # through one set of stages would judge each with the other's events)
        alone = _alone(path)
        assert [got["events_signal"], got["events_background"], got["events_hot_pixel"]] == alone["counts"]
        assert_same_events(open_source(tmp_path / f"clean_{cam}.mcap"), alone["kept"])
    assert node_out["stopped_by"] == "end of stream"


def _alone(path, kind="paper"):
    """A camera's recording through a fresh pipeline of its own, offline: its class counts and kept events."""
    from evstream.events import concat
    from evstream.pipeline import Pipeline, build

    src = open_source(path)
    events = Pipeline([build("stage", {"kind": kind})]).process(concat(list(src), src.geometry)).events
    return {"counts": np.bincount(events.classes(), minlength=3).tolist(), "kept": events.of_class(0)}


def assert_same_events(source, want) -> None:
    chunks = list(source)
    for k in "txyp":
        got = np.concatenate([getattr(c, k) for c in chunks]) if chunks else np.zeros(0)
        assert np.array_equal(got, getattr(want, k)), f"{k}: {len(got)} events vs {len(want)}"


def test_publisher_restarted_mid_stream(procs, tmp_path):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    sub = procs.subscriber(port, "evstream/cam1/events", "--denoise", "paper", "--archive",
                           str(tmp_path / "live.mcap"), "--until-end", "--idle-s", "40")
    with PacketCount(port, "evstream/cam1/events") as flowing:
        first = procs.start("publish", str(TURNTABLE), "--key", "evstream/cam1/events", "--connect", ep,
                            "--speed", "1", "--wait-subscribers", "10", "--drain-s", "30")
        flowing.wait(20)  # 20 of the 100 packets (10 ms each, sent in real time) went through the router
        first.kill()  # no end mark: the camera just vanished
    first.wait(timeout=10)
    second = procs.start("publish", str(TURNTABLE), "--key", "evstream/cam1/events", "--connect", ep,
                         "--speed", "0", "--wait-subscribers", "10", "--drain-s", "30", "--json")
    n = procs.result(second)["events"]
    out = procs.result(sub)["cameras"]["cam1"]
    assert out["restarts"] == 1
    assert len(out["segment_events"]) == 2 and 0 < out["segment_events"][0] < n
    assert out["segment_events"][1] == n  # the whole second run, through a fresh pipeline
    assert out["events_signal"] + out["events_background"] + out["events_hot_pixel"] == out["events"]
    assert out["archives"] == [str(tmp_path / "live.mcap"), str(tmp_path / "live.1.mcap")]
    # a fresh pipeline for the second run: its archive holds exactly what the denoiser keeps of the
    # whole recording from a clean start (stages carried over from the first run judge differently)
    assert_same_events(open_source(tmp_path / "live.1.mcap"), _alone(TURNTABLE)["kept"])


def test_slow_subscribers_block_loses_nothing_ring_counts_drops(procs):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    block = procs.subscriber(port, "evstream/cam1/events", "--denoise", "none", "--flow", "block", "--depth", "4",
                             "--delay-ms", "4", "--until-end", "--idle-s", "40")
    ring = procs.subscriber(port, "evstream/cam1/events", "--denoise", "none", "--flow", "ring", "--depth", "2",
                            "--delay-ms", "25", "--until-end", "--idle-s", "40")
    # the end mark is the newest sample, so the ring keeps it; an idle stop of a few seconds ran out under
    # load before the publisher had even started
    sent = procs.result(procs.start("publish", str(TURNTABLE), "--key", "evstream/cam1/events", "--connect", ep,
                                    "--speed", "0", "--wait-subscribers", "10", "--drain-s", "30", "--json"))
    b = procs.result(block)["cameras"]["cam1"]
    assert b["events"] == sent["events"] and b["packets"] == sent["packets"] and b["missing"] == 0
    r = procs.result(ring)["cameras"]["cam1"]
    assert r["packets"] < sent["packets"]
    assert r["missing"] > 0 and r["gaps"] > 0
    assert r["packets"] + r["missing"] <= sent["packets"]  # every skipped packet is counted, none twice


def test_garbage_payloads_are_counted_and_skipped_then_ctrl_c_stops_cleanly(procs, tmp_path):
    port = free_port()
    procs.router(port)
    sub = procs.subscriber(port, "evstream/*/events", "--denoise", "none", "--max-packet-bytes", "100000",
                           "--archive", str(tmp_path / "g_{camera}.mcap"))
    t, x, y, p, g = ev = _events(TURNTABLE)
    good = _numbered_packets(ev, 3)
    outside = encode_packet(to_packet(t[3000:3010], x[3000:3010], y[3000:3010], p[3000:3010], width=8, height=8))
    rng = np.random.default_rng(0)
    session = open_session(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        pub = matched_publisher(session, "evstream/cam1/events")
        pub.put(good[0], attachment=encode_attachment(0, time.time_ns()))
        pub.put(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes())  # random bytes
        pub.put(good[1][: len(good[1]) // 2])  # truncated
        pub.put(b"\x00\x01\x00\x00" + b"\xff" * 64)  # lengths pointing far past the end
        pub.put(bytes(150_000))  # oversized: refused on its length (past 100,000 + 64 KiB the transport drops it)
        pub.put(outside)  # events outside the 8x8 sensor it claims
        pub.put(good[1], attachment=b"\x01\x02\x03")  # bad attachment: packet still used (CDR seq)
        pub.put(good[2], attachment=encode_attachment(2, time.time_ns()))
        drain(session)
        session.put("evstream/cam2/events", b"not a packet")
        drain(session)
        deadline = time.monotonic() + 20
        while '"cam2"' not in procs.stderr(sub) and "cam2/events: malformed" not in procs.stderr(sub) \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        sub.send_signal(signal.SIGINT)
        out = procs.result(sub, timeout_s=20)
    finally:
        session.close()  # only now: closing drops what Zenoh still holds on the way
    c1 = out["cameras"]["cam1"]
    assert c1["events"] == 3000 and c1["packets"] == 3
    assert c1["oversized"] == 1 and c1["malformed"] == 4 and c1["bad_attachments"] == 1
    assert out["cameras"]["cam2"]["malformed"] == 1
    assert out["stopped_by"] == "SIGINT"
    assert "malformed packet skipped" in procs.stderr(sub)
    archived = list(open_source(tmp_path / "g_cam1.mcap"))  # a complete, readable file after Ctrl-C
    assert sum(len(c) for c in archived) == 3000


def test_until_end_stops_for_a_camera_that_sent_only_malformed_packets(procs):
    """No pipeline is made for a camera whose every packet is malformed; --until-end waited for it forever."""
    port = free_port()
    procs.router(port)
    sub = procs.subscriber(port, "evstream/*/events", "--denoise", "none", "--until-end", "--idle-s", "120")
    session = open_session(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        pub = matched_publisher(session, "evstream/junk/events")
        pub.put(b"not a packet")
        pub.put(b"\x00\x01\x00\x00" + b"\xff" * 64)
        _end_stream(session, pub)
        out = procs.result(sub, timeout_s=30)  # was: still waiting when --idle-s (120 s) ran out
    finally:
        session.close()
    assert out["cameras"]["junk"]["malformed"] == 2 and out["cameras"]["junk"]["ended"]
    assert out["stopped_by"] == "end of stream"


def test_a_subscriber_with_a_framer_takes_memory_for_a_batch_not_for_a_packet(procs):
    """A subscriber with a framer handed it each packet whole: bar.npz published as one packet (0.5 s) made
    5,000 frames of 346x260 at 100 µs windows in one batch, 1.8 GB (`--window-us 1` grows without bound).
    The pipeline now hands its framer a packet in pieces: the same 5,000 frames, a few hundred MB."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    node = procs.subscriber(port, "evstream/cam1/events", "--framer", "fw", "--window-us", "100", "--until-end",
                            "--idle-s", "40", peak=True)
    sent = procs.result(procs.start("publish", str(BAR), "--key", "evstream/cam1/events", "--connect", ep,
                                    "--speed", "0", "--packet-us", "500000", "--wait-subscribers", "10", "--json"))
    got = procs.result(node)["cameras"]["cam1"]
    assert sent["packets"] == got["packets"] == 1 and got["events"] == sent["events"] == 174_999
    assert got["frames"] == 5000
    hwm = [ln for ln in procs.stderr(node).splitlines() if ln.startswith("VmHWM")]
    peak_mb = int(hwm[-1].split()[1]) / 1024
    assert peak_mb < 1000, f"peak memory {peak_mb:.0f} MB"


def test_subscribe_save_says_what_it_wrote(procs, tmp_path):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    rrd = tmp_path / "live.rrd"
    sub = procs.start("subscribe", "evstream/*/events", "--connect", ep, "--save", str(rrd), "--until-end",
                      "--idle-s", "40")
    procs.wait_for(sub, "subscribed to")
    pub = procs.start("publish", str(BAR), "--key", "evstream/cam1/events", "--connect", ep, "--speed", "0",
                      "--wait-subscribers", "10", "--drain-s", "30")
    assert pub.wait(timeout=TIMEOUT_S) == 0 and sub.wait(timeout=TIMEOUT_S) == 0, procs.stderr(sub)
    out = (tmp_path / f"out{sub.n}.txt").read_text()
    assert f"wrote {rrd} — open with:" in out and rrd.stat().st_size > 10_000


def test_a_router_outage_mid_stream_is_reported_and_counted_in_missing(procs, tmp_path):
    """The router dies while a camera streams and comes back: the subscriber says so both times (it
    used to wait in silence), and every packet either arrives or is counted in `missing`."""
    port = free_port()
    router = procs.router(port)
    sub = procs.subscriber(port, "evstream/*/events", "--denoise", "none", "--until-end", "--idle-s", "40",
                           "--archive", str(tmp_path / "outage.mcap"))
    with PacketCount(port, "evstream/cam1/events") as flowing:
        pub = procs.start("publish", str(TURNTABLE), "--key", "evstream/cam1/events", "--connect",
                          f"tcp/127.0.0.1:{port}", "--speed", "0.05", "--wait-subscribers", "10", "--json")
        flowing.wait(5)  # 5 of the 100 packets (one per 0.2 s) went through: the publisher is connected
        router.kill()
    procs.wait_for(sub, "lost the connection to router")
    procs.router(port)
    procs.wait_for(sub, "evstream: connected to router", timeout_s=30)
    sent, got = procs.result(pub), procs.result(sub)
    cam = got["cameras"]["cam1"]
    assert got["stopped_by"] == "end of stream" and cam["last_seq"] == sent["packets"] - 1
    assert cam["gaps"] >= 1 and cam["missing"] > 0
    assert cam["packets"] + cam["missing"] == sent["packets"]  # none lost without a count
    assert 0 < cam["events"] < sent["events"]


def test_ros2_rmw_zenoh_event_packets(procs, tmp_path):
    """A ROS 2 node's EventPackets as rmw_zenoh publishes them: key <domain>/<topic>/<dds type>/<type hash>,
    CDR from mcap_ros2's serializer, one EVT3 stream cut into packets, rmw_zenoh's attachment written by
    Zenoh's own serializer (int64 seq, int64 source time, GID as a sequence)."""
    port = free_port()
    procs.router(port)
    sub = procs.subscriber(port, "0/**/event_camera_msgs::msg::dds_::EventPacket_/*", "--denoise", "none",
                           "--archive", str(tmp_path / "ros_{camera}.mcap"), "--idle-s", "4")
    t, x, y, p, g = _events(TURNTABLE)
    ros_encode = serialize_dynamic(DATATYPE, MSGDEF)[DATATYPE]
    enc = evt3.Evt3Encoder()
    key = ("0/dvs/events/event_camera_msgs::msg::dds_::EventPacket_/"
           "RIHS01_" + "ab" * 32)
    session = open_session(connect=[f"tcp/127.0.0.1:{port}"])
    cuts = np.arange(0, len(t) + 20_000, 20_000)
    try:
        pub = matched_publisher(session, key)
        for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
            payload = enc.encode(t[a:b], x[a:b], y[a:b], p[a:b])
            stamp_ns = 1_700_000_000_000_000_000 + int(t[a]) * 1000
            msg = {"header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": "dvs"},
                   "height": g.height, "width": g.width, "seq": k, "time_base": 123456789, "encoding": "evt3",
                   "is_bigendian": False, "events": payload}
            att = zext.z_serialize((zext.Int64(k + 1), zext.Int64(time.time_ns()), bytes(range(16))))
            pub.put(ros_encode(msg), attachment=att)
        drain(session)
        out = procs.result(sub)
    finally:
        session.close()
    dvs = out["cameras"]["dvs"]
    assert dvs["events"] == len(t) and dvs["malformed"] == 0 and dvs["bad_attachments"] == 0
    assert dvs["missing"] == 0 and dvs["first_seq"] == 1
    archived = list(open_source(tmp_path / "ros_dvs.mcap"))
    got_t = np.concatenate([c.t for c in archived])
    got_x = np.concatenate([c.x for c in archived])
    assert np.array_equal(got_t, t) and np.array_equal(got_x, x)  # one EVT3 stream across packets, decoded


def test_endpoints_are_explicit_and_loopback_by_default():
    from evstream.sources.zenoh_session import config

    c = config(mode="peer", connect=["tcp/127.0.0.1:7447"])
    assert json.loads(c.get_json("listen/endpoints")) == []
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    with pytest.raises(ValueError):
        config(listen=["127.0.0.1:7447"])  # no protocol
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "subscribe", "k", "--connect", "nonsense"],
                       cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert r.returncode == 2 and "endpoint" in r.stderr
    port = free_port()
    r = subprocess.run([sys.executable, "-m", "evstream.cli", "subscribe", "k", "--connect",
                        f"tcp/127.0.0.1:{port}", "--idle-s", "1"],
                       cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S, env={**os.environ})
    assert r.returncode == 1 and "cannot open a Zenoh" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_viewer_save_per_camera_and_frames_republished(procs, tmp_path):
    """`subscribe --save` logs each camera into the Rerun recording (a second camera gets its own .rrd);
    a republishing node with a framer publishes foxglove.RawImage frames beside the cleaned stream."""
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from rerun.chunk import RrdReader

    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    session = open_session(connect=[ep])
    frames = session.declare_subscriber("evstream/*/frames", zenoh.handlers.FifoChannel(1000))
    try:
        viewer = procs.subscriber(port, "evstream/*/events", "--save", str(tmp_path / "live.rrd"), "--flow", "block",
                                  "--until-end", "2", "--idle-s", "40")
        node = procs.subscriber(port, "evstream/cam1/events", "--republish", "--framer", "fw", "--window-us",
                                "50000", "--until-end", "--idle-s", "40")
        pubs = [procs.start("publish", str(path), "--key", f"evstream/{cam}/events", "--connect", ep, "--speed",
                            "0", "--wait-subscribers", "10", "--drain-s", "30", "--json")
                for cam, path in (("cam1", TURNTABLE), ("cam2", BAR))]
        for p in pubs:
            procs.result(p)
        out, node_out = procs.result(viewer), procs.result(node)
        images, pixels = [], []
        while (s := frames.try_recv()) is not None:
            msg = RawImage()
            msg.ParseFromString(s.payload.to_bytes())
            images.append((str(s.key_expr), msg.width, msg.height, msg.encoding, len(msg.data)))
            pixels.append(np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width))
    finally:
        session.close()
    assert out["flow"] == "block" and out["output"] == "save"
    assert {k: v["events"] for k, v in out["cameras"].items()} == {"cam1": 254078, "cam2": 174999}
    assert node_out["cameras"]["cam1"]["frames"] == len(images) > 0
    assert all(i == ("evstream/cam1/frames", 346, 260, "mono8", 346 * 260) for i in images)
    # each frame's pixels: the frames of the same denoiser and framer run offline on cam1's recording,
    # rendered here from their counts (white where ON outnumber OFF, black where OFF do, grey 128 else)
    from evstream.events import concat
    from evstream.framing import FixedWindow
    from evstream.pipeline import Pipeline, build

    src = open_source(TURNTABLE)
    offline = Pipeline([build("stage", {"kind": "paper"})], framer=FixedWindow(window_us=50_000))
    want = offline.process(concat(list(src), src.geometry)).frames + offline.finish(src.geometry).frames
    assert len(want) == len(pixels)
    for k, (got, frame) in enumerate(zip(pixels, want)):
        off, on = frame.counts[0].astype(np.int64), frame.counts[1].astype(np.int64)
        np.testing.assert_array_equal(got, np.select([on > off, off > on], [255, 0], 128), err_msg=f"frame {k}")
    paths = sorted(p.name for p in tmp_path.glob("live*.rrd"))
    assert len(paths) == 2  # live.rrd for the first camera, live.<camera>.rrd for the other
    for name in paths:
        entities = {c.entity_path for c in RrdReader(tmp_path / name).stream()}
        assert "/events/signal" in entities


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # a viewer's --save stream has none
def test_subscribe_logs_into_a_running_viewer(procs, tmp_path):
    """`subscribe --viewer URL` logs into a Rerun viewer that is already running: here the wheel's own
    `rerun`, listening on loopback and saving what it receives, read back afterwards."""
    from evstream.sinks.rerun_viewer import rerun_binary, wait_listening
    from rerun.chunk import RrdReader

    rr_port, port = free_port(), free_port()
    received, log = tmp_path / "received.rrd", tmp_path / "rerun.log"
    with open(log, "wb") as out:
        viewer = subprocess.Popen([rerun_binary(), "--bind", "127.0.0.1", "--port", str(rr_port), "--save",
                                   str(received)], stdout=out, stderr=subprocess.STDOUT)
    try:
        wait_listening(viewer, "127.0.0.1", [rr_port], 30.0, log)
        ep = f"tcp/127.0.0.1:{port}"
        procs.router(port)
        sub = procs.subscriber(port, "evstream/*/events", "--viewer", f"rerun+http://127.0.0.1:{rr_port}/proxy",
                               "--flow", "block", "--until-end", "--idle-s", "40")
        procs.result(procs.start("publish", str(BAR), "--key", "evstream/cam1/events", "--connect", ep, "--speed", "0",
                                 "--wait-subscribers", "10", "--json"))
        out = procs.result(sub)
    finally:
        viewer.send_signal(signal.SIGINT)  # the receiver finishes its file
        try:
            viewer.wait(timeout=20)
        except subprocess.TimeoutExpired:  # fail, but leave no viewer listening behind
            viewer.kill()
            viewer.wait()
            raise
    assert out["output"] == "connect" and out["cameras"]["cam1"]["events"] == 174_999
    points = 0
    for chunk in RrdReader(received).stream():
        if chunk.entity_path.startswith("/events/") and not chunk.is_static:
            rb = chunk.to_record_batch()
            if "Points3D:positions" in rb.schema.names:
                points += sum(len(row) for row in rb.column(rb.schema.names.index("Points3D:positions")).to_pylist())
    cam = out["cameras"]["cam1"]
    # a live viewer draws at most its wall-clock budget of points (publish --speed 0 sends 0.3 s of events
    # in a fraction of that): what it drew is in the viewer, what it left out is counted, nothing else
    assert points == cam["points_drawn"] > 0
    assert cam["points_drawn"] + cam["points_dropped"] == 174_999


def _port_free(port: int) -> bool:
    """Nothing listens on 127.0.0.1:`port` (SO_REUSEADDR, as Zenoh binds: old TIME_WAIT connections are fine)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_no_flags_means_a_client_of_the_router_on_the_default_endpoint():
    from evstream.sources.zenoh_session import DEFAULT_ENDPOINT, endpoints

    assert endpoints(None) == ("client", [], [DEFAULT_ENDPOINT])
    assert endpoints("router") == ("router", [DEFAULT_ENDPOINT], [])
    assert endpoints(None, connect=["tcp/127.0.0.1:1"]) == ("client", [], ["tcp/127.0.0.1:1"])
    assert endpoints(None, listen=["tcp/127.0.0.1:1"]) == ("peer", ["tcp/127.0.0.1:1"], [])


def test_no_router_is_one_line_naming_the_endpoint_and_how_to_start_one(tmp_path):
    port = free_port()
    for args in (["subscribe", "evstream/*/events", "--idle-s", "1"],
                 ["publish", str(BAR), "--key", "evstream/front/events"]):
        r = subprocess.run([sys.executable, "-m", "evstream.cli", *args, "--connect", f"tcp/127.0.0.1:{port}"],
                           cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1, r.stderr
        assert f"tcp/127.0.0.1:{port}" in lines[0] and "evstream router" in lines[0]
    if not _port_free(7447):
        pytest.skip("port 7447 is in use: cannot try the no-flag commands without a router")
    for args in (["subscribe", "evstream/*/events", "--idle-s", "1"],
                 ["publish", str(BAR), "--key", "evstream/front/events"]):
        r = subprocess.run([sys.executable, "-m", "evstream.cli", *args], cwd=ROOT, capture_output=True, text=True,
                           timeout=TIMEOUT_S)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1, r.stderr
        assert "tcp/127.0.0.1:7447" in lines[0] and "`evstream router`" in lines[0]


def test_readme_live_commands_with_no_flags_deliver_every_event(procs):
    """The README's three commands exactly, on the default endpoint tcp/127.0.0.1:7447: no --connect."""
    if not _port_free(7447):
        pytest.skip("port 7447 is in use (another router?): the no-flag commands need it free")
    router = procs.start("router")
    procs.wait_for(router, "listening on tcp/127.0.0.1:7447")
    sub = procs.start("subscribe", "evstream/*/events", "--until-end", "--json")
    procs.wait_for(sub, "subscribed to")
    pub = procs.start("publish", str(BAR), "--key", "evstream/front/events", "--wait-subscribers", "10", "--json")
    sent, got = procs.result(pub), procs.result(sub)
    n = len(_events(BAR)[0])
    assert sent["events"] == n and sent["unmatched_packets"] == 0
    front = got["cameras"]["front"]
    assert front["events"] == n and front["missing"] == 0 and got["stopped_by"] == "end of stream"


def test_a_rejected_packet_leaves_the_sequence_alone_and_upper_case_evt3_is_refused(procs, tmp_path):
    """A packet claiming seq 2^64-1 whose events lie outside its sensor is malformed, nothing more: no gap,
    no restart, no pipeline reset, no second archive. A packet with encoding "EVT3" is refused as
    event_camera_codecs refuses it (encoding names are lower case)."""
    import dataclasses

    from evstream.codecs.event_packet import decode_packet

    port = free_port()
    procs.router(port)
    sub = procs.subscriber(port, "evstream/cam1/events", "--denoise", "none", "--archive",
                           str(tmp_path / "seq.mcap"), "--until-end", "--idle-s", "40")
    t, x, y, p, g = ev = _events(TURNTABLE)
    good = _numbered_packets(ev, 3)
    hostile = encode_packet(to_packet(t[3000:3010], x[3000:3010], y[3000:3010], p[3000:3010], width=8, height=8,
                                      seq=2**64 - 1))
    upper = encode_packet(dataclasses.replace(decode_packet(good[1]), encoding="EVT3", seq=1))
    session = open_session(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        pub = matched_publisher(session, "evstream/cam1/events")
        pub.put(good[0], attachment=encode_attachment(0, time.time_ns()))
        pub.put(hostile, attachment=encode_attachment(2**64 - 1, time.time_ns()))
        pub.put(upper, attachment=encode_attachment(1, time.time_ns()))
        pub.put(good[1], attachment=encode_attachment(1, time.time_ns()))
        pub.put(good[2], attachment=encode_attachment(2, time.time_ns()))
        _end_stream(session, pub)
        out = procs.result(sub, timeout_s=30)
    finally:
        session.close()
    c1 = out["cameras"]["cam1"]
    assert c1["malformed"] == 2 and c1["packets"] == 3 and c1["events"] == 3000
    assert c1["missing"] == 0 and c1["gaps"] == 0 and c1["restarts"] == 0 and c1["last_seq"] == 2
    assert c1["archives"] == [str(tmp_path / "seq.mcap")] and not (tmp_path / "seq.1.mcap").exists()
    err = procs.stderr(sub)
    assert "restarted" not in err and "'EVT3'" in err and "lower case" in err
    assert sum(len(c) for c in open_source(tmp_path / "seq.mcap")) == 3000


def _peak_rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 1024


def test_a_huge_put_is_dropped_by_the_transport_before_it_fills_a_router_or_subscriber(procs):
    """Zenoh's reassembly limit (transport/link/rx/max_message_size) follows --max-packet-bytes on the router
    and the subscriber: a 48 MiB put passes a router taking 56 MB but not a subscriber taking 1 MB, a 160 MiB
    put passes neither; neither process's peak memory grows by the message (a few MB of Zenoh's buffers),
    the link stays up, and the sequence numbers the dropped messages carried are counted in `missing`."""
    port = free_port()
    router = procs.start("router", "--listen", f"tcp/127.0.0.1:{port}", "--max-packet-bytes", "56000000")
    procs.wait_for(router, "listening on")
    sub = procs.subscriber(port, "evstream/cam1/events", "--denoise", "none", "--max-packet-bytes", "1000000",
                           "--until-end", "--idle-s", "60")
    good = _numbered_packets(_events(TURNTABLE), 5)
    session = open_session(connect=[f"tcp/127.0.0.1:{port}"], max_packet_bytes=1 << 30)
    try:
        pub = matched_publisher(session, "evstream/cam1/events")
        for k in (0, 1):
            pub.put(good[k], attachment=encode_attachment(k, time.time_ns()))
        drain(session)
        time.sleep(1.0)  # both taken in: what the subscriber needs for packets is allocated
        base_router, base_sub = _peak_rss_mb(router.pid), _peak_rss_mb(sub.pid)
        pub.put(bytes(48 << 20), attachment=encode_attachment(2, time.time_ns()))  # passes the router only
        drain(session, 30)
        pub.put(bytes(160 << 20), attachment=encode_attachment(3, time.time_ns()))  # passes neither
        drain(session, 30)
        time.sleep(1.0)
        grown_router, grown_sub = _peak_rss_mb(router.pid) - base_router, _peak_rss_mb(sub.pid) - base_sub
        pub.put(good[4], attachment=encode_attachment(4, time.time_ns()))  # the link is still up
        _end_stream(session, pub)
        out = procs.result(sub, timeout_s=30)
    finally:
        session.close()
    assert grown_sub < 32, f"subscriber peak memory grew by {grown_sub:.0f} MB (a 48 MiB message went by)"
    assert grown_router < 128, f"router peak memory grew by {grown_router:.0f} MB (a 160 MiB message went by)"
    c1 = out["cameras"]["cam1"]
    assert c1["packets"] == 3 and c1["events"] == 3000 and c1["oversized"] == 0
    assert c1["missing"] == 2 and c1["gaps"] == 1 and c1["last_seq"] == 4


def _cycled_packets(n: int):
    """`n` EventPackets (seq 0..n-1) of the turntable, 1000 events each, cycled with time moving on."""
    import dataclasses

    from evstream.codecs.event_packet import decode_packet

    t, x, y, p, g = _events(TURNTABLE)
    base = [decode_packet(encode_packet(to_packet(t[i:i + 1000], x[i:i + 1000], y[i:i + 1000], p[i:i + 1000],
                                                  width=g.width, height=g.height)))
            for i in range(0, len(t) - 1000, 1000)]
    span_ns = (int(t[-1]) + 1) * 1000
    return (encode_packet(dataclasses.replace(base[k % len(base)], seq=k,
                                              time_base=base[k % len(base)].time_base + (k // len(base)) * span_ns))
            for k in range(n))


def test_block_survives_a_subscriber_that_pauses_longer_than_zenohs_5_s(procs):
    """A --flow block subscriber stopped for 7 s while a BLOCK publisher streams: the publisher waits, then
    everything arrives. With Zenoh's default (block/wait_before_close 5 s) the router closed the
    subscriber's link after 5 s and what was in flight was lost (counted in `missing`)."""
    port = free_port()
    procs.router(port)
    sub = procs.subscriber(port, "evstream/cam1/events", "--denoise", "none", "--depth", "8", "--until-end",
                           "--idle-s", "60")
    n = 20_000  # ~6 KB each, 120 MB: more than the links and queues hold
    session = open_session(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        pub = matched_publisher(session, "evstream/cam1/events")
        time.sleep(0.5)
        os.kill(sub.pid, signal.SIGSTOP)
        put_before_resume = []
        resume = threading.Timer(7.0, lambda: (put_before_resume.append(k), os.kill(sub.pid, signal.SIGCONT)))
        resume.start()
        for k, data in enumerate(_cycled_packets(n)):
            pub.put(data, attachment=encode_attachment(k, time.time_ns()))
        resume.join()
        assert put_before_resume and put_before_resume[0] < n - 1, "the publisher was not held back"
        drain(session, 60)
        pub.delete()
        drain(session)
        out = procs.result(sub, timeout_s=60)
    finally:
        session.close()
    c1 = out["cameras"]["cam1"]
    assert "lost the connection" not in procs.stderr(sub)
    assert c1["missing"] == 0 and c1["malformed"] == 0 and c1["packets"] == n


def test_a_republishing_node_counts_what_it_put_after_its_reader_was_killed(procs, tmp_path):
    """The cleaned stream's only reader is killed mid-stream: what the node republishes from then on went to
    nobody, and the node says how many packets (it said nothing). What the reader held when it died is
    not counted anywhere: Zenoh does not tell a publisher (docs/live.md)."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    reader = procs.subscriber(port, "evstream/*/events/clean", "--denoise", "none", "--archive",
                              str(tmp_path / "clean.mcap"))
    node = procs.subscriber(port, "evstream/*/events", "--republish", "--denoise", "none", "--wait-subscribers", "10",
                            "--until-end", "--idle-s", "40", "--drain-s", "2")
    pub = procs.start("publish", str(TURNTABLE), "--key", "evstream/cam1/events", "--connect", ep, "--speed", "0.1",
                      "--wait-subscribers", "10", "--json")
    deadline = time.monotonic() + 30
    while not any(tmp_path.glob("*clean*")) and time.monotonic() < deadline:
        time.sleep(0.05)  # the reader's archive opens with its first packet
    time.sleep(1.0)
    reader.kill()
    sent, out = procs.result(pub), procs.result(node)
    cam = out["cameras"]["cam1"]
    assert cam["events"] == sent["events"] and cam["missing"] == 0
    assert 0 < cam["published_unmatched_packets"] < cam["published_packets"]


def test_packets_lost_just_before_the_end_mark_are_counted(procs):
    """The end mark carries the number of packets sent: packets lost after the last one that arrived (no
    later packet reveals the gap) are counted in `missing` too."""
    port = free_port()
    procs.router(port)
    sub = procs.subscriber(port, "evstream/cam1/events", "--denoise", "none", "--until-end", "--idle-s", "30")
    good = _numbered_packets(_events(TURNTABLE), 2)
    session = open_session(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        pub = matched_publisher(session, "evstream/cam1/events")
        for k in (0, 1):
            pub.put(good[k], attachment=encode_attachment(k, time.time_ns()))
        pub.delete(attachment=encode_attachment(5, time.time_ns()))  # 5 sent: seq 2, 3 and 4 never arrived
        drain(session)
        out = procs.result(sub, timeout_s=30)
    finally:
        session.close()
    c1 = out["cameras"]["cam1"]
    assert c1["packets"] == 2 and c1["missing"] == 3 and c1["gaps"] == 1 and c1["ended"]


def test_one_denoise_node_per_camera_in_processes_of_their_own(procs, tmp_path):
    """N cameras -> one router -> N denoise nodes, each a process subscribed to its camera's key only (the
    node count chosen at start: one `subscribe evstream/CAM/events --republish` per camera) -> one reader
    of every cleaned stream. Each node sees its camera and no other, nothing is lost, and each cleaned
    stream is, event for event, the cascade run on that camera's recording alone."""
    cams = {"cam0": TURNTABLE, "cam1": BAR, "cam2": ROOT / "recordings" / "ball.npz"}
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs.router(port)
    final = procs.subscriber(port, "evstream/*/events/clean", "--denoise", "none", "--until-end", str(len(cams)),
                             "--idle-s", "60", "--archive", str(tmp_path / "clean_{camera}.mcap"))
    nodes = {cam: procs.subscriber(port, f"evstream/{cam}/events", "--republish", "--wait-subscribers", "10",
                                   "--drain-s", "30", "--until-end", "--idle-s", "60")
             for cam in cams}
    pubs = {cam: procs.start("publish", str(path), "--key", f"evstream/{cam}/events", "--connect", ep,
                             "--speed", "0", "--wait-subscribers", "10", "--drain-s", "30", "--json")
            for cam, path in cams.items()}
    sent = {cam: procs.result(p) for cam, p in pubs.items()}
    got = {cam: procs.result(p) for cam, p in nodes.items()}
    clean = procs.result(final)
    assert sorted(clean["cameras"]) == sorted(cams)
    for cam, path in cams.items():
        n = len(_events(path)[0])
        assert sent[cam]["events"] == n and sent[cam]["unmatched_packets"] == 0
        assert list(got[cam]["cameras"]) == [cam]  # its own key: no other camera's packets reach it
        mine = got[cam]["cameras"][cam]
        assert mine["events"] == n and mine["missing"] == 0 and mine["malformed"] == 0
        alone = _alone(path)
        assert [mine["events_signal"], mine["events_background"], mine["events_hot_pixel"]] == alone["counts"]
        assert clean["cameras"][cam]["events"] == mine["events_signal"] and clean["cameras"][cam]["missing"] == 0
        assert_same_events(open_source(tmp_path / f"clean_{cam}.mcap"), alone["kept"])


def test_a_packet_whose_events_go_back_or_leave_the_sensor_is_malformed_and_changes_nothing():
    """Packets through a real Zenoh session (its own subscriber), taken by `ZenohSubscription.handle`: events
    earlier than the camera's last accepted one, time going back inside a packet, or a coordinate outside
    the sensor are one `malformed` each; the camera's time and sequence move on only with good packets."""
    from evstream.sources.zenoh_sub import LivePacket, ZenohSubscription

    g_w, g_h = 16, 8
    n = 50
    t = np.arange(1000, 1000 + 10 * n, 10, dtype=np.int64)
    x = (np.arange(n) % g_w).astype(np.uint16)
    y = (np.arange(n) % g_h).astype(np.uint16)
    p = (np.arange(n) % 2).astype(np.uint8)

    def packet(tt, xx, seq, encoding="evt3"):  # (EVT3's encoder refuses what is wrong: mono carries it)
        return encode_packet(to_packet(tt, xx, y, p, width=g_w, height=g_h, seq=seq, encoding=encoding))

    later = t + 10 * n
    inner_back = t.copy()
    inner_back[20:] -= 100  # steps back by 100 µs at event 20, still after the first packet's time base
    wide = x.copy()
    wide[7] = g_w  # one column past the sensor
    sent = [(packet(t, x, 0), True), (packet(t - 400, x, 1), False), (packet(later, wide, 1, "mono"), False),
            (packet(inner_back + 10 * n, x, 1, "mono"), False), (packet(later, x, 1), True)]
    port = free_port()
    session = open_session(mode="peer", listen=[f"tcp/127.0.0.1:{port}"])
    try:
        sub = ZenohSubscription("evstream/cam/events", session=session, warn=lambda m: None)
        for data, _ in sent:
            session.put("evstream/cam/events", data)
        got = []
        deadline = time.monotonic() + 20
        while len(got) < len(sent) and time.monotonic() < deadline:
            sample = sub._sub.try_recv()
            if sample is None:
                time.sleep(0.01)
                continue
            got.append(sub.handle(sample))
        sub.close()
    finally:
        session.close()
    assert [isinstance(item, LivePacket) for item in got] == [ok for _, ok in sent]
    st = sub.cameras["cam"]
    assert st.malformed == 3 and st.packets == 2 and st.events == 2 * n
    assert st.restarts == 0 and st.gaps == 0 and st.last_seq == 1 and st.last_t == int(later[-1])
    assert np.array_equal(got[-1].chunk.t, later)


def test_a_packet_whose_time_goes_back_before_an_event_leaves_the_sensor_is_named_by_the_first(tmp_path):
    """Session 9's audit: the off-sensor event was named even when the time going back came first."""
    from evstream.sources.zenoh_sub import ZenohSubscription

    port = free_port()
    said: list[str] = []
    pub_session = open_session(listen=[f"tcp/127.0.0.1:{port}"])
    try:
        t = np.array([10, 20, 15, 30, 40], np.int64)  # event 2 goes back in time, event 4 is off the 8x8 sensor
        x = np.array([1, 1, 1, 1, 9], np.uint16)
        packet = encode_packet(to_packet(t, x, np.ones(5, np.uint16), np.zeros(5, np.uint8), width=8, height=8,
                                         encoding="mono"))
        with ZenohSubscription("evstream/cam/events", connect=[f"tcp/127.0.0.1:{port}"], idle_s=20,
                               should_stop=lambda: bool(said), warn=said.append) as sub:
            pub = matched_publisher(pub_session, "evstream/cam/events")
            pub.put(packet, attachment=encode_attachment(0, time.time_ns()))
            drain(pub_session)
            assert not [item for item in sub if getattr(item, "chunk", None) is not None]
    finally:
        pub_session.close()
    assert said == ["evstream/cam/events: malformed packet skipped: event time goes back"]
