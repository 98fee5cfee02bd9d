"""Where replay's and subscribe's Rerun recording goes: a name that says .rrd, and how to open it."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from .common import UsageError


def check_rrd_name(save, flag: str = "--save ") -> None:
    """A Rerun recording goes to a name ending in .rrd (or into a device, /dev/null): `--save x.mcap` wrote
    one under a name that says MCAP, or over a recording `x.npz`."""
    from evstream.safe_write import is_special

    if save and Path(save).suffix.lower() != ".rrd" and not is_special(Path(save)):
        raise UsageError(f"{flag}{save}: a Rerun recording's name ends in .rrd (an MCAP archive: evstream archive "
                         "REC OUT.mcap; another recording format: evstream convert)")


def rerun_command() -> str:
    """How to start the Rerun viewer from this shell: `rerun` when it is on PATH, else the one installed
    beside this Python (after `make demo`, `.venv/bin/rerun`: the venv is not activated)."""
    if shutil.which("rerun"):
        return "rerun"
    beside = Path(sys.executable).parent / "rerun"
    if not beside.exists():
        return "rerun"
    try:
        return os.path.relpath(beside) if not os.path.relpath(beside).startswith("..") else str(beside)
    except ValueError:  # another drive (Windows)
        return str(beside)
