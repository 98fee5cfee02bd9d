"""A Ctrl-C where a user can press it: what the threads that write behind the main one do after it.

A KeyboardInterrupt is raised in the main thread between two bytecodes, wherever it happens to be. In
`queue.Queue.put` it can land inside `threading.Condition.notify`, after the waiting thread was woken and
before it was struck off the condition's list: the next `put` then wakes that stale entry and nobody
(`evstream convert REC OUT.raw` + Ctrl-C hung for good, three threads asleep). `interrupted_wakeup` puts
the interrupt at exactly that line, with a trace function, so the test does not depend on luck.
"""

from __future__ import annotations

import inspect
import sys
import threading
import time

import numpy as np

import evstream
from evstream.events import EventChunk, Geometry
from evstream.threads import WriteBehind

G = Geometry(64, 48)
WAIT_S = 30  # a thread that is not done by then never will be


def interrupted_wakeup(call) -> None:
    """`call()` with a KeyboardInterrupt raised in this thread just after a Condition.notify released a
    waiter and before it removed it from the waiters' list: where a real Ctrl-C can land."""
    code = threading.Condition.notify.__code__
    lines, first = inspect.getsourcelines(threading.Condition.notify)
    line = first + next(i for i, text in enumerate(lines) if "waiters.remove(waiter)" in text)
    fired = []

    def in_notify(frame, event, arg):
        if event == "line" and frame.f_lineno == line and not fired:
            fired.append(True)
            raise KeyboardInterrupt
        return in_notify

    sys.settrace(lambda frame, event, arg: in_notify if frame.f_code is code else None)
    try:
        call()
    except KeyboardInterrupt:
        pass
    finally:
        sys.settrace(None)
    assert fired, "the put woke nobody: the interrupt was not placed"


def wait_for(condition, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.001)


def ends(call) -> bool:
    """Whether `call()` returns (on a thread of its own, waited for WAIT_S)."""
    t = threading.Thread(target=call, daemon=True)
    t.start()
    t.join(WAIT_S)
    return not t.is_alive()


def chunk(seed: int) -> EventChunk:
    rng = np.random.default_rng(seed)
    n = 1000
    return EventChunk(np.sort(rng.integers(0, 100_000, n)) + seed * 100_000, rng.integers(0, G.width, n),
                      rng.integers(0, G.height, n), rng.integers(0, 2, n), G)


def test_write_behind_closes_after_a_ctrl_c_inside_a_put():
    written = []
    writer = WriteBehind(written.append)
    waiting = writer._queue.not_empty._waiters  # the writer thread, asleep in its get
    wait_for(lambda: len(waiting) == 1, "the writer thread never waited for an item")
    interrupted_wakeup(lambda: writer.put("first"))
    wait_for(lambda: len(waiting) == 2, "the writer thread did not come back for the next item")  # + the stale one
    assert ends(writer.close), "WriteBehind.close hung after a Ctrl-C inside a put"
    assert written == ["first"]


def test_a_raw_output_abandoned_after_a_ctrl_c_inside_a_write_ends_and_keeps_the_target(tmp_path):
    out = tmp_path / "out.raw"
    out.write_bytes(b"an earlier recording")
    sink = evstream.open_sink(out, geometry=G)
    sink.write(chunk(0))  # starts the RAW encoder's thread, which then waits for the next chunk
    waiting = sink.sink._queue.not_empty._waiters
    wait_for(lambda: len(waiting) == 1, "the encoder never waited for a chunk")
    interrupted_wakeup(lambda: sink.write(chunk(1)))
    wait_for(lambda: len(waiting) == 2, "the encoder did not come back for the next chunk")
    assert ends(lambda: sink.fail(None, KeyboardInterrupt())), "abandoning the RAW output hung after a Ctrl-C"
    assert out.read_bytes() == b"an earlier recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.raw"]  # no OUT.part left
