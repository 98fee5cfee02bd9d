"""The check both seek test files share: a read from `start_us` (seeking where the format allows) gives
exactly the events of a read from the start with the earlier ones dropped."""

import numpy as np
from evstream.sources import open_source

from evstream.events import EventChunk, concat
from evstream.transforms import TimeRangeSource


def read_range(path, start_us, end_us=None, **options):
    """(events of the seeking read, events of a read from the start with the earlier ones dropped, seeks?)"""
    source = TimeRangeSource(open_source(path, **options), start_us, end_us)
    got = list(source)
    everything = concat(list(open_source(path, **options)), source.geometry)
    keep = everything.t >= start_us
    if end_us is not None:
        keep &= everything.t < end_us
    return concat(got, source.geometry), everything[keep], source.seeks


def assert_same(got: EventChunk, want: EventChunk):
    """Same events, field by field (classes and labels included)."""
    assert len(got) == len(want)
    if not len(want):
        return  # no chunk read at all has no class or label column to compare
    for f in ("t", "x", "y", "p", "cls", "label"):
        a, b = getattr(got, f), getattr(want, f)
        assert (a is None) == (b is None), f
        if a is not None:
            np.testing.assert_array_equal(a, b, err_msg=f)
