"""Prophesee RAW files (EVT 2.0, EVT 3.0): an ASCII `% key value` header, then the event words.

Decoded by our numba codecs (`evstream.codecs.evt2`/`evt3`): faery reads these at 10-27 M events/s
and shifts events where EVT3's TIME_LOW steps back; ours is spec-literal and faster. Timestamps are
the sensor's clock in µs, unwrapped. Sensor size from `% format ...;width=W;height=H`, `% geometry WxH`
or `% Width`/`% Height` lines, else from the camera plugin (Gen3 VGA files carry none), else assumed
1280x720 and said so in `info()`.

`save(path, chunks, geometry)` writes EVT3 (or EVT2) RAW files that Metavision and faery read.
"""

from __future__ import annotations

import builtins
import copy
import itertools
import os
import re
from collections.abc import Iterable, Iterator

from evstream.codecs import evt2, evt3
from evstream.events import EventChunk, Geometry

from ._base import Block, FileSource, as_geometry, read_header_lines

NAME = "Prophesee RAW (EVT 2.0, EVT 3.0)"
FORMAT = "prophesee-raw"

# camera plugins whose files may lack a geometry line
_PLUGIN_GEOMETRY = [
    ("gen41", Geometry(1280, 720)), ("imx636", Geometry(1280, 720)), ("imx646", Geometry(1280, 720)),
    ("gen4", Geometry(1280, 720)), ("genx320", Geometry(320, 320)), ("imx8", Geometry(320, 320)),
    ("gen31", Geometry(640, 480)), ("gen3", Geometry(640, 480)),
]
_DEFAULT_GEOMETRY = Geometry(1280, 720)
_VERSIONS = {"2.0": "evt2", "2.1": "evt2.1", "3.0": "evt3"}
_WRAP_US = 1 << 24


def probe(head: bytes, path: str) -> bool:
    if not head.startswith(b"% "):
        return False
    lines = head.split(b"\n")[:64]
    text = b"\n".join(ln for ln in lines if ln.startswith(b"%")).lower()
    if b"data file containing" in text:  # a DAT file: same header style, different body
        return False
    return (b"% evt " in text or b"format evt" in text or b"plugin_name" in text
            or path.lower().endswith(".raw"))


def parse_header(lines: list[str]) -> dict:
    """Header `% key value` lines as a dict (lower-case keys); `format` split into its fields."""
    out: dict = {}
    for line in lines:
        body = line[1:].strip()
        if not body or body.lower() == "end":
            continue
        key, _, value = body.partition(" ")
        out[key.lower()] = value.strip()
    fmt = out.get("format", "")
    if fmt:
        name, *fields = fmt.split(";")
        out["format_name"] = name.strip().upper()
        for f in fields:
            k, _, v = f.partition("=")
            out[f"format_{k.strip().lower()}"] = v.strip()
    return out


def header_version(h: dict) -> str | None:
    words = h.get("evt", "").split()
    if words:  # '% evt ' with no value says nothing: fall back to '% format'
        return _VERSIONS.get(words[0])
    name = h.get("format_name", "")
    return {"EVT2": "evt2", "EVT21": "evt2.1", "EVT3": "evt3"}.get(name)


def header_geometry(h: dict) -> tuple[Geometry | None, str]:
    try:
        if "format_width" in h and "format_height" in h:
            return Geometry(int(h["format_width"]), int(h["format_height"])), "header (format)"
        if "geometry" in h:
            return as_geometry(h["geometry"].split()[0]), "header (geometry)"
        if "width" in h and "height" in h:
            return Geometry(int(h["width"]), int(h["height"])), "header (width/height)"
    except ValueError:
        return None, "header (unreadable geometry)"
    plugin = h.get("plugin_name", "").lower()
    for key, g in _PLUGIN_GEOMETRY:
        if key in plugin:
            return g, f"camera plugin {plugin!r}"
    return None, ""


class RawSource(FileSource):
    """Replays a Prophesee RAW file. Extra option: `version` ('evt2', 'evt3') when the header lacks it.

    Timestamp policy defaults to 'sort': camera streams can step back by a few µs (EVT3 TIME_LOW).
    """

    default_timestamps = "sort"

    def __init__(self, path, version: str | None = None, **options):
        super().__init__(path, **options)
        with builtins.open(self.path, "rb") as f:
            lines, self.body_offset = read_header_lines(f, b"%", end_line="% end")
        self.header = parse_header(lines)
        self.version = version or header_version(self.header)
        if self.version is None:
            raise self.error(f"RAW header (bytes 0..{self.body_offset}) names no EVT version (no '% evt' or "
                             "'% format' line): damaged, or not a Prophesee RAW file; from Python, "
                             "evstream.sources.open_source(path, version='evt3') reads it as EVT 3.0")
        if self.version not in ("evt2", "evt3"):
            raise self.error(f"RAW {self.version} is not supported (EVT 2.0 and 3.0 are)")
        self.format = self.version
        g, source = header_geometry(self.header)
        if g is None:
            g, source = _DEFAULT_GEOMETRY, "assumed (no geometry in the header)"
        self.set_geometry(g, source)
        try:
            self.t_origin_us = int(self.header.get("t_origin_us", "0").split()[0])
        except ValueError:
            raise self.error(f"header t_origin_us {self.header['t_origin_us']!r} is not an integer") from None
        self.details = {"header": {k: v for k, v in self.header.items() if not k.startswith("format_")},
                        "body_offset": self.body_offset, "t_origin_us": self.t_origin_us}

    def set_time_range(self, start_us: int | None, end_us: int | None) -> bool:
        """Skip to `start_us` without decoding the events before it: the decoder's state (time base,
        wraps, and for EVT3 the row and vector base) is followed word by word — EVT's clock wraps (every
        16.8 s in EVT3), so where a time lies in the file is only known from its start — and decoding
        begins at the first word from which an event can be in the range (`skip_before`)."""
        self._seek_us = None if start_us is None else int(start_us) - self.t_origin_us
        return start_us is not None

    def _blocks(self) -> Iterator[Block]:
        dec = evt3.Evt3Decoder() if self.version == "evt3" else evt2.Evt2Decoder()
        word = 2 if self.version == "evt3" else 4
        pos = self.body_offset
        unknown_seen = 0
        seek = getattr(self, "_seek_us", None)
        with builtins.open(self.path, "rb") as f:
            f.seek(pos)
            while True:
                data = f.read(self.block_bytes)
                if not data:
                    break
                if seek is not None:
                    rest = dec.skip_before(data, seek)
                    if rest is None:  # the whole block is before the range
                        pos += len(data)
                        self.fraction_read = min(1.0, pos / max(1, self.file_size))
                        continue
                    seek = None
                    pos += len(data) - len(rest)
                    data = rest
                before = copy.deepcopy(dec)
                t, x, y, p = dec.decode(data)
                unknown = dec.counters["unknown"] - unknown_seen
                unknown_seen += unknown
                words = len(data) // word
                if unknown > 16 and unknown * 20 > words:
                    raise self.error(
                        f"{unknown} of {words} words in bytes {pos}..{pos + len(data)} have unknown "
                        f"types: not {self.version.upper()} data (corrupt, or a wrong '% evt' header?)", pos)
                if self.t_origin_us:
                    t += self.t_origin_us
                yield Block(t, x, y, p, pos, pos + len(data), locate=_locator(before, data, pos, word))
                pos += len(data)
                self.counters = dec.counters
        self.counters = dec.counters
        if dec.pending_bytes:
            self.warn(f"truncated: the last {dec.pending_bytes} byte(s) at byte {pos - dec.pending_bytes} "
                      f"are half an {self.version.upper()} word (ignored)")


def _locator(before, data: bytes, pos: int, word: int):
    """Event index within a block -> byte offset of the word that made it (binary search over
    prefixes, decoded from the decoder's state before the block; only run on the error path)."""

    def locate(i: int) -> int:
        r = before.pending_bytes
        lo, hi = 1, (r + len(data)) // word
        while lo < hi:  # smallest word count p whose decode yields more than i events
            mid = (lo + hi) // 2
            if len(copy.deepcopy(before).decode(data[: mid * word - r])[0]) > i:
                hi = mid
            else:
                lo = mid + 1
        return pos - r + (lo - 1) * word

    return locate


def open(path, **options) -> RawSource:  # noqa: A001 - the format-module interface
    return RawSource(path, **options)


# -- writer ----------------------------------------------------------------------------------------
def save(path: str | os.PathLike, events: EventChunk | Iterable[EventChunk], geometry: Geometry | None = None,
         version: str = "evt3", header: dict | None = None, t_origin_us: int | str = "auto") -> int:
    """Write events (a chunk or chunks, timestamps non-decreasing) as a RAW file; returns the count.

    EVT timestamps count from the camera's start; absolute clocks (AEDAT4's Unix µs) would take
    millions of TIME_HIGH wraps, so `t_origin_us` ('auto': a multiple of 2^24 µs below the first event
    when that is past 2^32 µs, else 0) is subtracted and kept in a `% t_origin_us` header line, which
    our reader adds back (other readers see time from the origin).
    """
    chunks = iter([events] if isinstance(events, EventChunk) else events)
    enc = evt3.Evt3Encoder() if version == "evt3" else evt2.Evt2Encoder() if version == "evt2" else None
    if enc is None:
        raise ValueError(f"version {version!r}: choose 'evt3' or 'evt2'")
    held = []  # chunks up to the first non-empty one, which fixes the time origin
    for c in chunks:
        held.append(c)
        if len(c):
            break
    geometry = geometry or (held[0].geometry if held else None)
    if geometry is None:
        raise ValueError("save: no events and no geometry given")
    if geometry.width > 2048 or geometry.height > 2048:
        raise ValueError(f"save: EVT addresses are 11 bits; a {geometry} sensor does not fit")
    t_first = int(held[-1].t[0]) if held and len(held[-1]) else 0
    if t_origin_us == "auto":
        t_origin_us = t_first // _WRAP_US * _WRAP_US if t_first >= 1 << 32 else 0
    t_origin_us = int(t_origin_us)
    if t_origin_us > t_first:
        raise ValueError(f"save: t_origin_us {t_origin_us} is after the first event ({t_first} µs)")
    fmt = "EVT3" if version == "evt3" else "EVT2"
    lines = [f"evt {'3.0' if version == 'evt3' else '2.0'}",
             f"format {fmt};height={geometry.height};width={geometry.width}",
             f"geometry {geometry.width}x{geometry.height}", "generator evstream"]
    if t_origin_us:
        lines.append(f"t_origin_us {t_origin_us}")
    for k, v in (header or {}).items():
        if not re.fullmatch(r"[A-Za-z0-9_]+", str(k)) or "\n" in str(v):
            raise ValueError(f"save: header entry {k!r} must be a word and a one-line value")
        lines.append(f"{k} {v}")
    n = 0
    with builtins.open(path, "wb") as f:
        f.write("".join(f"% {ln}\n" for ln in lines).encode() + b"% end\n")
        for chunk in itertools.chain(held, chunks):
            if len(chunk):
                f.write(enc.encode(chunk.t - t_origin_us, chunk.x, chunk.y, chunk.p))
                n += len(chunk)
    return n
