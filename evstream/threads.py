"""Both cores for one run: reading ahead of the stages and writing behind them, on threads.

The numba kernels (decoders, stages, encoders) run `nogil`, and zstd, zlib and file I/O release the GIL
too, so a reader thread (`ReadAhead`: the source's decoding), the caller's thread (the stages) and a
writer thread (`WriteBehind`: the sinks' encoding, compression and writing) overlap on a small machine.

- Memory stays constant: each queue holds at most `depth` items (chunks or batches), however long the
  recording.
- Order and output are those of a serial run: one thread per role, FIFO queues, every item handed on.
- An error in a thread is raised, as it was raised there, where the caller next touches the queue
  (its next chunk, its next write, or `close`): the command line reports it in one line as before.
- Stopping early (Ctrl-C, an error in the stages) stops the reader at its next chunk and lets the
  writer finish what it was given, so sinks close a file whole up to there.

`EVSTREAM_THREADS=0` (or 1) in the environment runs every command serially (or threaded), for comparisons
and debugging; without it each command uses what measured faster for it (`enabled(default)`).
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

__all__ = ["ReadAhead", "WriteBehind", "enabled", "take"]

_END = object()
_POLL_S = 0.05  # how often a blocked thread looks whether it should stop


def take(q: queue.Queue) -> Any:
    """`q.get()` for a thread that the main thread hands items to, which a Ctrl-C cannot leave asleep.

    A KeyboardInterrupt that lands in the main thread's `put` after it woke the waiting thread and before it
    struck that thread off the condition's list (threading.Condition.notify) leaves a stale entry there;
    the next `put` then wakes that entry, not the thread, which would sleep forever beside an item (seen as
    `convert` hanging after Ctrl-C). A timed wait looks at the queue again every `_POLL_S`."""
    while True:
        try:
            return q.get(timeout=_POLL_S)
        except queue.Empty:
            continue


def enabled(default: bool = True) -> bool:
    """Whether a command overlaps reading, stages and writing: EVSTREAM_THREADS (0/1) when set, else the
    command's `default` — measured per command (docs/archive.md): on this project's 2-core machine threads
    pay in `archive`; `replay --save` threaded outruns Rerun's encoder, whose queue then grows with the
    recording (no bound on memory), and `convert`'s RAW encoder already has a thread of its own."""
    value = os.environ.get("EVSTREAM_THREADS")
    if value is None or not value.strip():
        return default
    return value.strip().lower() not in ("0", "no", "off", "false")


class ReadAhead:
    """Iterate `items` on a thread, at most `depth` items ahead of the consumer; iterate this (once) for
    them in order. The source's own error is raised by the iteration at the point it happened.
    `close()` (also at the end of the iteration, or when the consumer stops early) stops the thread at
    its next item and waits for it, so the source's files are closed before the caller goes on."""

    def __init__(self, items: Iterable[Any], depth: int = 2, name: str = "evstream-reader"):
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        self._items = items
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self.cpu_s = 0.0  # the reader thread's CPU time, once it ended
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        it = None
        try:
            it = iter(self._items)
            for item in it:
                if not self._put((True, item)):
                    return
            self._put((False, _END))
        except BaseException as e:  # handed to the consumer, raised there
            self._put((False, e))
        finally:
            close = getattr(it, "close", None)  # a generator source: its `finally` runs here, now
            if close is not None:
                try:
                    close()
                except Exception:
                    pass
            self.cpu_s = time.thread_time()

    def _put(self, entry) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(entry, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def __iter__(self) -> Iterator[Any]:
        try:
            while True:
                ok, item = self._queue.get()
                if ok:
                    yield item
                elif item is _END:
                    return
                else:
                    raise item
        finally:
            self.close()

    def __enter__(self) -> ReadAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the reader (it finishes the item it is reading) and wait for it."""
        self._stop.set()
        while self._thread.is_alive():
            try:  # make room for a put in progress
                self._queue.get_nowait()
            except queue.Empty:
                pass
            self._thread.join(_POLL_S)


class WriteBehind:
    """Call `write(item)` on a thread for every `put(item)`, in order, at most `depth` items waiting.
    `close()` waits until everything put is written. An error in `write` is raised (once) by the next `put`
    or by `close`; the items put after it are dropped (a sink that failed writes nothing more)."""

    def __init__(self, write: Callable[[Any], None], depth: int = 2, name: str = "evstream-writer"):
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        self._write = write
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._raised = False
        self._closed = False
        self.cpu_s = 0.0  # the writer thread's CPU time, once it ended
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = take(self._queue)
            if item is _END:
                self.cpu_s = time.thread_time()
                return
            if self._error is not None:
                continue  # failed: drop the rest, keep the putter from blocking
            try:
                self._write(item)
            except BaseException as e:
                self._error = e

    def put(self, item: Any) -> None:
        if self._closed:
            raise RuntimeError("WriteBehind: put after close")
        self._raise()
        if self._error is not None:
            return  # failed and said so: dropped
        while True:
            try:
                self._queue.put(item, timeout=_POLL_S)
                return
            except queue.Full:
                self._raise()  # a failed writer still drains, but say so now

    def _raise(self) -> None:
        if self._error is not None and not self._raised:
            self._raised = True  # once: a caller cleaning up after it (closing sinks) is not stopped again
            raise self._error

    def close(self, *, check: bool = True) -> None:
        """Wait until everything put is written; raise the writer's error (unless `check` is false: the
        caller is already handling another one)."""
        if not self._closed:
            self._closed = True
            while True:
                try:
                    self._queue.put(_END, timeout=_POLL_S)
                    break
                except queue.Full:
                    if not self._thread.is_alive():  # pragma: no cover - the writer never leaves early
                        break
            self._thread.join()
        if check:
            self._raise()

    @property
    def error(self) -> BaseException | None:
        """The writer's error, if it had one."""
        return self._error
