"""Writing events from a loop: `open_sink(OUT)` picks the sink by the name (.mcap, .rrd, a Rerun viewer's
URL, .npz native, .raw EVT3/EVT2, .h5 HDF5) and takes batches or chunks until closed.

    with evstream.open_sink("out/clean.mcap", geometry=source.geometry) as sink:
        for batch in evstream.batches(pipe, source):
            sink.write(batch)

Every output goes through `safe_write.AtomicOutput`: written beside the target (`OUT.part`) and renamed
once whole, never onto an input; a failed run leaves what was there before. Native files take whole
arrays, so they hold the events until closed; RAW is encoded as it comes (a writer thread), HDF5
datasets grow chunk by chunk, MCAP and Rerun stream.
"""

from __future__ import annotations

import contextlib
import os
import queue
import threading
import weakref
from pathlib import Path
from typing import Any

from .events import EventChunk, NoiseClass, concat
from .pipeline import Batch, Pipeline, RunStats, build, paced
from .safe_write import AtomicOutput, being_read, is_no_space, no_space_error
from .threads import ReadAhead, enabled, take

FILE_FORMATS = {".npz": "native", ".raw": "evt", ".h5": "hdf5", ".hdf5": "hdf5"}


def open_sink(out, *, geometry=None, keep_noise: bool = False, framer: str | None = None, source=None, inputs=(),
              **options) -> SinkWriter:
    """A sink for `out`, to `write(batch_or_chunk)` into and `close()` (or use `with`).

    `keep_noise`: also write the events not classed SIGNAL (MCAP: one topic per class; files: every
    event, with its class where the format has a place for it). `framer`: the framer's kind, for the
    Rerun view. `source`: the recording being read (its sensor size is the default `geometry`). `out` is
    never a file being read: not `source`'s, not one in `inputs` (paths or opened recordings), not any
    recording `evstream.open` has open in this process (by file identity: links too; `OutputIsInput`).
    Other options go to the sink: MCAP `camera=`, `frames=`, `points=`, `metadata=`...; Rerun
    `point_budget_hz=`, `slab_ms=`; RAW `evt=3|2`; native `meta=`. A sink never closed is not put in
    place: when it is garbage-collected (or the script ends) its temporary is removed, with a warning.
    """
    from .api import as_geometry

    if geometry is None and source is not None:
        geometry = source.geometry
    geometry = as_geometry(geometry) if geometry is not None else None
    read = [_input_path(i) for i in (*((source,) if source is not None else ()), *inputs)]
    read = [p for p in read if p is not None] + being_read()
    name = os.fspath(out)
    if name.startswith(("rerun+http://", "rerun+https://")) or name.endswith(".rrd"):
        return _rerun(name, geometry, framer, options, read)
    suffix = Path(name).suffix.lower()
    if suffix == ".mcap":
        from evstream.sinks.mcap_sink import McapSink

        Path(name).parent.mkdir(parents=True, exist_ok=True)
        options.setdefault("frames", False)
        output = AtomicOutput(name, read)
        try:
            sink = McapSink(str(output.part), keep_noise=keep_noise, geometry=geometry, **options)
        except BaseException:
            output.discard()
            raise
        return SinkWriter(sink, output=output)
    if suffix in FILE_FORMATS:
        return SinkWriter(FileSink(name, geometry=geometry, keep_noise=keep_noise, inputs=read, **options))
    raise ValueError(f"{name}: no sink for that name; outputs are .mcap, .rrd (or rerun+http://HOST:PORT/proxy),"
                     " .npz (native), .raw (EVT3/EVT2), .h5 (HDF5)")


def _input_path(given) -> str | None:
    """A path, or an opened recording's file (a time-range view's underlying source's)."""
    if isinstance(given, (str, os.PathLike)):
        return os.fspath(given)
    while given is not None and getattr(given, "path", None) is None and hasattr(given, "source"):
        given = given.source
    path = getattr(given, "path", None)
    return os.fspath(path) if isinstance(path, (str, os.PathLike)) else None


def _rerun(name: str, geometry, framer, options, inputs=()) -> SinkWriter:
    from evstream.sinks.rerun_sink import FILE_SENDS, RerunSink
    from evstream.sinks.rerun_viewer import open_output

    if geometry is None:
        raise ValueError(f"{name}: the Rerun view needs the sensor size: pass geometry=")
    output = None if "://" in name else AtomicOutput(name, inputs)
    try:
        out = open_output(save=str(output.part) if output else None, connect=None if output else name)
    except BaseException:
        if output is not None:
            output.discard()
        raise
    try:
        sends = FILE_SENDS if output is not None else {}  # a file: Rerun's writer kept busy (rerun_sink)
        sink = RerunSink(out.rec, geometry=geometry, framer=framer, **{**sends, **options})
    except BaseException:
        out.stop()
        if output is not None:
            output.discard()
        raise
    return SinkWriter(sink, after_close=lambda: (out.finish(), out.stop()), output=output,
                      abandon=lambda: (out.rec.disconnect(), out.stop()))


class SinkWriter:
    """A sink fed from a loop: `write` takes a pipeline's `Batch` or a bare `EventChunk` (its events count
    as classified, or all SIGNAL when unclassified); `close` gives the sink the run's statistics. It is a
    pipeline Sink too: `pipe.run(source, [writer])` closes it, or on an error `fail`s it (target untouched)."""

    def __init__(self, sink, after_close=None, output: AtomicOutput | None = None, abandon=None):
        self.sink = sink
        self.stats = RunStats()
        self._after_close = after_close
        self._output = output  # committed once closed: a failed run leaves the old OUT
        self._closed = False
        # never closed (no `with`, no close()): when this writer is collected or the process ends, its
        # temporary is removed and a warning says so; the target stays as it was
        self._unclosed = weakref.finalize(self, _never_closed, sink, output, abandon, _target_of(sink, output))

    def write(self, item: Batch | EventChunk) -> None:
        if isinstance(item, EventChunk):
            self.stats.add(item, 0)
            item = Batch(item, [], self.stats)
        else:
            self.stats = item.stats
        self.sink.write(item)

    def close(self, stats: RunStats | None = None) -> None:
        if stats is not None:  # from Pipeline.run, which counted the run itself
            self.stats = stats
        if self._closed:
            return
        self._closed = True
        self._unclosed.detach()
        try:
            self.sink.close(self.stats)
        finally:
            if self._after_close is not None:
                self._after_close()
        if self._output is not None:
            self._output.commit()

    def __enter__(self) -> SinkWriter:
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if exc is None:
            self.close()
        else:
            self.fail(None, exc)

    def fail(self, stats: RunStats | None, error: BaseException) -> None:
        """After a failed run (the loop's error, or Pipeline.run's): the target stays as it was."""
        if stats is not None:
            self.stats = stats
        self._unclosed.detach()
        if isinstance(self.sink, FileSink):  # a failed run leaves what was there before
            self.sink.abandon()
        output, self._output = self._output, None
        try:
            self.close()
        except Exception:  # the loop's own error is the one to see
            pass
        finally:
            if output is not None:
                output.discard()


def _target_of(sink, output: AtomicOutput | None) -> str:
    if output is not None:
        return str(output.target)
    return str(getattr(sink, "path", None) or "the sink's output")


def _never_closed(sink, output: AtomicOutput | None, abandon, target: str) -> None:
    """A SinkWriter collected (or left at exit) without `close()`: nothing says its output is whole, so it is
    not put in place; its temporary is removed and the user told why."""
    import warnings

    from .sources._base import EventWarning

    try:
        if isinstance(sink, FileSink):
            sink.abandon()
        elif hasattr(sink, "abandon"):
            sink.abandon()
        if abandon is not None:
            abandon()
    finally:
        if output is not None:
            output.discard(keep=False)
    warnings.warn(f"{target}: open_sink(...) was never closed (call close() or use `with`), so it was not "
                  "written; its temporary file is removed", EventWarning, stacklevel=1)


class FileSink:
    """Events into a native (.npz), RAW (.raw, EVT3 or EVT2) or HDF5 (.h5) file: SIGNAL only unless
    `keep_noise`. Written to OUT.part, renamed to OUT when closed."""

    def __init__(self, path, *, geometry=None, keep_noise: bool = False, evt: int | str = 3, meta: dict | None = None,
                 inputs=()):
        self.path = Path(path)
        self.format = FILE_FORMATS[self.path.suffix.lower()]
        if self.format == "evt":
            if str(evt) not in ("3", "2"):
                raise ValueError(f"evt {evt}: choose 3 or 2")
            self.format = f"evt{evt}"
        self.geometry = geometry
        self.keep_noise = keep_noise
        self.meta = meta
        self.events = 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.output = AtomicOutput(self.path, inputs=inputs)
        self.part = self.output.part
        self._chunks: list[EventChunk] = []
        self._hdf5 = None  # the HDF5 writer, from the first write
        self._queue: queue.Queue | None = None
        self._thread = None
        self._error: list[BaseException] = []

    def write(self, batch: Batch) -> None:
        chunk = batch.events if self.keep_noise else batch.events.of_class(NoiseClass.SIGNAL)
        self.geometry = self.geometry or chunk.geometry
        self.events += len(chunk)
        if self.format == "hdf5":
            if self._hdf5 is None:
                from evstream.sources import hdf5

                self._hdf5 = hdf5.Writer(self.part, self.geometry)
            self._hdf5.append(chunk)
            return
        if not self.format.startswith("evt"):
            self._chunks.append(chunk)
            return
        if self._queue is None:  # the RAW encoder pulls from an iterable: it runs beside the loop
            self._start_raw()
        if self._error:
            raise self._error[0]
        self._queue.put(chunk)

    def _start_raw(self) -> None:
        from evstream.sources import prophesee_raw

        self._queue = queue.Queue(maxsize=8)

        def chunks():
            while (chunk := take(self._queue)) is not None:  # take: a Ctrl-C in a put cannot strand it
                yield chunk

        def encode():
            try:
                prophesee_raw.save(self.part, chunks(), self.geometry, version=self.format)
            except BaseException as e:  # handed to the writing thread at its next write or close
                self._error.append(e)
                while take(self._queue) is not None:  # let the writer finish its puts
                    pass

        self._thread = threading.Thread(target=encode, name="evstream-raw-writer", daemon=True)
        self._thread.start()

    def close(self, stats: RunStats | None = None) -> None:
        if self.format == "abandoned":
            return
        try:
            if self.format.startswith("evt"):
                if self._queue is None:
                    self._start_raw()
                self._queue.put(None)
                self._thread.join()
                if self._error:
                    raise self._error[0]
            elif self.format == "hdf5":
                from evstream.sources import hdf5

                writer, self._hdf5 = self._hdf5, None
                if writer is None:  # nothing written: an empty file
                    if self.geometry is None:
                        raise ValueError(f"{self.path}: no events and no geometry given")
                    writer = hdf5.Writer(self.part, self.geometry)
                writer.close()
            else:
                from evstream.sources import native

                if self.geometry is None:
                    raise ValueError(f"{self.path}: no events and no geometry given")
                events = concat(self._chunks, self.geometry)
                self._chunks = []
                native.save(self.part, events, self.meta)
            self.output.commit()
        finally:
            self.output.discard()  # nothing once committed

    def abandon(self) -> None:
        """Drop what was written (an error in the loop): OUT stays as it was."""
        if self._queue is not None and self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        if self._hdf5 is not None:
            self._hdf5.abort()
            self._hdf5 = None
        self.output.discard()
        self.format, self._chunks = "abandoned", []

    def describe(self) -> dict[str, Any]:
        return {"out": str(self.path), "format": self.format, "events": self.events}


def not_a_file_format(out: Path) -> str:
    """What `convert` says of an output name it has no format for, with the command that writes it if any."""
    elsewhere = {".mcap": "an MCAP archive: evstream archive REC OUT.mcap",
                 ".rrd": "a Rerun recording: evstream replay REC --save OUT.rrd"}.get(out.suffix.lower())
    return (f"{out}: output format from the extension: .npz (native), .raw (EVT3/EVT2), .h5"
            + (f"; {elsewhere}" if elsewhere else ""))


def convert(path, out, *, evt: int | str = 3, on_progress=None, **options) -> dict[str, Any]:
    """Every event of a recording into another format (.npz native, .raw EVT3/EVT2, .h5 HDF5); returns
    what `evstream convert` prints. The output is never the input (checked by file identity).
    `on_progress(events, fraction)` after each chunk: events so far, the share of the file read (None
    where the reader does not know it). `options` go to `evstream.open` (geometry, timestamps, start_us...)."""
    from .api import open as open_recording

    out = Path(out)
    if out.suffix.lower() not in FILE_FORMATS:
        raise ValueError(not_a_file_format(out))
    source = open_recording(path, **options)
    meta = {"converted_from": str(path), "source_format": getattr(source, "format", "?")}
    sink = FileSink(out, geometry=source.geometry, keep_noise=True, evt=evt, meta=meta, inputs=[path, *being_read()])
    writer = SinkWriter(sink)
    try:
        with writer, ReadAhead(source) if enabled(default=False) else contextlib.nullcontext(source) as chunks:
            for chunk in chunks:  # serial unless EVSTREAM_THREADS=1: a reader thread measured slower here
                writer.write(chunk)
                if on_progress is not None:
                    on_progress(sink.events, getattr(source, "fraction_read", None))
    except OSError as e:  # the partial output is gone (SinkWriter); a full disk said naming OUT
        if is_no_space(e):
            raise no_space_error(out) from None
        raise
    return {"source": str(path), "out": str(out), "format": sink.format, "events": sink.events,
            "width": source.geometry.width, "height": source.geometry.height}


def archive(recording, out, *, pipeline: Pipeline | None = None, keep_noise: bool = False, frames: bool = False,
            frame_format: str = "foxglove", points: bool = False, camera: str = "camera", encoding: str = "evt3",
            packet_us: int = 10_000, flush_s: float = 1.0, speed: float = 0.0, command=None, on_batch=None,
            stop=None, path=None, **options) -> dict[str, Any]:
    """A recording cleaned into an MCAP archive (ROS 2 EventPackets, the removed events per noise class
    with `keep_noise`, frames, point clouds, provenance): what `evstream archive` does. Returns its
    summary (the run's statistics, packets and frames written).

    `recording`: a path (opened with `evstream.open(path, **options)`) or a source already opened (then
    `path` names its file, for the provenance and the check that the archive is not written onto it).
    `pipeline`: the stages (and framer) to run; default the paper's cascade; `frames` without a framer
    adds a fixed-window one. `speed`: 1 = real time, 0 = as fast as possible. `on_batch(batch)` after
    each batch (progress); `stop()` polled between chunks ends the run early: the archive of the events so
    far is closed whole but kept as OUT-STEM.partial.mcap (the summary's `mcap`, with `partial` true), OUT
    left as it was. `command`: the command line, kept in the provenance. The archive is written beside OUT
    and renamed when whole (flushed every `flush_s`: a crash loses at most that), never onto the recording."""
    from evstream.sinks.mcap_sink import McapSink

    from . import api, threads

    if hasattr(recording, "geometry"):
        source = recording
        path = os.fspath(path) if path is not None else getattr(source, "path", None)
    else:
        path = os.fspath(recording)
        source = api.open(path, **options)
    if pipeline is None:
        pipeline = Pipeline([build("stage", {"kind": "paper"})])
    if frames and pipeline.framer is None:
        pipeline.framer = build("framer", {"kind": "fw"})
    provenance = {"source": str(path), "source_format": getattr(source, "format", type(source).__name__),
                  "width": source.geometry.width, "height": source.geometry.height,
                  "pipeline": pipeline.describe(), "command": command, "evstream": _version()}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    sink = McapSink(os.fspath(out), camera=camera, encoding=encoding, keep_noise=keep_noise,
                    frames=pipeline.framer is not None, frame_format=frame_format, points=points,
                    packet_us=packet_us, flush_s=flush_s, metadata=provenance,
                    geometry=pipeline.out_geometry(source.geometry),
                    inputs=([path] if path else []) + being_read())  # nor any recording the script has open
    def stopped() -> bool:  # cut short: the archive so far is closed whole but kept aside, OUT left as it was
        if stop is not None and stop():
            sink.interrupt()
            return True
        return False

    stats = pipeline.run(paced(source, speed), [sink], on_batch=on_batch,
                         threads=threads.enabled(), stop=stopped)
    return {**stats.as_dict(), "mcap": sink.written, "packets": sink.packets, "frames_written": sink.frames_written,
            "partial": sink.interrupted}


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("evstream")
    except Exception:  # not installed (running from a source tree)
        return "unknown"
