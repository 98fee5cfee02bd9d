"""`--spawn` where no desktop viewer can open a window: one line saying so and what to use instead, exit 1,
never the SDK's "gRPC connection severed" internal error (issue 15 item 4)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from evstream.sinks.rerun_viewer import DEFAULT_GRPC_PORT, NO_DISPLAY, free_port, is_listening

ROOT = Path(__file__).resolve().parents[1]
BAR = ROOT / "recordings" / "bar.npz"


def run(env_extra: dict, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    if is_listening("127.0.0.1", DEFAULT_GRPC_PORT):  # seen when another checkout's viewer was up
        pytest.skip(f"a viewer already listens on 127.0.0.1:{DEFAULT_GRPC_PORT}: --spawn logs into it, as it should")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(env_extra)
    return subprocess.run([sys.executable, "-m", "evstream.cli", *args], env=env, cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize("command", [["replay", str(BAR), "--spawn"],
                                     ["subscribe", "evstream/*/events", "--spawn", "--duration-s", "1"]])
def test_spawn_without_a_display_says_so_in_one_line(tmp_path, command):
    if command[0] == "subscribe":
        command = [*command, "--connect", f"tcp/127.0.0.1:{free_port()}"]
    r = run({}, tmp_path, *command)
    assert r.returncode == 1, r.stderr
    assert r.stderr.strip().splitlines() == [f"evstream: error: {NO_DISPLAY}"], r.stderr
    assert "--save" in NO_DISPLAY and "--serve" in NO_DISPLAY


def test_spawn_with_a_display_that_refuses_a_window_says_so_in_one_line(tmp_path):
    number = next(n for n in range(77, 200) if not Path(f"/tmp/.X11-unix/X{n}").exists())
    r = run({"DISPLAY": f":{number}"}, tmp_path, "replay", str(BAR), "--spawn", "--json")
    assert r.returncode == 1, r.stderr
    lines = [ln for ln in r.stderr.strip().splitlines() if ln]
    # the viewer dies before or after it listens, as the machine's load has it: one line either way
    assert len(lines) == 1 and lines[0].startswith("evstream: error: the "), r.stderr
    assert "viewer exited" in lines[0], r.stderr
    assert "--save" in lines[0] and "severed" not in r.stderr and "internal error" not in r.stderr
