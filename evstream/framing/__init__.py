"""Framers (events -> frames) and frame rendering; importing this package registers the framers.

`fw` fixed time window, `fn` fixed event count, `oa` overlapping accumulation, `adaptive` the paper's
adaptive overlap. All stream: `push(chunk) -> frames`, `finish() -> frames`, chunk-invariant, and
close time-based frames on the watermark (see `base`).
"""

from .base import COUNT_DTYPE, FramerBase
from .fixed import FixedCount, FixedWindow
from .overlap import AdaptiveOverlap, OverlapAccumulation

__all__ = ["COUNT_DTYPE", "AdaptiveOverlap", "FixedCount", "FixedWindow", "FramerBase",
           "OverlapAccumulation"]
