"""Transforms: stages that change the sensor geometry or drop events, and say which (`drops_events`,
`changes_geometry`, `out_geometry`). Importing this package registers them as stages.

`crop`, `flip`, `rotate`, `transpose`, `downsample` (geometry), `polarity`, `time_range`, `rate_limit`
(selection), `undistort` (the camera's calibration).
"""

from .base import Transform
from .geometry import Crop, Downsample, Flip, Rotate, Transpose
from .select import Polarity, RateLimit, TimeRange, TimeRangeSource
from .undistort import Undistort

__all__ = ["Crop", "Downsample", "Flip", "Polarity", "RateLimit", "Rotate", "TimeRange", "TimeRangeSource", "Transform",
           "Transpose", "Undistort"]
