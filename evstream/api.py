"""The Python API: what the command line does, from a script, a notebook or a training loop.

In the order data flows — source, stages, framer, sinks:

    chunks = evstream.open("rec.raw", geometry="1280x720")       # a stream of EventChunks
    pipe = evstream.build_pipeline("paper", framer="fw")         # stages by name, with parameters
    with evstream.open_sink("out/clean.mcap", geometry=chunks.geometry) as sink:
        for batch in evstream.batches(pipe, chunks):             # classified events and frames
            sink.write(batch)

Stages classify, they do not drop: `classify` returns each event's noise class, `clean` the events
kept (SIGNAL), on a chunk, a stream of chunks or a numpy structured array with fields t, x, y, p (tonic's
and faery's dtypes; faery's `on` is read as `p`). `Denoise` is the same as a tonic-style transform,
`Represent` the framers' learning representations (time surface, voxel grid, ...) as one.
The command line (`evstream.cli`) is a thin shell over these functions.
"""

from __future__ import annotations

import dataclasses
import numbers
import weakref
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from .events import EventChunk, EventError, Geometry, NoiseClass, Validator, concat
from .pipeline import Batch, Pipeline, build, factory, kinds

MAX_REPRESENT_BYTES = 1 << 30  # Represent's array at most this (1 GiB) unless told otherwise
_UNITS = {"_us": "µs", "_ms": "ms", "_s": "s", "_hz": "Hz", "_px": "pixels", "_events": "events"}


# -- sources -------------------------------------------------------------------------------------
def open(path, *, geometry=None, timestamps: str | None = None,  # noqa: A001 - evstream.open, as io.open
         start_us: int | None = None, end_us: int | None = None, chunk_events: int | None = None):
    """A recording (any supported file or an MCAP log) as a stream of chunks: iterate it for
    `EventChunk`s; `.geometry` is the sensor size. `geometry` ("WxH", (W, H) or a Geometry) overrides the
    file's; `timestamps` is what to do with time going back: "error", "sort" or "drop" (default: the
    format's); `start_us` <= t < `end_us` keeps a time range (either may be None: open on that side);
    `chunk_events`: events per chunk (default the reader's, 50,000)."""
    from evstream.sources import open_source

    from .safe_write import reading

    options: dict[str, Any] = {}
    if geometry is not None:
        options["geometry"] = as_geometry(geometry)
    if timestamps is not None:
        options["timestamps"] = timestamps
    if chunk_events is not None:  # int() made 2.5 two events a chunk and True one, without a word
        if isinstance(chunk_events, bool) or not isinstance(chunk_events, numbers.Integral) or chunk_events < 1:
            raise ValueError(f"chunk_events={chunk_events!r}: a whole number of events, at least 1")
        options["chunk_events"] = int(chunk_events)
    source = open_source(path, **options)
    reading(source, path)  # `open_sink` will not write over it while it is alive
    if start_us is None and end_us is None:
        return source
    from .transforms import TimeRangeSource

    return TimeRangeSource(source, start_us, end_us)


def read(path, **options) -> EventChunk:
    """A whole recording as one chunk (the options of `open`)."""
    source = open(path, **options)
    return concat(list(source), source.geometry)


def info(path, **options) -> dict[str, Any]:
    """What `evstream info` prints: format, geometry, events, time span, rate, ON fraction, label counts
    (None when the file has none) and the reader's own details (`source`), after one pass over the file."""
    source = open(path, **options)
    n = on = 0
    t_first = t_last = None
    labels = np.zeros(3, np.int64)
    has_labels = True
    for chunk in source:
        if not len(chunk):
            continue
        n += len(chunk)
        on += int(chunk.p.sum())
        t_first = int(chunk.t[0]) if t_first is None else t_first
        t_last = int(chunk.t[-1])
        if chunk.label is None:
            has_labels = False
        else:
            labels += chunk.class_counts("label")
    duration = (t_last - t_first) if n else 0
    return {
        "path": str(path),
        "format": getattr(source, "format", type(source).__name__),
        "width": source.geometry.width,
        "height": source.geometry.height,
        "events": n,
        "t_first_us": t_first,
        "t_last_us": t_last,
        "duration_us": duration,
        "rate_hz": n / (duration * 1e-6) if duration > 0 else 0.0,
        "on_fraction": on / n if n else 0.0,
        "labels": {c.name.lower(): int(labels[c]) for c in NoiseClass} if has_labels and n else None,
        "source": source.info() if hasattr(source, "info") else {},  # reader details, after the read
    }


def as_geometry(geometry) -> Geometry:
    """A sensor size from "WxH", (W, H), tonic's (W, H, 2) or a Geometry."""
    from evstream.sources._base import as_geometry as parse

    if isinstance(geometry, (tuple, list)) and len(geometry) == 3:
        geometry = tuple(geometry[:2])
    return parse(geometry)


def subscribe(keyexpr: str, *, connect=(), listen=(), geometry=None, **options):
    """A live Zenoh stream (what `evstream publish` sends) as an iterable of `LivePacket`s (`.camera`,
    `.chunk`, `.restart`) and `End` marks; a context manager that closes its session. `connect`/`listen`:
    Zenoh endpoints (default: a client of the router at tcp/127.0.0.1:7447). Other options are
    `ZenohSubscription`'s (`flow`, `depth`, `idle_s`, `should_stop`)."""
    from evstream.sources.zenoh_sub import ZenohSubscription

    connect = [connect] if isinstance(connect, str) else list(connect)
    listen = [listen] if isinstance(listen, str) else list(listen)
    geometry = as_geometry(geometry) if geometry is not None else None
    return ZenohSubscription(keyexpr, connect=connect, listen=listen, geometry=geometry, **options)


# -- stages, framers, pipelines -------------------------------------------------------------------
def stage(kind: str, **params):
    """A registered stage by name: `stage("stcf", tau_us=10_000)`, `stage("paper", coarse={"window_us": 10_000})`."""
    return build("stage", {"kind": kind, **params})


def framer(kind: str, **params):
    """A registered framer by name: `framer("fw", window_us=5_000)`."""
    return build("framer", {"kind": kind, **params})


def build_pipeline(*stages, framer=None) -> Pipeline:
    """Stages in order (each a name, a `{"kind": ..., **params}` dict or a built stage; "none" adds
    nothing), then an optional framer (a name, a dict or a built framer). One argument ending in .toml
    reads a pipeline file."""
    if len(stages) == 1 and isinstance(stages[0], str) and stages[0].endswith(".toml"):
        pipe = Pipeline.from_toml(stages[0])
    else:
        pipe = Pipeline([_build("stage", s) for s in stages if s != "none"])
    if framer is not None:
        pipe.framer = _build("framer", framer)
    return pipe


def _build(role: str, spec):
    if isinstance(spec, str):
        return build(role, {"kind": spec})
    if isinstance(spec, dict):
        return build(role, spec)
    return spec  # already built


def catalogue(role: str | None = None) -> list[dict[str, Any]]:
    """Every registered stage and framer (or those of `role`): kind, one-line summary, and parameters
    with their default and unit; a stage made of stages (the paper's) lists theirs as `coarse.window_us`."""
    return [entry(r, kind) for r in ([role] if role else ["stage", "framer"]) for kind in kinds(r)]


def entry(role: str, kind: str) -> dict[str, Any]:
    """One stage's or framer's catalogue entry: kind, summary (its docstring's first paragraph), parameters."""
    cls = factory(role, kind)
    try:  # a built default shows the stages a composite holds (the paper's coarse, fine)
        obj = build(role, {"kind": kind})
    except (ValueError, OSError):  # one that needs a parameter (a camera model): its class says what it takes
        obj = cls
    doc = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
    return {"role": role, "kind": kind, "summary": doc, "parameters": _parameters(obj)}


def _parameters(obj, prefix: str = "") -> list[dict[str, Any]]:
    params = []
    parts = getattr(obj, "parts", {}) if not isinstance(obj, type) else {}  # a stage made of stages
    for f in dataclasses.fields(obj) if dataclasses.is_dataclass(obj) else ():
        if not f.init or f.name.startswith("_"):
            continue
        if f.name in parts:
            params += _parameters(parts[f.name], f"{prefix}{f.name}.")
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else "required")
        unit = "" if isinstance(default, bool) else next(
            (u for suffix, u in _UNITS.items() if f.name.endswith(suffix)), "")
        kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        params.append({"name": prefix + f.name, "default": default, "unit": unit, "type": kind})
    return params


def set_params(spec: dict[str, Any], settings: Iterable[str], role: str = "stage") -> dict[str, Any]:
    """`spec` ({"kind": NAME, ...}) with `PARAM=VALUE` settings applied: "coarse.window_us=10000" (a dotted
    name reaches into a sub-stage's parameters). A value is read as TOML reads it (10000, 0.2, true,
    "text"); a bare word is a string. Raises ValueError naming the setting (no "=", or a parameter the
    stage does not have, with the ones it has)."""
    from .pipeline import tomllib

    known = [p["name"] for p in entry(role, spec["kind"])["parameters"]] if spec.get("kind") in kinds(role) else []
    spec = {k: (dict(v) if isinstance(v, dict) else v) for k, v in spec.items()}
    for setting in settings:
        name, eq, text = setting.partition("=")
        name = name.strip()
        if not eq or not name or any(not part for part in name.split(".")):
            raise ValueError(f"{setting}: expected PARAM=VALUE, e.g. coarse.window_us=10000")
        if name not in known:
            raise ValueError(f"{setting}: {role} {spec.get('kind')!r} has no parameter {name!r}; "
                             f"its parameters: {', '.join(known) or 'none'}")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = text.strip()
        *outer, last = name.split(".")
        place = spec
        for part in outer:
            place = place.setdefault(part, {})
        place[last] = value
    return spec


# -- running stages on events ---------------------------------------------------------------------
def batches(pipe: Pipeline, chunks: Iterable[EventChunk]) -> Iterator[Batch]:
    """Drive `chunks` through `pipe`, one `Batch` (classified events, new frames, stats) per chunk, or per
    piece of one whose frames would take more than `pipe.frames_bytes` at once (`Pipeline.feed`), then one
    with the frames the end of the stream closes. `Pipeline.run` does the same into sinks. Each call is
    one stream: a pipeline that ran before starts it afresh, as built (`Pipeline.restart`), so the same
    pipeline given the next recording, or a notebook cell run again, gives what a new pipeline gives."""
    if pipe.used:
        pipe.restart()
    geometry = getattr(chunks, "geometry", None)
    for chunk in chunks:
        geometry = chunk.geometry
        yield from pipe.feed(chunk)
    if geometry is not None:
        yield pipe.finish(geometry)


def classify(what, events, *, geometry=None):
    """Noise classes (uint8: 0 signal, 1 background activity, 2 hot pixel) of `events`, by `what` (a
    stage or framer-less pipeline, built or by name). A chunk or a structured array gives one array of
    classes per event; a stream of chunks gives a stream of classified chunks. A built stage keeps its
    state from call to call (one recording in pieces); a name makes a fresh one. A stage that drops
    events (crop, keep_signal, ...) has no class for every event given: a chunk or an array is then a
    ValueError (`clean` gives the events it keeps; a stream, the classified chunks)."""
    run, stages = _runner(what, "classify")
    if isinstance(events, (EventChunk, np.ndarray)):
        chunk = events if isinstance(events, EventChunk) else from_structured(events, geometry)
        dropper = next((s for s in stages if getattr(s, "drops_events", False)), None)
        out = run(chunk) if dropper is None else None
        if out is None or len(out) != len(chunk):  # declared, or found (a stage of the user's own)
            raise ValueError(f"classify: {_kind(dropper or stages[-1])} drops events: there is no class for every "
                             "event given; clean() gives the events kept (classify of a stream, the classified chunks)")
        return out.classes()
    return (run(chunk) for chunk in _stream(events, "classify"))


def clean(what, events, *, geometry=None):
    """The events `what` classes SIGNAL, in the form they came: a chunk, a structured array (same dtype,
    fields untouched), or a stream of chunks (a stream of the kept chunks). A transform in `what` (crop,
    flip, downsample, ...) or `keep_signal`: an array holds the events it keeps where it puts them, in the
    array's dtype (fields t, x, y, p or on only: others cannot follow the events)."""
    run, stages = _runner(what, "clean")
    if isinstance(events, EventChunk):
        return run(events).of_class(NoiseClass.SIGNAL)
    if isinstance(events, np.ndarray):
        out = run(from_structured(events, geometry))
        moves = next((s for s in stages if getattr(s, "drops_events", False) or hasattr(s, "out_geometry")), None)
        if moves is None and len(out) == len(events):  # a transform has out_geometry: it may move events
            return events[out.classes() == NoiseClass.SIGNAL]
        _check_fields_follow(events, moves or stages[-1])
        return _as_array(out.of_class(NoiseClass.SIGNAL), events)
    return (run(chunk).of_class(NoiseClass.SIGNAL) for chunk in _stream(events, "clean"))


def _kind(stage) -> str:
    return getattr(stage, "kind", None) or type(stage).__name__


def _check_fields_follow(events: np.ndarray, stage) -> None:
    others = [n for n in events.dtype.names if n not in ("t", "x", "y", "p", "on")]
    if others:
        raise ValueError(f"clean: {_kind(stage)} drops or moves events, so the array's field(s) {', '.join(others)} "
                         "cannot follow them; pass the fields t, x, y, p only (arr[['t', 'x', 'y', 'p']])")


def _as_array(chunk: EventChunk, like: np.ndarray) -> np.ndarray:
    """`chunk` in the dtype of the structured array `like`: its polarity as that array gave it (bool,
    0/1 or -1/+1); a coordinate that does not fit the field's type is a ValueError, not a wrapped value."""
    out = np.empty(len(chunk), like.dtype)
    for name in like.dtype.names:
        v = chunk.p if name in ("p", "on") else getattr(chunk, name)
        if name in ("p", "on") and len(like) and like[name].min() < 0:
            v = np.where(v > 0, 1, -1)
        elif name in "xy" and len(v) and not np.can_cast(np.min_scalar_type(int(v.max())), like.dtype[name]):
            raise ValueError(f"clean: {name} = {int(v.max())} after the transform does not fit the array's "
                             f"{like.dtype[name]} field")
        out[name] = v
    return out


def _stream(events, what: str):
    """`events` as a stream of chunks: a TypeError saying what was given when it is none (at once when it
    cannot be iterated, else at the item), not `object of type 'int' has no len()` from inside a stage; an
    EventError when a chunk starts before the previous one ended (a stage would take it silently)."""
    form = "give an EventChunk, a structured array or a stream (iterable) of EventChunks"
    try:
        items = iter(events)
    except TypeError:
        raise TypeError(f"{what}: events is a {type(events).__name__}; {form}") from None

    def checked():
        last_t, last_i = None, None
        for i, chunk in enumerate(items):
            if not isinstance(chunk, EventChunk):
                raise TypeError(f"{what}: item {i} of the stream is a {type(chunk).__name__}, not an EventChunk; "
                                f"{form}")
            if len(chunk):  # each chunk was checked alone; a stage's state also needs them in time order
                if last_t is not None and chunk.t[0] < last_t:
                    raise EventError(f"{what}: item {i} of the stream starts at t={int(chunk.t[0])} µs, before the "
                                     f"last event of item {last_i} (t={last_t} µs): time goes back")
                last_t, last_i = int(chunk.t[-1]), i
            yield chunk

    return checked()


def _runner(what, caller: str):
    """A function of one chunk, and the stages it runs (what a chunk may lose or where its events go). A
    built stage or pipeline keeps its state from call to call, so its chunks must come in time order."""
    if isinstance(what, (str, dict, list, tuple)):  # a fresh one for this call
        what = build_pipeline(*what) if isinstance(what, (list, tuple)) else build_pipeline(what)
        return (lambda chunk: what.process(chunk).events), what.stages
    run = (lambda chunk: what.process(chunk).events) if isinstance(what, Pipeline) else what
    return _in_time_order(run, what, caller), what.stages if isinstance(what, Pipeline) else [what]


# id of a built stage -> the time of the last event it was given (removed when it is collected); a pipeline
# knows its own (`Pipeline.last_t_us`: a stream that `batches` or `run` ended, the next starts afresh)
_LAST_T: dict[int, int] = {}


def _in_time_order(run, owner, caller: str):
    """`run` refusing a chunk that starts before the last event `owner` was given, by an earlier call too: a
    notebook cell run again over the same recording with the same stage classed its start with the state
    the end had left (163,082 events of ball.npz kept instead of 190,691)."""
    key = id(owner)

    def checked(chunk: EventChunk):
        last = owner.last_t_us if isinstance(owner, Pipeline) else _LAST_T.get(key)
        if len(chunk) and last is not None and chunk.t[0] < last:
            raise EventError(f"{caller}: the events start at t={int(chunk.t[0])} µs, before the last event this stage "
                             f"was given (t={last} µs): time goes back; for another pass build a fresh stage "
                             "(evstream.stage) or pass its name")
        out = run(chunk)
        if len(chunk) and not isinstance(owner, Pipeline):
            if key not in _LAST_T:
                try:
                    weakref.finalize(owner, _LAST_T.pop, key, None)
                except TypeError:  # cannot be watched (no weak reference): not checked
                    return out
            _LAST_T[key] = int(chunk.t[-1])
        return out

    return checked


def from_structured(events: np.ndarray, geometry=None) -> EventChunk:
    """A numpy structured array (fields t, x, y, p — or faery's `on` — any order and integer types; t in
    µs) as a validated chunk. `geometry` ("WxH", (W, H), tonic's sensor_size (W, H, 2)) is required:
    a filter's thresholds depend on the sensor's size, which the array does not carry."""
    names = events.dtype.names or ()
    p_name = "p" if "p" in names else "on" if "on" in names else None
    missing = [f for f in "txy" if f not in names] + ([] if p_name else ["p"])
    if missing:
        raise EventError(f"structured array lacks field(s) {', '.join(missing)}; it has {', '.join(names) or 'none'}")
    if not np.issubdtype(events.dtype["t"], np.integer):
        raise EventError(f"field t is {events.dtype['t']}: evstream wants integer microseconds "
                         "(e.g. (t * 1e6).astype(np.int64) for seconds)")
    if geometry is None:
        raise EventError("a structured array does not say its sensor size: pass geometry=(width, height)")
    g = as_geometry(geometry)
    for name in "xy":
        if len(events) and events[name].min() < 0:
            raise EventError(f"<array>: event {int(np.argmax(events[name] < 0))}: {name} is negative")
    p = events[p_name]
    chunk = EventChunk.from_arrays(events["t"], events["x"], events["y"], p > 0, g)
    return Validator(g, where="<array>")(chunk)


class Denoise:
    """A tonic-style transform: called on a structured array of one recording (t, x, y, p), returns the
    events the stage keeps, same dtype. Each call starts a fresh stage (samples are independent), so it
    drops into `tonic.transforms.Compose([...])` or a torch `Dataset.__getitem__` as it is.

        transform = Denoise(sensor_size=(346, 260, 2), kind="paper", coarse={"window_us": 10_000})
    """

    def __init__(self, sensor_size, kind: str = "paper", **params):
        self.geometry = as_geometry(sensor_size)
        self.spec = {"kind": kind, **params}
        build("stage", self.spec)  # a bad name or parameter fails here, not in a DataLoader worker

    def __call__(self, events: np.ndarray) -> np.ndarray:
        return clean(build("stage", self.spec), events, geometry=self.geometry)

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.spec.items() if k != "kind")
        return f"Denoise(sensor_size=({self.geometry.width}, {self.geometry.height}), kind={self.spec['kind']!r}" + (
            f", {params})" if params else ")")


class Represent:
    """A tonic-style transform to a learning representation: called on one sample's structured array (t, x,
    y, p; or an EventChunk, or a stream of chunks), returns every window's representation that the framer
    `kind` (timesurface, voxel, histogram, count, timestamp; docs/framing.md) gives for it, as one float32
    array (windows, C, H, W) — `torch.from_numpy` shares it. Each call starts a fresh framer, so samples
    stay independent. The array is at most `max_bytes` (default 1 GiB; None: no cap): a sample that would
    make more is a ValueError saying so before memory runs out; `windows(events)` gives the same
    representations one window at a time, in memory bounded by the sensor and one window, however long
    the recording (`evstream.open(path)` streams it from the file).

        to_voxels = Represent(sensor_size=(346, 260, 2), kind="voxel", bins=5, window_us=50_000)
    """

    def __init__(self, sensor_size, kind: str = "voxel", *, max_bytes: int | None = MAX_REPRESENT_BYTES, **params):
        from .framing.represent import RepresentationFramer

        self.geometry = as_geometry(sensor_size)
        self.spec = {"kind": kind, **params}
        framer = build("framer", self.spec)  # a bad name or parameter fails here, not in a DataLoader worker
        if not isinstance(framer, RepresentationFramer):
            ours = [k for k in kinds("framer") if issubclass(factory("framer", k), RepresentationFramer)]
            raise ValueError(f"Represent: {kind!r} makes frames to look at, not arrays; the representations: "
                             f"{', '.join(ours)} (window={kind!r} chooses the window)")
        if max_bytes is not None and (isinstance(max_bytes, bool) or not isinstance(max_bytes, numbers.Integral)
                                      or max_bytes < 1):
            raise ValueError(f"Represent: max_bytes={max_bytes!r}: a whole number of bytes, at least 1, or None")
        self.max_bytes = max_bytes
        self.shape = (len(framer.channels), self.geometry.height, self.geometry.width)

    def __call__(self, events) -> np.ndarray:
        window_bytes = 4 * int(np.prod(self.shape))
        data = []
        for rep in self.windows(events):
            if self.max_bytes is not None and (len(data) + 1) * window_bytes > self.max_bytes:
                raise ValueError(
                    f"Represent: {self.spec['kind']} of this sample is more than {len(data):,} windows of "
                    f"{'x'.join(map(str, self.shape))} float32 ({window_bytes * (len(data) + 1) / 2**30:.2f} GiB "
                    f"with the next, over max_bytes={self.max_bytes:,}): take them one at a time with "
                    "Represent.windows(events), or pass max_bytes=None (or a larger cap)")
            data.append(rep.data)
        out = np.empty((len(data), *self.shape), np.float32)
        for i in range(len(data)):  # copied in and let go one by one: memory of one array, not two
            out[i], data[i] = data[i], None
        return out

    def windows(self, events) -> Iterator:
        """The representations one window at a time, as `Representation`s (`.data` float32 (C, H, W),
        `.t_start`, `.t_end`, `.n_events`), from a structured array, a chunk or a stream of chunks (read
        as it goes: memory bounded by the sensor and one window, not the recording)."""
        framer = build("framer", self.spec)
        if isinstance(events, (EventChunk, np.ndarray)):
            chunks = [events if isinstance(events, EventChunk) else from_structured(events, self.geometry)]
        else:
            chunks = _stream(events, "Represent")
        for chunk in chunks:
            if chunk.geometry != self.geometry:
                raise ValueError(f"Represent: the events are on a {chunk.geometry} sensor, the transform's "
                                 f"sensor_size is {self.geometry}")
            yield from framer.push(chunk)
        yield from framer.finish()

    def __repr__(self) -> str:
        params = "".join(f", {k}={v!r}" for k, v in self.spec.items() if k != "kind")
        if self.max_bytes != MAX_REPRESENT_BYTES:
            params += f", max_bytes={self.max_bytes!r}"
        return (f"Represent(sensor_size=({self.geometry.width}, {self.geometry.height}), "
                f"kind={self.spec['kind']!r}{params})")
