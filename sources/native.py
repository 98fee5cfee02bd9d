"""evstream's native format: an `.npz` of struct-of-arrays events plus geometry, labels and metadata.

Arrays: `t` int64 µs, `x`, `y` uint16, `p` uint8 (1 = ON), optional `label` and `cls` uint8;
scalars `width`, `height`; `meta` a JSON string (scene, seed, noise, provenance). No pickle: the
file is read with `allow_pickle=False`.
"""

from __future__ import annotations

import builtins
import json
import os
import zipfile
import zlib
from collections.abc import Iterable, Iterator

import numpy as np

from evstream.events import EventChunk, EventError, Geometry, Validator, concat

from ._base import MAX_SENSOR_SIDE

NAME = "native (.npz)"
FORMAT = "native"
DEFAULT_CHUNK_EVENTS = 50_000
# What numpy's lazy .npz members raise on a damaged file (a bad CRC, a broken deflate stream, a cut member).
ZIP_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)


def probe(head: bytes, path: str) -> bool:
    if not head.startswith(b"PK\x03\x04"):
        return False
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
    except zipfile.BadZipFile:
        return False
    return {"t.npy", "x.npy", "y.npy", "p.npy", "width.npy", "height.npy"} <= names


def save(path: str | os.PathLike, events: EventChunk | Iterable[EventChunk], meta: dict | None = None,
         compress: bool = True) -> EventChunk:
    """Write events (a chunk or an iterable of chunks) to `path`; returns what was written."""
    chunk = events if isinstance(events, EventChunk) else concat(list(events))
    arrays = {"t": chunk.t, "x": chunk.x, "y": chunk.y, "p": chunk.p,
              "width": np.int64(chunk.geometry.width), "height": np.int64(chunk.geometry.height),
              "meta": np.array(json.dumps(meta or {}, sort_keys=True))}
    for name in ("label", "cls"):
        if getattr(chunk, name) is not None:
            arrays[name] = getattr(chunk, name)
    with builtins.open(path, "wb") as f:
        (np.savez_compressed if compress else np.savez)(f, **arrays)
    return chunk


class NativeSource:
    """Replays a native `.npz` in chunks of `chunk_events` events (or `chunk_us` of event time)."""

    format = FORMAT

    def __init__(self, path, chunk_events: int = DEFAULT_CHUNK_EVENTS, chunk_us: int | None = None,
                 geometry: Geometry | None = None, timestamps: str = "error"):
        self.path = os.fspath(path)
        try:
            self._npz = np.load(self.path, allow_pickle=False)
            files = set(self._npz.files)
            missing = {"t", "x", "y", "p", "width", "height"} - files
            if missing:
                raise EventError(f"{self.path}: native file lacks arrays {sorted(missing)}")
            self.geometry = geometry or Geometry(int(self._npz["width"]), int(self._npz["height"]))
            if geometry is None and max(self.geometry.width, self.geometry.height) > MAX_SENSOR_SIDE:
                raise EventError(f"{self.path}: the file claims a {self.geometry} sensor, larger than any event "
                                 f"camera ({MAX_SENSOR_SIDE} a side); pass geometry=(width, height) if it is real")
            self.meta = json.loads(str(self._npz["meta"])) if "meta" in files else {}
            self._t = self._npz["t"]
        except ZIP_ERRORS as e:
            if isinstance(e, EventError):
                raise
            raise EventError(f"{self.path}: unreadable native file: {e}") from None
        self.has_labels = "label" in files
        self.fraction_read: float | None = None  # share of the events read so far
        self.chunk_events = int(chunk_events)
        self.chunk_us = chunk_us
        self.timestamps = timestamps
        if self.chunk_events <= 0 or (chunk_us is not None and chunk_us <= 0):
            raise ValueError("chunk_events and chunk_us must be positive")

    def info(self) -> dict:
        return {"format": self.format, "path": self.path, "meta": self.meta}

    def _bounds(self) -> list[int]:
        n = len(self._t)
        if self.chunk_us is None:
            return [*range(0, n, self.chunk_events), n]
        if n == 0:
            return [0, 0]
        edges = np.arange(int(self._t[0]), int(self._t[-1]) + self.chunk_us, self.chunk_us)
        return [0, *np.searchsorted(self._t, edges[1:], side="left").tolist(), n]

    def __iter__(self) -> Iterator[EventChunk]:
        z = self._npz
        try:  # members are decompressed here, on first use: a corrupt one shows only now
            arrays = {k: z[k] for k in ("x", "y", "p", *(["label"] if self.has_labels else []))}
        except ZIP_ERRORS as e:
            raise EventError(f"{self.path}: unreadable native file: {type(e).__name__}: {e}") from None
        n = len(self._t)
        for k, a in arrays.items():
            if len(a) != n:
                raise EventError(f"{self.path}: array {k!r} has {len(a)} entries, 't' has {n}")
        check = Validator(self.geometry, self.path, self.timestamps)
        bounds = self._bounds()
        for a, b in zip(bounds[:-1], bounds[1:]):
            t_end = int(self._t[b]) if b < n else (int(self._t[-1]) if n else 0)
            chunk = EventChunk.from_arrays(
                self._t[a:b], arrays["x"][a:b], arrays["y"][a:b], arrays["p"][a:b], self.geometry,
                label=arrays["label"][a:b] if self.has_labels else None, t_end=t_end,
            )
            self.fraction_read = b / n if n else 1.0
            yield check(chunk)


def open(path, **options) -> NativeSource:  # noqa: A001 - the format-module interface
    return NativeSource(path, **options)
