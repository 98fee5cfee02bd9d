"""Every script in examples/ runs as the docs say, and prints what the API computes in this process."""

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np

import evstream

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
BIN = Path(sys.executable).parent


def run(*argv, timeout=300) -> str:
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    r = subprocess.run([sys.executable, *map(str, argv)], cwd=ROOT, capture_output=True, text=True,
                       timeout=timeout, env=env)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_every_example_is_tested_here():
    here = Path(__file__).read_text()
    names = sorted(p.name for p in EXAMPLES.glob("*.py"))
    assert len(names) >= 4 and [n for n in names if f'"{n}"' not in here] == []


def test_replay_count():
    out = run(EXAMPLES / "replay_count.py", "recordings/turntable.npz")
    classes = evstream.classify("paper", evstream.read(ROOT / "recordings/turntable.npz"))
    for c in evstream.NoiseClass:
        assert f"{c.name.lower():<11} {int((classes == c).sum()):>10,}" in out
    out = run(EXAMPLES / "replay_count.py", "recordings/bar.npz", "--denoise", "stcf", "--set", "tau_us=10000")
    classes = evstream.classify(evstream.stage("stcf", tau_us=10_000), evstream.read(ROOT / "recordings/bar.npz"))
    assert f"signal      {int((classes == 0).sum()):>10,}" in out


def test_clean_folder(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    (folder / "notes.bin").write_bytes(b"not a recording at all")  # read as N-MNIST: fails midway
    (folder / "notes.xyz").write_bytes(b"\x00\x01 neither")  # no reader takes it
    evstream.convert(ROOT / "recordings/bar.npz", folder / "bar.raw")
    out = run(EXAMPLES / "clean_folder.py", folder, tmp_path / "clean")
    assert f"skipped {folder / 'notes.bin'}: " in out and f"skipped {folder / 'notes.xyz'}: " in out
    assert sorted(p.name for p in (tmp_path / "clean").iterdir()) == ["bar.mcap"]  # nothing half-written left
    archive = evstream.read(tmp_path / "clean" / "bar.mcap")  # every event: the noise on its own topics
    events = evstream.read(ROOT / "recordings/bar.npz")
    signal = int((evstream.classify("paper", events) == 0).sum())
    assert f"wrote {tmp_path / 'clean' / 'bar.mcap'}: {len(events):,} events, {signal:,} signal" in out
    assert len(archive) == len(events)


def test_dataset_transform():
    out = run(EXAMPLES / "dataset_transform.py", "recordings/ball.npz", "--sample-ms", "400")
    events = evstream.read(ROOT / "recordings/ball.npz")
    edges = np.searchsorted(events.t, np.arange(events.t[0], events.t[-1] + 400_000, 400_000))
    lines = out.strip().splitlines()
    assert len(lines) == len(edges) - 1
    for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        kept = int((evstream.classify("paper", events[a:b]) == 0).sum())  # fresh per sample
        assert lines[i].startswith(f"sample {i}: {b - a:,} events -> {kept:,} kept (('x', 'y', 't', 'p'))")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_subscribe_against_a_real_router(tmp_path):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    procs = []
    try:
        router = subprocess.Popen([BIN / "evstream", "router", "--listen", endpoint], cwd=ROOT, env=env,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(router)
        assert "listening on" in router.stdout.readline()
        sub = subprocess.Popen([sys.executable, EXAMPLES / "live_subscribe.py", "--connect", endpoint,
                                "--idle-s", "120"],
                               cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(sub)
        assert sub.stdout.readline().startswith("subscribed to evstream/*/events")
        pub = subprocess.run([BIN / "evstream", "publish", "recordings/bar.npz", "--key", "evstream/cam0/events",
                              "--connect", endpoint, "--speed", "0", "--wait-subscribers", "60"], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=300)
        assert pub.returncode == 0, pub.stderr
        out, err = sub.communicate(timeout=300)
        assert sub.returncode == 0, err
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
    events = evstream.read(ROOT / "recordings/bar.npz")
    c = np.bincount(evstream.classify("paper", events), minlength=3)  # packets are chunks: same classes
    assert out.strip() == (f"cam0: {len(events):,} events: signal {c[0]:,}, background {c[1]:,}, "
                           f"hot pixel {c[2]:,}")
