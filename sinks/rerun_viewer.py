"""Where a Rerun recording goes: an `.rrd` file, a spawned desktop viewer, a served web viewer, or a
viewer already running.

rerun-sdk 0.41's own `spawn` and `serve_grpc`/`serve_web_viewer` listen on all interfaces and take no
bind address, so the viewer and the server here are the `rerun` binary shipped in the wheel, started
with `--bind` (127.0.0.1 unless the user names another address), and the SDK connects to them over
gRPC like any client. The memory limit goes to the viewer (`--memory-limit`: it drops the oldest data
past it) or to the server's buffer for late-joining web viewers (`--server-memory-limit`).
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote, urlsplit

import rerun as rr

DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
DEFAULT_MEMORY_LIMIT = "25%"


def rerun_binary() -> str:
    """The viewer binary from the installed wheel (the same version as the SDK)."""
    import rerun_cli

    path = Path(rerun_cli.__file__).parent / "rerun"
    if not path.is_file():
        raise OSError(f"the rerun viewer binary is missing from the rerun-sdk wheel ({path})")
    return str(path)


NO_DISPLAY = ("no display for the desktop viewer (neither DISPLAY nor WAYLAND_DISPLAY is set): "
              "use --save OUT.rrd, or --serve for the web viewer")


def has_display() -> bool:
    """Whether a desktop viewer could open a window here."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _die_with_parent() -> None:
    """In the child before exec (Linux): SIGTERM it when the process that started it dies, so a
    killed replay leaves no server behind."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _connect_host(bind: str) -> str:
    """Address a local client uses to reach a server bound to `bind`."""
    return "127.0.0.1" if bind in ("0.0.0.0", "", "::", "[::]") else bind


def is_listening(host: str, port: int, timeout_s: float = 0.2) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


def _check_viewer(url: str) -> None:
    """Refuse a viewer URL nothing listens at, at once (the SDK would retry for seconds, then drop
    everything logged): ValueError with the reason."""
    parsed = urlsplit(url)
    if not parsed.scheme.startswith("rerun") or not parsed.hostname:
        raise ValueError(f"viewer URL {url!r}: expected rerun+http://HOST:PORT/proxy")
    port = parsed.port or DEFAULT_GRPC_PORT
    if not is_listening(parsed.hostname, port, timeout_s=2.0):
        raise ValueError(f"no Rerun viewer listening at {url} (start one with `rerun`, or use --spawn)")


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nothing listens on right now (the OS picks it)."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _port_or_free(host: str, port: int) -> int:
    return free_port(host) if is_listening(_connect_host(host), port) else port


def _log_tail(log: Path) -> str:
    """The last line of a viewer's log, without its timestamp and colour codes."""
    import re

    lines = log.read_text(errors="replace").strip().splitlines() if log.exists() else []
    return re.sub(r"\x1b\[[0-9;]*m", "", lines[-1]).strip() if lines else ""


def wait_listening(proc: subprocess.Popen, host: str, ports: list[int], timeout_s: float, log: Path) -> None:
    """Wait until the rerun process `proc` listens on every port; OSError (with its log's last line)
    when it exits first or does not listen in time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise OSError(f"the rerun viewer exited with code {proc.returncode}: {_log_tail(log) or 'no output'}")
        if all(is_listening(host, p) for p in ports):
            return
        time.sleep(0.05)
    proc.terminate()
    raise OSError(f"the rerun viewer did not listen on {host}:{ports} within {timeout_s:.0f} s (log: {log})")


def _wait_window(proc: subprocess.Popen, log: Path, timeout_s: float) -> None:
    """A spawned viewer listens before it opens its window, and exits when the display refuses one (a
    stale DISPLAY): wait for its renderer to start (its log names the wgpu adapter), so that failure is one
    line here rather than "gRPC connection severed" from the SDK later."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise OSError(f"the desktop viewer exited (code {proc.returncode}: {_log_tail(log) or 'no output'}): "
                          "use --save OUT.rrd, or --serve for the web viewer")
        if log.exists() and b"wgpu adapter" in log.read_bytes():
            return
        time.sleep(0.05)


FLUSH_STEP_S = 1.0  # how long one wait for the SDK's flush lasts (signals are handled between waits)
FLUSH_STALL_S = 10.0  # an `.rrd` that has not grown for this long while a flush waits: its writer stopped


def wait_flushed(rec: rr.RecordingStream, part: Path | None = None) -> None:
    """Wait until what was logged has reached its destination, in bounded steps.

    rerun-sdk 0.41's `flush()` waits without end by default, and a file writer that stops on a full disk
    does not always say so ("File-writer thread shut down prematurely"): about half the time the flush
    just never completes. While `part` (the `.rrd` being written) grows, the wait goes on; once it has
    not grown for `FLUSH_STALL_S` (or the disk is full), the recording is set aside for good
    (`_release_never`) and a RuntimeError says the writer stopped."""
    size, since = -1, time.monotonic()
    while True:
        try:
            rec.flush(timeout_sec=FLUSH_STEP_S)
            return
        except RuntimeError as e:
            if "timed out" not in str(e):
                raise
        if part is None:
            continue  # a viewer still taking data: wait on (Ctrl-C reaches us between the waits)
        try:
            now = part.stat().st_size
        except OSError:  # removed under us
            now = -1
        grew, size = now != size, now
        if grew:
            since = time.monotonic()
        if now < 0 or (not grew and (_disk_full(part) or time.monotonic() - since >= FLUSH_STALL_S)):
            _release_never(rec)
            raise RuntimeError("the file writer stopped before the recording was whole")


def _disk_full(path: Path) -> bool:
    try:
        st = os.statvfs(path.parent)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < (4 << 20)


def _release_never(rec: rr.RecordingStream) -> None:
    """rerun-sdk 0.41: a recording whose flush cannot complete blocks forever when it is released (its
    destructor flushes) and so does the SDK's own flush at exit. Keep it alive for the life of the process
    (one reference that is never given back) and skip the SDK's exit flush, so that the process ends."""
    import ctypes

    ctypes.pythonapi.Py_IncRef(ctypes.py_object(rec))
    rr.unregister_shutdown()


class _RrdFile:
    """The SDK's `.rrd` file sink, pointed at a file beside the target (`safe_write`) that is renamed onto
    it when whole. A full disk shows as the SDK's "File-writer thread shut down prematurely" (its Rust log
    lines are off in the CLI, `evstream.cli`): said here as one OSError naming the file, nothing left at
    the target."""

    def __init__(self, rec: rr.RecordingStream, target: str, inputs=(), keep_existing: bool = False):
        from evstream.safe_write import AtomicOutput

        try:
            self.output = AtomicOutput(target, inputs, keep_existing=keep_existing)
        except OSError as e:  # a directory there, a folder not writable
            reason = str(e).removeprefix(f"{target}: ").removeprefix("cannot write there: ")
            raise OSError(f"{target}: cannot write the Rerun recording: {reason}") from None
        try:
            rec.save(str(self.output.part))
        except RuntimeError as e:  # the SDK's "Failed to create file: ...": an I/O error, said as one
            self.output.discard()
            raise OSError(f"{target}: cannot write the Rerun recording: {e}") from None

    def failed(self, e: BaseException) -> OSError:
        from evstream.safe_write import no_space_error

        self.output.discard(keep=False)
        target = self.output.target
        if _disk_full(target):
            return no_space_error(target)
        return OSError(f"{target}: cannot write the Rerun recording: {e}")

    def commit(self) -> None:
        self.output.commit()

    def abandon(self) -> None:
        if not self.output.done:
            self.output.discard(keep=False)


@dataclass
class RerunOutput:
    """An open recording stream and what it is connected to (a child process, URLs to show)."""

    rec: rr.RecordingStream
    mode: str  # "save", "spawn", "serve", "connect"
    process: subprocess.Popen | None = None
    path: str | None = None
    grpc_url: str | None = None
    web_url: str | None = None
    notes: list[str] = field(default_factory=list)
    log: Path | None = None

    file: _RrdFile | None = None

    def finish(self, interrupted: bool = False) -> str | None:
        """Flush and detach the SDK (the file gets its footer and is put in place; a viewer or server keeps
        the data). `interrupted` (Ctrl-C in `replay --save`): the file, whole up to there, is set aside as
        STEM.partial.rrd instead, an older file at the target left as it was. Returns where the file is."""
        with self.guard():
            wait_flushed(self.rec, self.file.output.part if self.file is not None else None)
            self.rec.disconnect()
        if self.file is None:
            return None
        if interrupted:
            return str(self.file.output.set_aside())
        self.file.commit()
        return str(self.file.output.target)

    @contextlib.contextmanager
    def guard(self):
        """Say in one line why the SDK lost the viewer: its RuntimeError "gRPC connection severed" becomes an
        OSError naming the cause (a spawned viewer that exited, with its log's last line)."""
        try:
            yield
        except RuntimeError as e:
            if self.file is not None:  # the SDK's file writer stopped (a full disk): one line naming the file
                raise self.file.failed(e) from None
            if "connection severed" not in str(e) and "transport error" not in str(e):
                raise
            raise OSError(self.lost_viewer()) from None

    def lost_viewer(self) -> str:
        if self.mode == "spawn" and not has_display():
            return NO_DISPLAY
        if self.process is not None and self.process.poll() is not None:
            tail = _log_tail(self.log) if self.log else ""
            what = "desktop viewer" if self.mode == "spawn" else "Rerun server"
            hint = ": use --save OUT.rrd, or --serve for the web viewer" if self.mode == "spawn" else ""
            return f"the {what} exited (code {self.process.returncode}{': ' + tail if tail else ''}){hint}"
        return f"lost the connection to the Rerun viewer at {self.grpc_url}"

    def stop(self) -> None:
        """End a server this process started (spawned desktop viewers stay open); an `.rrd` not finished
        (the run failed) is removed, an older file of that name left as it was."""
        if self.file is not None:
            self.file.abandon()
        if self.process is not None and self.mode == "serve" and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def open_output(*, save: str | None = None, spawn: bool = False, serve: bool = False,
                connect: str | None = None, bind: str = "127.0.0.1",
                memory_limit: str = DEFAULT_MEMORY_LIMIT, grpc_port: int = DEFAULT_GRPC_PORT,
                web_port: int = DEFAULT_WEB_PORT, application_id: str = "evstream",
                log_dir: str | os.PathLike | None = None, inputs=(), keep_existing: bool = False) -> RerunOutput:
    """Open a recording stream for exactly one of `save`, `spawn`, `serve`, `connect` (`inputs`: files the
    saved `.rrd` may not be; `keep_existing`: `save` is a name the program chose, and a file there is left
    as it is, the recording going to `STEM.N.rrd`: `finish` says where)."""
    chosen = [m for m, on in (("save", save), ("spawn", spawn), ("serve", serve), ("connect", connect)) if on]
    if len(chosen) != 1:
        raise ValueError(f"choose one Rerun output (save, spawn, serve or connect), got {chosen or 'none'}")
    rec = rr.RecordingStream(application_id)
    log_dir = Path(log_dir) if log_dir else Path(os.environ.get("TMPDIR", "/tmp"))
    if save:
        Path(save).parent.mkdir(parents=True, exist_ok=True)
        return RerunOutput(rec, "save", path=save, file=_RrdFile(rec, save, inputs, keep_existing))
    if connect:
        _check_viewer(connect)
        rec.connect_grpc(connect)
        return RerunOutput(rec, "connect", grpc_url=connect)
    exe = rerun_binary()
    host = _connect_host(bind)
    if spawn:
        url = f"rerun+http://{host}:{grpc_port}/proxy"
        if is_listening(host, grpc_port):  # a viewer is already there: log into it, as rr.spawn does
            rec.connect_grpc(url)
            return RerunOutput(rec, "spawn", grpc_url=url, notes=[f"using the viewer at {url}"])
        if not has_display():
            raise OSError(NO_DISPLAY)
        log = log_dir / f"evstream-rerun-viewer-{grpc_port}.log"
        with open(log, "wb") as out:
            proc = subprocess.Popen(
                [exe, "--bind", bind, "--port", str(grpc_port), "--memory-limit", memory_limit,
                 "--expect-data-soon"],
                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                start_new_session=True,  # the viewer outlives the replay
                env={**os.environ, "RERUN_APP_ONLY": "true"},
            )
        try:
            wait_listening(proc, host, [grpc_port], 30.0, log)
        except OSError as e:  # e.g. the display refused a window before the viewer listened
            raise OSError(f"{e}: use --save OUT.rrd, or --serve for the web viewer") from None
        _wait_window(proc, log, 5.0)
        rec.connect_grpc(url)
        return RerunOutput(rec, "spawn", process=proc, grpc_url=url, log=log)
    # serve: a gRPC server buffering the stream plus the web viewer, both on `bind`
    grpc_port = _port_or_free(bind, grpc_port)
    web_port = _port_or_free(bind, web_port)
    log = log_dir / f"evstream-rerun-serve-{grpc_port}.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [exe, "--serve-web", "--bind", bind, "--port", str(grpc_port), "--web-viewer-port", str(web_port),
             "--server-memory-limit", memory_limit],
            stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
            env={**os.environ, "RERUN_APP_ONLY": "true"},
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )
    wait_listening(proc, host, [grpc_port, web_port], 30.0, log)
    grpc_url = f"rerun+http://{host}:{grpc_port}/proxy"
    shown = socket.gethostname() if host != bind else host
    web_url = f"http://{shown}:{web_port}/?url={quote(f'rerun+http://{shown}:{grpc_port}/proxy', safe='')}"
    rec.connect_grpc(grpc_url)
    return RerunOutput(rec, "serve", process=proc, grpc_url=grpc_url, web_url=web_url, log=log)


def serve_file(path: str | os.PathLike, *, bind: str = "127.0.0.1", log_dir: str | os.PathLike | None = None
               ) -> tuple[subprocess.Popen, str]:
    """Serve a file Rerun opens (.rrd, .mcap) to the web viewer: the `rerun --serve-web` process (end it
    with `terminate()`) and the page's URL. Both ports are free ones on `bind`."""
    exe = rerun_binary()
    host = _connect_host(bind)
    grpc_port, web_port = free_port(host), free_port(host)
    log = Path(log_dir or os.environ.get("TMPDIR", "/tmp")) / f"evstream-rerun-file-{grpc_port}.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [exe, "--serve-web", "--bind", bind, "--port", str(grpc_port), "--web-viewer-port", str(web_port),
             str(path)], stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
            env={**os.environ, "RERUN_APP_ONLY": "true"},
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )
    wait_listening(proc, host, [grpc_port, web_port], 30.0, log)
    return proc, f"http://{host}:{web_port}/?url={quote(f'rerun+http://{host}:{grpc_port}/proxy', safe='')}"
