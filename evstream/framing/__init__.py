"""Framers (events -> frames) and frame rendering; importing this package registers the framers.

`fw` fixed time window, `fn` fixed event count, `oa` overlapping accumulation, `adaptive` the paper's
adaptive overlap; the representations for learning (`represent`: timesurface, voxel, histogram,
count, timestamp) run over any of those windows. All stream: `push(chunk) -> frames`,
`finish() -> frames`, chunk-invariant, and close time-based frames on the watermark (see `base`).
"""

from .base import COUNT_DTYPE, FramerBase
from .fixed import FixedCount, FixedWindow
from .overlap import AdaptiveOverlap, OverlapAccumulation
from .represent import CountImage, Histogram, Representation, TimestampImage, TimeSurface, VoxelGrid

__all__ = ["COUNT_DTYPE", "AdaptiveOverlap", "CountImage", "FixedCount", "FixedWindow", "FramerBase",
           "Histogram", "OverlapAccumulation", "Representation", "TimeSurface", "TimestampImage", "VoxelGrid"]
