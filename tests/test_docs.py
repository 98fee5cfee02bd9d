"""Every ```sh / ```bash block of README.md and docs/*.md, run as written.

A block runs in a scratch mirror of the repository (its files linked, `out/`, `docs/` and `recordings/`
copied, so what a block writes never lands in the tree) with the venv's bin first on PATH. Only what
must be is substituted: a free port for a loopback endpoint a block names. Long-running commands
(`evstream router`, `evstream subscribe` without `--until-end`, anything with `--serve`) start as real
background processes, each waited for until it is ready, and are stopped with Ctrl-C at the end of the
block; a subscriber must then have received every event the block's `publish` sent. Every other command
must exit 0 and create the `out/...` paths it names. A line `<!-- doc-test: skip: REASON -->` just
before a fence skips that block with the reason; ```text blocks are synopses, not run.
"""

from __future__ import annotations

import fcntl
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import REAL_DATA, real_data_skip_reason

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BIN = Path(sys.executable).parent
FENCE = re.compile(r"^(`{3,})(\S*)\s*$")
SKIP = re.compile(r"^<!--\s*doc-test:\s*skip:\s*(.+?)\s*-->\s*$")
COPIED = ("out", "docs", "recordings")  # what blocks may write into; everything else is linked
DEFAULT_ROUTER_PORT = 7447
COMMAND_TIMEOUT_S = 300


@dataclass
class Block:
    path: Path
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    skip: str | None

    @property
    def id(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def blocks(path: Path) -> list[Block]:
    """The fenced blocks of a Markdown file, with the skip mark of the line before each."""
    lines = path.read_text(encoding="utf-8").splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, lang, start = m.group(1), m.group(2), i
        j = i + 1
        while j < len(lines) and lines[j].rstrip() != fence:
            j += 1
        mark = SKIP.match(lines[start - 1]) if start else None
        out.append(Block(path, start + 1, lang, "\n".join(lines[start + 1 : j]), mark.group(1) if mark else None))
        i = j + 1
    return out


ALL_BLOCKS = [b for p in DOCS for b in blocks(p)]
SHELL_BLOCKS = [b for b in ALL_BLOCKS if b.lang in ("sh", "bash")]


def commands(text: str) -> list[str]:
    """The block's commands: continuation lines joined, blank and comment-only lines dropped."""
    out, cur = [], ""
    for raw in text.splitlines():
        line = raw.rstrip()
        if line.endswith("\\"):
            cur += line[:-1] + " "
            continue
        cur += line
        if cur.strip() and not cur.lstrip().startswith("#"):
            out.append(cur.strip())
        cur = ""
    return out


def words(command: str) -> list[str]:
    return shlex.split(command, comments=True)


def is_server(command: str) -> bool:
    """A command that runs until stopped: a router, a subscriber not told to stop, a web viewer."""
    w = words(command)
    if w[:2] == ["evstream", "router"]:
        return "--duration-s" not in w
    if w[:2] == ["evstream", "subscribe"]:
        return not {"--until-end", "--duration-s", "--idle-s"} & set(w)
    return "--serve" in w


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def substitute_ports(text: str) -> str:
    """Each loopback port a block names becomes one free port (the same port wherever it recurs)."""
    ports: dict[str, int] = {}

    def repl(m):
        return f"{m.group(1)}{ports.setdefault(m.group(2), free_port())}"

    return re.sub(r"(127\.0\.0\.1:|localhost:)(\d{2,5})\b", repl, text)


def uses_default_router(block_commands: list[str]) -> bool:
    live = [words(c) for c in block_commands if words(c)[:2] in (["evstream", "router"], ["evstream", "subscribe"],
                                                                  ["evstream", "publish"])]
    return any("--connect" not in w and "--listen" not in w for w in live)


def mirror(tmp: Path) -> Path:
    """A scratch copy of the repository to run a block in: files linked, writable folders copied."""
    tmp.mkdir()
    for entry in ROOT.iterdir():
        if entry.name in COPIED or entry.name in (".git", ".pytest_cache"):
            continue
        (tmp / entry.name).symlink_to(entry)
    for name in COPIED[1:]:
        shutil.copytree(ROOT / name, tmp / name, ignore=shutil.ignore_patterns("__pycache__"))
    (tmp / "out").mkdir()
    return tmp


def environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def out_paths(command: str) -> list[str]:
    """The out/... paths a command names (for a check that it made them)."""
    return [w for w in words(command) if w.startswith("out/") and "{" not in w and "*" not in w]


class Server:
    def __init__(self, command: str, cwd: Path, env: dict, log: Path):
        self.command = command
        self.out, self.err = log.with_suffix(".out"), log.with_suffix(".err")
        self.proc = subprocess.Popen(["bash", "-c", f"exec {command}"], cwd=cwd, env=env,
                                     stdout=self.out.open("w"), stderr=self.err.open("w"),
                                     start_new_session=True)

    def text(self) -> tuple[str, str]:
        return self.out.read_text(), self.err.read_text()

    def wait_ready(self, timeout_s: float = 60.0):
        """Until the process says it is listening or subscribed (or has died)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            out, err = self.text()
            if self.proc.poll() is not None:
                pytest.fail(f"`{self.command}` exited with {self.proc.returncode} before it was ready:\n{out}{err}")
            if re.search(r"listening on|subscribed to|serving|web viewer:", out + err):
                return
            time.sleep(0.1)
        pytest.fail(f"`{self.command}` was not ready after {timeout_s:g} s:\n{out}{err}")

    def stop(self, timeout_s: float = 30.0) -> int:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        return self.proc.returncode


@pytest.fixture
def default_router_port():
    """Blocks that rely on the default endpoint need tcp/127.0.0.1:7447 for themselves; doc tests of
    other checkouts on this machine take turns through a lock file."""
    with open(Path("/tmp") / f"evstream-doc-test-{DEFAULT_ROUTER_PORT}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        deadline = time.monotonic() + 60
        while True:
            with socket.socket() as s:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    s.bind(("127.0.0.1", DEFAULT_ROUTER_PORT))
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        pytest.fail(f"port {DEFAULT_ROUTER_PORT} stays busy: the block needs the default router port")
                    time.sleep(1)
        yield DEFAULT_ROUTER_PORT


def run_block(block: Block, tmp_path: Path):
    work = mirror(tmp_path / "repo")
    if "../shared/data/real" in block.text:  # the real recordings beside the mirror, as beside the checkout
        if not REAL_DATA.is_dir():
            pytest.skip(real_data_skip_reason())
        (tmp_path / "shared" / "data").mkdir(parents=True)
        (tmp_path / "shared" / "data" / "real").symlink_to(REAL_DATA)
    logs = tmp_path / "logs"
    logs.mkdir()
    env = environment()
    servers: list[Server] = []
    published: list[int] = []
    try:
        for i, command in enumerate(commands(substitute_ports(block.text))):
            if is_server(command):
                servers.append(Server(command, work, env, logs / f"{i}"))
                servers[-1].wait_ready()
                continue
            before = {p for p in out_paths(command) if (work / p).exists()}
            r = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", command], cwd=work, env=env,
                               capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
            assert r.returncode == 0, (f"{block.id}: `{command}` exited with {r.returncode}\n"
                                       f"stdout:\n{r.stdout[-3000:]}\nstderr:\n{r.stderr[-3000:]}")
            for p in out_paths(command):
                if p not in before and not p.endswith("/"):
                    assert (work / p).exists(), f"{block.id}: `{command}` did not create {p}"
            if words(command)[:2] == ["evstream", "publish"]:
                m = re.search(r"published ([\d,]+) events", r.stdout)
                assert m, f"{block.id}: `{command}` did not say what it published:\n{r.stdout}"
                published.append(int(m.group(1).replace(",", "")))
    finally:
        codes = [(s, s.stop()) for s in reversed(servers)]  # subscribers before the router they use
    for server, code in codes:
        out, err = server.text()
        assert code == 0, f"{block.id}: `{server.command}` ended with {code} after Ctrl-C:\n{out}{err}"
        if words(server.command)[:2] == ["evstream", "subscribe"] and published:
            m = re.search(r"([\d,]+) events in [\d,]+ packets", out)
            got = int(m.group(1).replace(",", "")) if m else 0
            assert got == sum(published), (f"{block.id}: `{server.command}` received {got:,} events of the "
                                           f"{sum(published):,} published:\n{out}{err}")


@pytest.mark.parametrize("block", SHELL_BLOCKS, ids=[b.id for b in SHELL_BLOCKS])
def test_documented_commands_run_as_written(block, tmp_path, request):
    if block.skip:
        pytest.skip(block.skip)
    if uses_default_router(commands(block.text)):
        request.getfixturevalue("default_router_port")
    stamp, project = ROOT / ".venv" / ".installed", ROOT / "pyproject.toml"
    if "make " in block.text and (not stamp.exists() or stamp.stat().st_mtime < project.stat().st_mtime):
        pytest.skip("the venv is older than pyproject.toml: `make` would reinstall it (run `make` first)")
    run_block(block, tmp_path)


def test_every_fenced_block_says_what_it_is():
    """A fence without a language would dodge the test above; commands go in sh/bash, synopses in text."""
    bare = [b.id for b in ALL_BLOCKS if not b.lang]
    assert not bare, f"fenced blocks without a language (sh, bash, text, toml, ...): {bare}"


def test_skip_marks_sit_on_shell_blocks_and_give_a_reason():
    for path in DOCS:
        lines = path.read_text(encoding="utf-8").splitlines()
        for n, line in enumerate(lines):
            if "doc-test:" in line:
                assert SKIP.match(line), f"{path.name}:{n + 1}: malformed mark (want <!-- doc-test: skip: REASON -->)"
                nxt = FENCE.match(lines[n + 1]) if n + 1 < len(lines) else None
                assert nxt and nxt.group(2) in ("sh", "bash"), f"{path.name}:{n + 1}: a skip mark not before a sh block"


def test_the_block_parser_reads_what_a_shell_would():
    text = ("# comment\nevstream a \\\n    --b 'x y'   # note\n\nevstream router --listen tcp/127.0.0.1:7447\n"
            "evstream subscribe 'k/*' --connect tcp/127.0.0.1:7447\nevstream subscribe k --until-end\n")
    cmds = commands(text)
    assert cmds[0] == "evstream a      --b 'x y'   # note" and words(cmds[0]) == ["evstream", "a", "--b", "x y"]
    assert [is_server(c) for c in cmds] == [False, True, True, False]
    sub = substitute_ports(text)
    ports = set(re.findall(r"127\.0\.0\.1:(\d+)", sub))
    assert len(ports) == 1 and "7447" not in ports
    assert not uses_default_router(cmds[1:3]) and uses_default_router(cmds[3:])
