import numpy as np
import pytest

from evstream.denoise.oracle import KeepSignal, TruthStage
from evstream.events import EventChunk, Geometry, NoiseClass
from evstream.pipeline import Pipeline, RunStats, build, kinds, paced
from evstream.testing import assert_chunk_invariant, random_bounds, random_stream, split

G = Geometry(24, 18)


class ListSink:
    def __init__(self):
        self.batches, self.closed = [], None

    def write(self, batch):
        self.batches.append(batch)

    def close(self, stats):
        self.closed = stats


def test_pipeline_runs_stages_in_order_and_counts_classes():
    s = random_stream(3, 500)
    sink = ListSink()
    stats = Pipeline([TruthStage()]).run(split(s, random_bounds(3, len(s))), [sink])
    assert stats.events_in == 500
    assert stats.per_class.tolist() == np.bincount(s.label, minlength=3).tolist()
    assert sink.closed is stats
    assert sum(len(b.events) for b in sink.batches) == 500


def test_keep_signal_is_the_only_dropping_stage():
    s = random_stream(4, 300)
    out = Pipeline([TruthStage(), KeepSignal()]).process(s).events
    assert len(out) == int((s.label == NoiseClass.SIGNAL).sum())
    assert (out.cls == 0).all()


def test_truth_stage_is_chunk_invariant():
    assert_chunk_invariant(TruthStage, random_stream(5, 200), 5)


def test_sinks_closed_when_source_fails():
    def broken():
        yield random_stream(0, 10)
        raise OSError("disk gone")

    sink = ListSink()
    with pytest.raises(OSError):
        Pipeline([]).run(broken(), [sink])
    assert isinstance(sink.closed, RunStats) and sink.closed.events_in == 10


def test_toml_description(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text('[[stage]]\nkind = "truth"\n\n[[stage]]\nkind = "keep_signal"\n')
    p = Pipeline.from_toml(f)
    assert [type(s).__name__ for s in p.stages] == ["TruthStage", "KeepSignal"]
    assert p.describe()["stages"] == [{"kind": "truth"}, {"kind": "keep_signal"}]
    f.write_text('[[stage]]\nkind = "nope"\n')
    with pytest.raises(ValueError, match="unknown stage kind 'nope'"):
        Pipeline.from_toml(f)
    f.write_text("[[stage]\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        Pipeline.from_toml(f)


def test_registry_lists_kinds_and_rejects_bad_params():
    assert {"truth", "keep_signal"} <= set(kinds("stage"))
    with pytest.raises(ValueError, match="truth"):
        build("stage", {"kind": "truth", "bogus": 1})


def test_paced_follows_event_time():
    now = [0.0]
    sleeps = []

    def sleep(dt):
        sleeps.append(dt)
        now[0] += dt

    chunks = [EventChunk.from_arrays([t], [0], [0], [1], G) for t in (1_000_000, 1_500_000, 3_000_000)]
    out = list(paced(chunks, speed=2.0, clock=lambda: now[0], sleep=sleep))
    assert len(out) == 3
    assert sleeps == pytest.approx([0.25, 0.75])
    assert list(paced(chunks, 0)) == chunks
    with pytest.raises(ValueError):
        list(paced(chunks, -1))


def test_the_declared_denoise_kinds_are_what_their_modules_register():
    """evstream.denoise names each stage kind's module without importing it (start-up); importing every
    module of the package registers exactly the declared kinds, each from its declared module."""
    import importlib
    import pkgutil

    import evstream.denoise as denoise
    from evstream.pipeline import _DECLARED, _REGISTRY

    for info in pkgutil.walk_packages(denoise.__path__, denoise.__name__ + "."):
        importlib.import_module(info.name)
    registered = {kind: f.__module__ for kind, f in _REGISTRY["stage"].items()
                  if f.__module__.startswith(denoise.__name__ + ".")}
    declared = {kind: module for kind, module in _DECLARED["stage"].items()}
    assert set(registered) == set(declared)
    for kind, module in registered.items():
        assert module == declared[kind] or module.startswith(declared[kind] + "."), (kind, module)
