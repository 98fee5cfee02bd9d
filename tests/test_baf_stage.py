"""The BAF stage's call, whose short way (an unclassified chunk of the geometry object its state was
made for) skips `Classifier.__call__`: the same classes as the brute-force reference whichever way each
chunk takes."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_baselines import ref_baf

from evstream.denoise.baf import BackgroundActivityFilter
from evstream.events import Geometry, NoiseClass
from evstream.testing import SMALL, random_stream, split


@settings(max_examples=max(1, settings().max_examples // 2))  # an O(n²) reference
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 200), tau_us=st.integers(1, 3000),
       ways=st.lists(st.sampled_from(["short", "equal geometry", "classified", "classify"]), min_size=1,
                     max_size=12), grid=st.booleans(), data=st.data())
def test_every_way_of_calling_gives_the_reference_classes(seed, n, tau_us, ways, grid, data):
    """Chunks taking the short way, an equal but other Geometry object (the full check), a `cls` already
    set (all SIGNAL: the base's path) or `classify`, in any order: the reference's classes. On a 100 µs
    grid, ages equal to tau are common (the strict `<`)."""
    s = random_stream(seed, n)
    if grid:
        s, tau_us = s.replace(t=s.t // 100 * 100), max(1, tau_us // 100) * 100
    cuts = sorted(data.draw(st.lists(st.integers(0, n), max_size=len(ways) - 1)))
    chunks = split(s, [0, *cuts, n])
    stage = BackgroundActivityFilter(tau_us=tau_us)
    got = []
    for k, c in enumerate(chunks):
        way = ways[k % len(ways)]
        if way == "equal geometry":
            c = c.replace(geometry=Geometry(SMALL.width, SMALL.height))
            assert c.geometry is not s.geometry and c.geometry == s.geometry
        if way == "classified":
            c = c.with_classes(np.zeros(len(c), np.uint8))
        got.append(stage.classify(c) if way == "classify" else stage(c).cls)
    np.testing.assert_array_equal(np.concatenate(got), ref_baf(s, tau_us)[0])


def test_a_stream_on_the_short_way_gives_the_reference_classes():
    """Every chunk after the first on the short way, timestamps on a 100 µs grid (ages equal to tau)."""
    for seed in range(3):
        s = random_stream(seed, 400)
        s = s.replace(t=s.t // 100 * 100)
        stage = BackgroundActivityFilter(tau_us=300)
        got = np.concatenate([stage(c).cls for c in split(s, list(range(0, 400, 37)) + [400])])
        np.testing.assert_array_equal(got, ref_baf(s, 300)[0])


def test_a_classified_chunk_and_another_sensor_take_the_base_path():
    """Events already classed noise keep their class and are not judged; a chunk of another sensor size
    is refused, as by every stage."""
    s = random_stream(4, 300)
    stage, again = BackgroundActivityFilter(tau_us=400), BackgroundActivityFilter(tau_us=400)
    stage(s[:100]), again(s[:100])
    marked = s[100:].with_classes(np.where(np.arange(200) % 3 == 0, NoiseClass.HOT_PIXEL, 0).astype(np.uint8))
    out = stage(marked).cls
    assert (out[::3] == NoiseClass.HOT_PIXEL).all()
    live = np.flatnonzero(marked.cls == 0)
    np.testing.assert_array_equal(out[live], again.classify(s[100:][live]))
    with pytest.raises(ValueError, match="geometry"):
        stage(random_stream(0, 10, Geometry(30, 20)))
