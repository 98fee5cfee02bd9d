"""A bounded, seeded mutation fuzzer for the file readers (used by tests/test_fuzz.py).

`seed_files(dir)` writes one small valid file per format; `mutants(data, rng)` yields (class, bytes)
mutants of one: bit flips, header bytes, length fields set to boundary values, truncation, blocks
duplicated or dropped, and for zip files members whose sizes lie and zip bombs. `read(path)` replays a
file the way `evstream info` does and returns the event count, or raises EventError; anything else is
a finding.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib

import numpy as np
from evstream.sources import aedat2, hdf5, native, open_source, prophesee_raw, text
from test_sources_formats import write_dat, write_mat, write_nmnist

from evstream.events import Geometry
from evstream.testing import random_stream

G = Geometry(128, 128)
BOUNDARY = [0, 1, 2, 0x7F, 0x80, 0xFF, 0x7FFF, 0x8000, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF,
            0x7FFFFFFFFFFFFFFF, 0xFFFFFFFFFFFFFFFF]


def _events(n=600, seed=0, g=G):
    s = random_stream(seed, n, g)
    return s.replace(label=None)


def _npz(path, arrays: dict, compress: bool):
    with open(path, "wb") as f:
        (np.savez_compressed if compress else np.savez)(f, **arrays)


def seed_files(d, real=None) -> dict:
    """name -> path of one small valid file per format (AEDAT4 from the real recordings, when present)."""
    s = _events()
    g640 = Geometry(640, 480)
    s640 = _events(600, 1, g640)
    writers = {
        "evt3.raw": lambda p: prophesee_raw.save(p, s640),
        "evt2.raw": lambda p: prophesee_raw.save(p, s640, version="evt2"),
        "event2d.dat": lambda p: write_dat(p, s),
        "nmnist.bin": lambda p: write_nmnist(p, s.replace(geometry=Geometry(128, 128))),
        "aedat2.aedat": lambda p: aedat2.save(p, s.t, s.x, s.y, s.p),
        "events.txt": lambda p: text.save(p, s),
        "events.h5": lambda p: hdf5.save(p, s),
        "events.npy": lambda p: np.save(p, s.to_structured()),
        "native.npz": lambda p: native.save(p, s, {"seed": 0}),
        "stored.npz": lambda p: _npz(p, {"t": s.t, "x": s.x, "y": s.y, "p": s.p}, compress=False),
        "events.mat": lambda p: write_mat(p, "events", np.stack([s.x, s.y, s.p, s.t], axis=1), compress=True),
        "archive.mcap": lambda p: _mcap(p, s),
    }
    files = {}
    for name, write in writers.items():
        write(d / name)
        files[name] = d / name
    if real is not None and (real / "davis346_frames_imu_evlib.aedat4").exists():
        data = (real / "davis346_frames_imu_evlib.aedat4").read_bytes()
        files["real.aedat4"] = d / "real.aedat4"
        files["real.aedat4"].write_bytes(data)
    return files


def _mcap(path, s):
    from evstream.sinks.mcap_sink import McapSink

    from evstream.pipeline import Pipeline

    Pipeline([]).run([s], [McapSink(path, frames=False)])


# -- mutations ----------------------------------------------------------------------------------------
def _flip(data: bytearray, rng) -> bytearray:
    for _ in range(int(rng.integers(1, 9))):
        i = int(rng.integers(len(data)))
        data[i] ^= 1 << int(rng.integers(8))
    return data


def _header(data: bytearray, rng) -> bytearray:
    span = min(len(data), 512)
    for _ in range(int(rng.integers(1, 5))):
        data[int(rng.integers(span))] = int(rng.integers(256))
    return data


def _length(data: bytearray, rng) -> bytearray:
    """A 2-, 4- or 8-byte little- or big-endian integer set to a boundary value (lengths, counts, sizes)."""
    width = int(rng.choice([2, 4, 8]))
    if len(data) <= width:
        return data
    near_start = rng.random() < 0.6
    i = int(rng.integers(0, min(len(data), 1024) - width)) if near_start else int(rng.integers(len(data) - width))
    value = int(rng.choice(BOUNDARY)) & ((1 << (8 * width)) - 1)
    if rng.random() < 0.3:  # the value there, scaled: a length that is wrong but plausible
        old = int.from_bytes(data[i:i + width], "little")
        value = (old * int(rng.choice([2, 16, 1024])) + int(rng.integers(-2, 3))) & ((1 << (8 * width)) - 1)
    data[i:i + width] = value.to_bytes(width, "big" if rng.random() < 0.25 else "little")
    return data


def _truncate(data: bytearray, rng) -> bytearray:
    return data[: int(rng.integers(0, len(data)))]


def _duplicate(data: bytearray, rng) -> bytearray:
    a = int(rng.integers(len(data)))
    b = min(len(data), a + int(rng.integers(1, 4096)))
    at = int(rng.integers(len(data)))
    return data[:at] + data[a:b] + data[at:]


def _drop(data: bytearray, rng) -> bytearray:
    a = int(rng.integers(len(data)))
    b = min(len(data), a + int(rng.integers(1, 4096)))
    return data[:a] + data[b:]


def _zip_sizes(data: bytearray, rng) -> bytearray:
    """Every size field of one zip member (local header and central directory) claims more: up to 4 GiB."""
    try:
        z = zipfile.ZipFile(io.BytesIO(bytes(data)))
        infos = z.infolist()
    except (zipfile.BadZipFile, ValueError, OSError):
        return _length(data, rng)
    info = infos[int(rng.integers(len(infos)))]
    claim = int(rng.choice([info.file_size * 1000, 2**31, 2**32 - 1, info.file_size + 1]))
    claim = min(claim, 2**32 - 1)
    h = info.header_offset
    if data[h:h + 4] == b"PK\x03\x04":
        data[h + 22:h + 26] = struct.pack("<I", claim)  # uncompressed size
    pos = bytes(data).find(b"PK\x01\x02")
    while 0 <= pos < len(data) - 46:
        name_len, extra_len, comment_len = struct.unpack("<HHH", data[pos + 28:pos + 34])
        offset = struct.unpack("<I", data[pos + 42:pos + 46])[0]
        if offset == h:
            data[pos + 24:pos + 28] = struct.pack("<I", claim)
            if rng.random() < 0.5:
                data[pos + 20:pos + 24] = struct.pack("<I", claim)  # compressed size too
        pos = bytes(data).find(b"PK\x01\x02", pos + 46 + name_len + extra_len + comment_len)
    return data


_BOMBS: dict = {}


def _npy(a) -> bytes:
    b = io.BytesIO()
    np.save(b, a)
    return b.getvalue()


def zip_bomb(kind: str) -> bytes:
    """A native .npz (x, y, p, width, height small) whose `t` member is a bomb: "inflate" = 256 MiB of
    zeros behind a valid npy header, deflated to ~256 KB; "claim" = a small member whose npy header
    claims 2**29 int64 (4 GiB)."""
    if kind not in _BOMBS:
        small = np.zeros(4, np.uint16)
        members = {f"{k}.npy": _npy(a) for k, a in (("x", small), ("y", small), ("p", small.astype(np.uint8)),
                                                    ("width", np.int64(128)), ("height", np.int64(128)))}
        members = {k: _deflated(v) for k, v in members.items()}
        if kind == "inflate":
            head = io.BytesIO()
            np.lib.format.write_array_header_1_0(head, {"descr": "<i8", "fortran_order": False, "shape": (2**25,)})
            comp = zlib.compressobj(9, zlib.DEFLATED, -15)
            crc = zlib.crc32(head.getvalue())
            body = [comp.compress(head.getvalue())]
            zeros = bytes(1 << 20)
            for _ in range(256):
                body.append(comp.compress(zeros))
                crc = zlib.crc32(zeros, crc)
            body.append(comp.flush())
            members["t.npy"] = (b"".join(body), crc, len(head.getvalue()) + (256 << 20))
        else:
            head = io.BytesIO()
            np.lib.format.write_array_header_1_0(head, {"descr": "<i8", "fortran_order": False, "shape": (2**29,)})
            members["t.npy"] = _deflated(head.getvalue() + bytes(64))
        _BOMBS[kind] = _zip(members)
    return _BOMBS[kind]


def _deflated(raw: bytes) -> tuple[bytes, int, int]:
    comp = zlib.compressobj(6, zlib.DEFLATED, -15)
    return comp.compress(raw) + comp.flush(), zlib.crc32(raw), len(raw)


def _zip(members: dict) -> bytes:
    """A zip of deflated members {name: (raw deflate stream, crc, uncompressed size)}."""
    out = io.BytesIO()
    entries = []
    for name, (payload, crc, usize) in members.items():
        offset = out.tell()
        fname = name.encode()
        out.write(struct.pack("<4sHHHHHIIIHH", b"PK\x03\x04", 20, 0, 8, 0, 0, crc, len(payload), usize,
                              len(fname), 0) + fname + payload)
        entries.append((fname, crc, len(payload), usize, offset))
    cd_start = out.tell()
    for fname, crc, csize, usize, offset in entries:
        out.write(struct.pack("<4sHHHHHHIIIHHHHHII", b"PK\x01\x02", 20, 20, 0, 8, 0, 0, crc, csize, usize,
                              len(fname), 0, 0, 0, 0, 0, offset) + fname)
    cd_end = out.tell()
    out.write(struct.pack("<4sHHHHIIH", b"PK\x05\x06", 0, 0, len(entries), len(entries), cd_end - cd_start,
                          cd_start, 0))
    return out.getvalue()


MUTATIONS = {"bit flips": _flip, "header bytes": _header, "length field": _length, "truncation": _truncate,
             "duplicated block": _duplicate, "dropped block": _drop}


def mutants(name: str, data: bytes, rng, count: int):
    """`count` (class, bytes) mutants of `data`, the file called `name`."""
    classes = list(MUTATIONS)
    if name.endswith(".npz"):
        classes += ["zip sizes", "zip sizes"]
    for k in range(count):
        kind = classes[k % len(classes)]
        if name.endswith(".npz") and k % 50 == 49:
            kind = "zip bomb"
            yield kind, zip_bomb("inflate" if k % 100 == 49 else "claim")
            continue
        buf = bytearray(data)
        mutate = _zip_sizes if kind == "zip sizes" else MUTATIONS[kind]
        if rng.random() < 0.2:  # two mutations at once, now and then
            buf = MUTATIONS[classes[int(rng.integers(6))]](buf, rng) if len(buf) else buf
        yield kind, bytes(mutate(buf, rng) if len(buf) else buf)


def read(path) -> int:
    """Replay `path` as `evstream info` does: the event count, or EventError. Checks the events are valid."""
    src = open_source(path)
    n = 0
    g = src.geometry
    last = None
    for c in src:
        if len(c):
            assert (c.x < g.width).all() and (c.y < g.height).all(), path
            assert c.p.max() <= 1, path
            assert np.all(np.diff(c.t) >= 0) and (last is None or c.t[0] >= last), path
            last = int(c.t[-1])
        n += len(c)
    return n
