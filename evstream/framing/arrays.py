"""Representations to files: one `.npz` per window, ready for a training loop (`np.load(f)["data"]`).

Each file `DIR/frame_000000.npz`, ... holds `data` (float32, C×H×W), `t_start_us`, `t_end_us`,
`n_events` (int64 scalars), `kind` and `channels` (strings; no pickle: `np.load` needs no
allow_pickle). A file is written under a temporary name beside it and renamed when whole, so a
stopped run leaves whole files only.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def save_representation(path: str | os.PathLike, rep) -> None:
    """One representation as an .npz at `path`, written whole (temporary name, then rename: `safe_write`); a
    full disk is one OSError naming it (was Python's "[Errno 28] No space left on device", no file named)."""
    from ..safe_write import AtomicOutput

    with AtomicOutput(path, sync=False) as part, open(part, "wb") as f:
        np.savez(f, data=rep.data, t_start_us=np.int64(rep.t_start), t_end_us=np.int64(rep.t_end),
                 n_events=np.int64(rep.n_events), kind=np.array(rep.kind), channels=np.array(list(rep.channels)))


class ArrayWriter:
    """A sink writing every representation of a run as `frame_000000.npz`, ... in `out_dir` (created)."""

    def __init__(self, out_dir: str | os.PathLike):
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.written = 0

    def write(self, batch) -> None:
        for rep in batch.frames:
            if getattr(rep, "data", None) is None:
                raise ValueError(f"{self.out_dir}: .npz output takes a representation framer "
                                 "(timesurface, voxel, histogram, count, timestamp)")
            save_representation(self.out_dir / f"frame_{self.written:06d}.npz", rep)
            self.written += 1

    def close(self, stats) -> None:
        pass
