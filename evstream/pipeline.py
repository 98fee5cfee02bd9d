"""Stages, framers, sources and sinks, and the `Pipeline` that connects them.

A source yields `EventChunk`s; each stage maps a chunk to a chunk (denoise stages write `cls`, they
never drop); an optional framer turns events into `Frame`s; every sink receives one `Batch` per
source chunk, or per piece of one: a chunk from which the framer would close more frames than
`Pipeline.frames_bytes` hold is handed to it in pieces (`framing.bound`), one batch each. Stages and
framers hold their own state and must be chunk-invariant, causal and bounded in memory (see
`evstream.testing`).
"""

from __future__ import annotations

import copy
import dataclasses
import errno
import importlib
import inspect
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .events import N_CLASSES, EventChunk, Frame, Geometry, NoiseClass

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib


@runtime_checkable
class Stage(Protocol):
    """Maps a chunk to a chunk: denoise stages keep every event and write `cls`; transforms
    (`evstream.transforms`) may drop events or change the geometry, and say so."""

    def __call__(self, chunk: EventChunk) -> EventChunk: ...


@runtime_checkable
class Framer(Protocol):
    """Turns a stream of chunks into frames; `finish` closes the frame still open."""

    def push(self, chunk: EventChunk) -> list[Frame]: ...

    def finish(self) -> list[Frame]: ...


@runtime_checkable
class Source(Protocol):
    """An iterable of validated chunks from one sensor, with its geometry and a description."""

    geometry: Geometry

    def __iter__(self) -> Iterator[EventChunk]: ...


@runtime_checkable
class Sink(Protocol):
    """Receives every batch; `close` is called once, with the final statistics. A sink writing a file may
    also have `fail(stats, error)`, called instead of `close` when the run fails (the file it replaces is
    then kept as it was); it may raise a clearer error in place of `error`."""

    def write(self, batch: Batch) -> None: ...

    def close(self, stats: RunStats) -> None: ...


@dataclass
class RunStats:
    """Counts of a run so far: events in, events per assigned class, frames, time covered.
    `events_in` counts the events leaving the stages; `events_dropped` those transforms dropped; `chunks`
    the chunks given (a chunk in pieces counts once)."""

    events_in: int = 0
    events_dropped: int = 0
    per_class: np.ndarray = field(default_factory=lambda: np.zeros(N_CLASSES, np.int64))
    frames: int = 0
    chunks: int = 0
    t_first_us: int | None = None
    t_last_us: int | None = None
    wall_s: float = 0.0

    def add(self, chunk: EventChunk, n_frames: int) -> None:
        """The events leaving the stages (a chunk or a piece of one) and the frames they closed."""
        self.frames += n_frames
        if not len(chunk):
            return
        self.events_in += len(chunk)
        counts = chunk.class_counts()
        if counts is None:  # unclassified: all SIGNAL
            self.per_class[NoiseClass.SIGNAL] += len(chunk)
        else:
            self.per_class += counts
        if self.t_first_us is None:
            self.t_first_us = int(chunk.t[0])
        self.t_last_us = int(chunk.t[-1])

    @property
    def duration_us(self) -> int:
        return 0 if self.t_first_us is None else self.t_last_us - self.t_first_us

    @property
    def rate_hz(self) -> float:
        """Event rate in event time (events per second of recording)."""
        return self.events_in / (self.duration_us * 1e-6) if self.duration_us > 0 else 0.0

    @property
    def throughput_hz(self) -> float:
        """Processing speed: events per wall-clock second."""
        return self.events_in / self.wall_s if self.wall_s > 0 else 0.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "events_in": self.events_in,
            "events_signal": int(self.per_class[NoiseClass.SIGNAL]),
            "events_background": int(self.per_class[NoiseClass.BACKGROUND]),
            "events_hot_pixel": int(self.per_class[NoiseClass.HOT_PIXEL]),
            "events_dropped": self.events_dropped,
            "frames": self.frames,
            "chunks": self.chunks,
            "duration_us": self.duration_us,
            "rate_hz": self.rate_hz,
            "wall_s": self.wall_s,
            "throughput_hz": self.throughput_hz,
        }


_UNCOPIED = ("uncopied",)  # Pipeline._built when the stages could not be copied


@dataclass
class Batch:
    """What sinks receive for each source chunk, or each piece of one (`Pipeline.feed`): its classified
    events, the frames they closed, stats so far."""

    events: EventChunk
    frames: list[Frame]
    stats: RunStats


class Pipeline:
    """Stages in order, then an optional framer. `feed` one chunk (its batches), `finish` at end of stream.

    The stages take each chunk whole; the framer takes it in pieces when it would close more frames from it
    than `frames_bytes` hold (a small window over a long chunk: `window_us=1` over a 0.5 s chunk was 500,000
    frames at once), one batch per piece, so a batch's frames stay within about `frames_bytes` (fn windows
    with a time limit: twice). Framers are chunk-invariant: the same frames as from the whole chunk.

    A pipeline runs one stream at a time, and a new stream starts from the pipeline as it was built: the
    first chunk after `finish`, and every `run` (and `evstream.batches`) of a pipeline that ran before,
    start with its stages, framer and stats as they were before its first chunk (`restart`). Carrying a
    stream's state into the next recording (or into a notebook cell run again) classed the start of the
    second by the end of the first."""

    frames_bytes: int | None = None  # the frames one batch holds, at most (about); None: 64 MB (framing.bound)

    def __init__(self, stages: Iterable[Stage] = (), framer: Framer | None = None):
        self.stages = list(stages)
        self.framer = framer
        self.stats = RunStats()
        self._cutter = None  # the stream's chunks in pieces for the framer (framing.bound): made at its first chunk
        self.cpu_s: dict[str, float] = {}  # CPU seconds per thread of the last threaded `run`
        self._built: tuple | None = None  # (stages, framer) as before the first chunk, copied then
        self._ended = False  # `finish` was called: the next chunk starts a new stream
        self._t_given: int | None = None  # the last event time the stream in progress was given

    @property
    def last_t_us(self) -> int | None:
        """The time of the last event given to the stream in progress (None: none yet, or it ended with
        `finish`, so the next chunk starts a new stream): a chunk that starts before it goes back in time."""
        return None if self._ended else self._t_given

    @property
    def used(self) -> bool:
        """Whether a stream has run through the pipeline since it was built or restarted."""
        return self._built is not None and (self._ended or self.stats.chunks > 0)

    def restart(self) -> None:
        """Stages, framer and stats as they were before the first chunk: what a newly built pipeline of the
        same stages gives. A stage that could not be copied then (one of the user's own, holding a file or
        a lock, say) makes this a ValueError saying to build a new pipeline."""
        if self._built is None:
            return
        if self._built is _UNCOPIED:
            raise ValueError("this pipeline has already run a stream, and its stages could not be copied to start "
                             "the next one afresh; build a new pipeline for each stream")
        self.stages, self.framer = copy.deepcopy(self._built)
        self.stats = RunStats()
        self._cutter = None
        self._ended = False
        self._t_given = None

    def _start(self) -> None:
        if self._ended:
            self.restart()
        if self._built is None:
            try:
                self._built = copy.deepcopy((self.stages, self.framer))
            except Exception:  # noqa: BLE001 - a stage of the user's own that cannot be copied: one stream only
                self._built = _UNCOPIED

    def feed(self, chunk: EventChunk) -> Iterator[Batch]:
        """The batches of one chunk: its events through the stages (now), then to the framer (as the batches are
        taken; take them all before the next chunk), in pieces if it would close more than `frames_bytes` of
        frames from them, one batch each; one batch when it closes fewer, as at every default window."""
        return self._framed(self._stages(chunk))

    def process(self, chunk: EventChunk) -> Batch:
        """One chunk as one batch: its events through the stages, and every frame they close at once (a small
        window over a long chunk is many frames, all in memory together: `feed` gives them a few at a time)."""
        events = self._stages(chunk)
        batches = list(self._framed(events))
        if len(batches) == 1:
            return batches[0]
        return Batch(events, [f for batch in batches for f in batch.frames], self.stats)

    def _stages(self, chunk: EventChunk) -> EventChunk:
        if self._built is None or self._ended:
            self._start()
        if self._cutter is None and self.framer is not None:
            from .framing.bound import Cutter  # the framers' package (it imports this module), loaded by now

            self._cutter = Cutter(self.framer, self.frames_bytes)  # None: its default
        n = len(chunk)
        if n:
            self._t_given = int(chunk.t[-1])
        for stage in self.stages:
            chunk = stage(chunk)
        self.stats.events_dropped += n - len(chunk)
        self.stats.chunks += 1
        return chunk

    def _framed(self, events: EventChunk) -> Iterator[Batch]:
        if self.framer is None:
            self.stats.add(events, 0)
            yield Batch(events, [], self.stats)
            return
        for piece in self._cutter.pieces(events):
            frames = self.framer.push(piece)
            self.stats.add(piece, len(frames))
            yield Batch(piece, frames, self.stats)

    def finish(self, geometry: Geometry) -> Batch:
        """The frames the end of the stream closes; the next chunk starts a new stream (`restart`)."""
        frames = self.framer.finish() if self.framer is not None and not self._ended else []
        self.stats.frames += len(frames)
        self._ended = self._built is not None or self._ended
        return Batch(EventChunk.empty(geometry, with_cls=True), frames, self.stats)

    def run(
        self,
        source: Iterable[EventChunk],
        sinks: Iterable[Sink] = (),
        on_batch: Callable[[Batch], None] | None = None,
        *,
        threads: bool = False,
        stop: Callable[[], bool] | None = None,
    ) -> RunStats:
        """Drive `source` through the pipeline into `sinks` (`feed`: one batch per chunk, or per piece of one);
        sinks are closed even on error (`fail`ed, if they can tell a failed run from a whole one). `on_batch`
        is called after the sinks wrote a batch. `threads`: read the source ahead on one thread and write the
        sinks behind on another, while this one runs the stages (`evstream.threads`: same batches, same
        order, same output; both cores). `stop`: asked after each chunk; true ends the run there, as if the
        source had ended."""
        from .threads import ReadAhead, WriteBehind

        if self.used:  # one run is one stream, from the pipeline as built
            self.restart()
        sinks = list(sinks)
        t0, cpu0 = time.perf_counter(), time.thread_time()
        geometry = None  # of the events leaving the stages: a transform may crop, rotate, downsample

        def deliver(item: tuple[Batch, bool]) -> None:
            batch, last = item
            for sink in sinks:
                sink.write(batch)
            if on_batch is not None and not last:  # the end's frames go to the sinks only
                on_batch(batch)

        chunks = ReadAhead(source) if threads else None
        writer = WriteBehind(deliver) if threads else None
        put = writer.put if writer is not None else deliver
        try:
            for chunk in chunks if chunks is not None else source:
                for batch in self.feed(chunk):
                    geometry = batch.events.geometry
                    self.stats.wall_s = time.perf_counter() - t0
                    put((batch, False))
                if stop is not None and stop():
                    break
            if chunks is not None:
                chunks.close()
            if geometry is None and getattr(source, "geometry", None) is not None:
                geometry = self.out_geometry(source.geometry)  # no chunk came
            if geometry is not None:
                batch = self.finish(geometry)
                if batch.frames:
                    put((batch, True))
            if writer is not None:
                writer.close()
        except BaseException as e:
            if chunks is not None:
                chunks.close()
            if writer is not None:
                writer.close(check=False)  # what it was given is written: the outputs whole up to here
            self.stats.wall_s = time.perf_counter() - t0
            for sink in sinks:
                fail = getattr(sink, "fail", None)
                if fail is None:
                    sink.close(self.stats)
                else:
                    fail(self.stats, e)
            raise
        self.stats.wall_s = time.perf_counter() - t0
        if threads:
            self.cpu_s = {"reader": chunks.cpu_s, "stages": time.thread_time() - cpu0, "writer": writer.cpu_s}
        for sink in sinks:
            sink.close(self.stats)
        return self.stats

    def out_geometry(self, geometry: Geometry) -> Geometry:
        """The geometry of the events leaving the stages (transforms may crop, rotate, downsample)."""
        for stage in self.stages:
            out = getattr(stage, "out_geometry", None)
            geometry = out(geometry) if out is not None else geometry
        return geometry

    def reports(self) -> list[str]:
        """One line from each stage that reports something at the end (what a rate limiter dropped)."""
        return [stage.report() for stage in self.stages if callable(getattr(stage, "report", None))]

    def describe(self) -> dict[str, Any]:
        """Parameters of every stage and the framer, for provenance (MCAP metadata, logs)."""
        return {
            "stages": [describe(s) for s in self.stages],
            "framer": describe(self.framer) if self.framer is not None else None,
        }

    # -- construction from a description ---------------------------------------------------------
    @classmethod
    def from_config(cls, config: dict[str, Any]) -> Pipeline:
        """From `{"stage": [{"kind": ..., **params}, ...], "framer": {"kind": ..., **params}}`."""
        unknown = sorted(set(config) - {"stage", "framer"})
        if unknown:  # a typo such as [[stages]] would otherwise run no stage at all
            raise ValueError(f"unknown table {unknown[0]!r}; a pipeline has [[stage]] (one per stage) and [framer]")
        specs = config.get("stage", [])
        if not isinstance(specs, list) or not all(isinstance(spec, dict) for spec in specs):
            raise ValueError("stages are an array of tables: [[stage]] (double brackets), one per stage")
        framer_spec = config.get("framer")
        if framer_spec is not None and not isinstance(framer_spec, dict):
            raise ValueError("the framer is a table: [framer] with kind = ...")
        stages = [build("stage", dict(spec)) for spec in specs]
        framer = build("framer", dict(framer_spec)) if framer_spec else None
        return cls(stages, framer)

    @classmethod
    def from_toml(cls, path) -> Pipeline:
        """From a TOML file: `[[stage]] kind = "density" window_us = 20000` ... `[framer] kind = "fw"`. A file
        that cannot be read is an OSError of its kind saying so in one line, naming `path`; one that is not
        UTF-8 or not TOML, a ValueError naming it and where."""
        try:
            f = open(path, "rb")
        except OSError as e:  # was Python's "[Errno 2] No such file or directory: 'p.toml'"
            why = {errno.ENOENT: "no such pipeline file", errno.EISDIR: "is a folder, not a pipeline file"}
            raise type(e)(f"{path}: {why.get(e.errno, e.strerror or e)}") from None
        with f:
            try:
                config = tomllib.load(f)
            except tomllib.TOMLDecodeError as e:
                raise ValueError(f"{path}: not valid TOML: {e}") from None
            except UnicodeDecodeError as e:  # was Python's "'utf-8' codec can't decode byte 0xe9 in position 5"
                raise ValueError(f"{path}: not UTF-8 text: byte {e.start} (0x{e.object[e.start]:02x}); a pipeline "
                                 "file is TOML, which is UTF-8") from None
        try:
            return cls.from_config(config)
        except (TypeError, ValueError, KeyError) as e:
            raise ValueError(f"{path}: {e}") from None


# -- registry of stage and framer kinds ---------------------------------------------------------
_REGISTRY: dict[str, dict[str, Callable[..., Any]]] = {"stage": {}, "framer": {}}
# kind -> the module that registers it when imported: listed at once, imported when first built or looked at
_DECLARED: dict[str, dict[str, str]] = {"stage": {}, "framer": {}}


def register(role: str, kind: str):
    """Class decorator: make a stage or framer constructible by name (`--denoise`, TOML `kind`)."""

    def deco(factory):
        _REGISTRY[role][kind] = factory
        factory.kind = kind
        return factory

    return deco


def declare(role: str, module: str, *kinds: str) -> None:
    """Name the kinds `module` registers when imported, without importing it: a command building one
    denoise stage does not import every filter (start-up)."""
    for kind in kinds:
        _DECLARED[role][kind] = module


def _load_plugins() -> None:
    # Importing the packages registers (or declares) their stages and framers.
    from . import denoise, framing, transforms  # noqa: F401


def _known(role: str) -> list[str]:
    return sorted(set(_REGISTRY[role]) | set(_DECLARED[role]))


def kinds(role: str) -> list[str]:
    _load_plugins()
    return _known(role)


def factory(role: str, kind: str):
    """The class (or function) registered as `kind`, unbuilt: for listings of its parameters."""
    _load_plugins()
    return _factory(role, kind)


def _factory(role: str, kind: str):
    if kind not in _REGISTRY[role] and kind in _DECLARED[role]:
        importlib.import_module(_DECLARED[role][kind])  # registers it
    return _REGISTRY[role][kind]


def build(role: str, spec: dict[str, Any]):
    """Instantiate a registered stage or framer from `{"kind": name, **params}`."""
    _load_plugins()
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind is None:
        raise ValueError(f"a {role} needs kind = one of {', '.join(_known(role))}")
    if kind not in _known(role):
        raise ValueError(f"unknown {role} kind {kind!r}; known: {', '.join(_known(role))}")
    factory = _factory(role, kind)
    accepted = _parameters(factory)
    unknown = sorted(set(spec) - set(accepted)) if accepted is not None else []
    if unknown:  # name what it takes, not Python's "__init__() got an unexpected keyword argument"
        raise ValueError(f"{role} {kind!r}: unknown parameter {unknown[0]!r}; "
                         f"its parameters: {', '.join(accepted) or 'none'}")
    try:
        return factory(**spec)
    except TypeError as e:
        raise ValueError(f"{role} {kind!r}: {e}") from None


def _parameters(factory) -> list[str] | None:
    """The keyword parameters a stage or framer takes (None when it takes any)."""
    if dataclasses.is_dataclass(factory):
        return [f.name for f in dataclasses.fields(factory) if f.init and not f.name.startswith("_")]
    try:
        sig = inspect.signature(factory)
    except (TypeError, ValueError):
        return None
    if any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values()):
        return None
    return [n for n, p in sig.parameters.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def describe(obj) -> dict[str, Any]:
    """`{"kind": ..., **dataclass fields}` for a registered stage or framer."""
    out = {"kind": getattr(obj, "kind", type(obj).__name__)}
    params = getattr(obj, "params", None)
    if params is not None:
        out.update(params() if callable(params) else params)
    return out


# -- pacing -------------------------------------------------------------------------------------
def paced(
    chunks: Iterable[EventChunk],
    speed: float,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[EventChunk]:
    """Yield chunks no earlier than their event time allows: `speed` 1 = real time, 2 = twice as fast,
    0 = as fast as possible. A chunk is released when the stream reaches its last event's time."""
    if speed < 0:
        raise ValueError(f"speed must be >= 0, got {speed}")
    if speed == 0:
        yield from chunks
        return
    t0_event = None
    t0_wall = 0.0
    for chunk in chunks:
        if len(chunk):
            if t0_event is None:
                t0_event, t0_wall = int(chunk.t[0]), clock()
            due = t0_wall + (int(chunk.t[-1]) - t0_event) * 1e-6 / speed
            delay = due - clock()
            if delay > 0:
                sleep(delay)
        yield chunk
