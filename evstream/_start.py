"""What runs first when the package loads (imported before anything heavy): Ctrl-C while it loads.

- A local cluster's worker (EVSTREAM_BATCH_WORKER=1 in a spawned process, evstream.batch): SIGINT
  ignored. A terminal's Ctrl-C goes to the whole process group, workers too; a worker killed by it
  mid-task never cleaned up (its temporaries stayed, the command waited for it). The command stops the
  tasks itself. This module is what the worker imports first: the console script's main, re-imported by
  the spawn, imports the package (else the worker's preload does). The worker started with SIGINT
  blocked (evstream.batch.start_client), so a Ctrl-C during its start waited: ignored, then unblocked,
  it is dropped.
- The `evstream` command: a Ctrl-C while its imports load (up to a second) ends it with one line and
  130, not a traceback through numpy's import; `evstream.cli.main` puts Python's handler back.
"""

import os
import signal
import sys
import threading


def _quit(signum, frame):
    sys.stderr.write("evstream: interrupted\n")
    os._exit(128 + signum)  # nothing to clean up yet: nothing was opened


def _a_spawned_worker() -> bool:
    """EVSTREAM_BATCH_WORKER=1 and a process multiprocessing spawned (re-importing its parent's main, or
    started). The variable alone is not enough: distributed sets its workers' variables in the parent's
    environment too (nanny.py: "even if this means poisoning the process running the Nanny"), so a
    command started from there later would inherit it."""
    if os.environ.get("EVSTREAM_BATCH_WORKER") != "1" or "multiprocessing" not in sys.modules:
        return False
    mp = sys.modules["multiprocessing"]
    return bool(getattr(mp.current_process(), "_inheriting", False)) or mp.parent_process() is not None


def guard():
    """On import (evstream/__init__ imports this module first): returns the handler to put back or None."""
    if threading.current_thread() is not threading.main_thread():
        return None
    if _a_spawned_worker():
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C pending since the worker started is dropped
        if hasattr(signal, "pthread_sigmask"):
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        return None
    if os.path.basename(sys.argv[0] if sys.argv else "") == "evstream" and \
            signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        return signal.signal(signal.SIGINT, _quit)
    return None


def release() -> None:
    """The command loaded (evstream.cli.main): Python's handler back (KeyboardInterrupt)."""
    if _previous is not None and signal.getsignal(signal.SIGINT) is _quit:
        signal.signal(signal.SIGINT, _previous)


_previous = guard()
