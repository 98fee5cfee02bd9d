"""Framer option sets the streaming tests share: every framer kind and window, small enough that a short
random stream closes many frames (the bounded-batch tests of framing.bound and of the pipeline)."""

FRAMERS = [
    {"kind": "fw", "window_us": 20},
    {"kind": "fn", "n_events": 2},
    {"kind": "fn", "n_events": 3, "max_window_us": 40},
    {"kind": "oa", "window_us": 40, "stride_us": 10},
    {"kind": "adaptive", "window_us": 40, "n_base": 2},
    {"kind": "timesurface", "window_us": 30},
    {"kind": "voxel", "window": "oa", "window_us": 40, "stride_us": 20},
    {"kind": "histogram", "window": "fn", "n_events": 4},
]
