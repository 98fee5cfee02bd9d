"""Core data-path costs: chunk slicing and concatenation, the native reader, a memory copy for scale."""

import tempfile
from pathlib import Path

from evstream.sources import native

from evstream.events import Geometry, concat
from evstream.testing import random_stream

from .common import events_per_s, report


def run() -> None:
    g = Geometry(346, 260)
    n = 2_000_000
    s = random_stream(0, n, g)
    report("memory copy (t, x, y, p)", events_per_s(lambda: [a.copy() for a in (s.t, s.x, s.y, s.p)], n))
    report("slice into 10k-event chunks + concat",
           events_per_s(lambda: concat([s[i : i + 10_000] for i in range(0, n, 10_000)]), n))
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "s.npz"
        native.save(path, s, compress=False)
        report("native reader (.npz, 50k chunks)",
               events_per_s(lambda: sum(len(c) for c in native.open(path)), n, repeat=3))
