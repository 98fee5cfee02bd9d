"""Frames to pictures: the paper's rendering, signed counts, colour maps; PNG files (zlib, no dependency).

Styles (`render(frame, style)`):
- `paper`: gray (128) background, white where ON events outnumber OFF ones, black where OFF do
  (the paper's figures: "black represents negative events and white represents positive events");
- `signed`: gray 128 at zero, brighter with more ON − OFF, darker with more OFF − ON, scaled to a
  robust maximum (the 99th percentile of the nonzero |ON − OFF|) so one hot pixel does not wash it out;
- a colour map name from `COLOUR_MAPS`: diverging maps (`coolwarm`, `bwr`) colour the signed counts,
  sequential ones (`viridis`, `hot`) the total events per pixel; RGB output.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..events import Frame

GRAY = 128

# Anchor colours, interpolated linearly into 256-entry tables. Diverging maps run OFF -> 0 -> ON.
_ANCHORS = {
    "coolwarm": ((59, 76, 192), (221, 221, 221), (180, 4, 38)),
    "bwr": ((0, 0, 255), (255, 255, 255), (255, 0, 0)),
    "viridis": ((68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)),
    "hot": ((0, 0, 0), (230, 0, 0), (255, 210, 0), (255, 255, 255)),
}
DIVERGING = ("coolwarm", "bwr")
STYLES = ("paper", "signed", *_ANCHORS)


def _table(anchors) -> np.ndarray:
    a = np.asarray(anchors, np.float64)
    pos = np.linspace(0, 255, len(a))
    return np.stack([np.interp(np.arange(256), pos, a[:, c]) for c in range(3)], axis=1).round().astype(np.uint8)


COLOUR_MAPS = {name: _table(a) for name, a in _ANCHORS.items()}


def _image(frame: Frame | np.ndarray) -> np.ndarray:
    return frame.image if isinstance(frame, Frame) else np.asarray(frame)


def paper(frame: Frame | np.ndarray) -> np.ndarray:
    """The paper's rendering: uint8 (H, W), 128 background, 255 ON, 0 OFF (by the sign of ON − OFF)."""
    signed_counts = _image(frame)
    out = np.full(signed_counts.shape, GRAY, np.uint8)
    out[signed_counts > 0] = 255
    out[signed_counts < 0] = 0
    return out


def robust_scale(values: np.ndarray) -> float:
    """The 99th percentile of the nonzero |values|, at least 1: what maps to full brightness."""
    nz = np.abs(values[values != 0])
    return max(1.0, float(np.percentile(nz, 99))) if nz.size else 1.0


def signed(frame: Frame | np.ndarray, scale: float | None = None) -> np.ndarray:
    """Signed counts in gray: uint8 (H, W), 128 at zero, 255 at +scale and above, 1 at −scale and below."""
    img = _image(frame).astype(np.float64)
    s = robust_scale(img) if scale is None else float(scale)
    return (GRAY + 127 * np.clip(img / s, -1, 1)).round().astype(np.uint8)


def coloured(frame: Frame, cmap: str = "coolwarm", scale: float | None = None) -> np.ndarray:
    """RGB uint8 (H, W, 3): a diverging map over ON − OFF, or a sequential map over ON + OFF."""
    if cmap not in COLOUR_MAPS:
        raise ValueError(f"unknown colour map {cmap!r}; choose from {', '.join(COLOUR_MAPS)}")
    if cmap in DIVERGING:
        idx = signed(frame, scale)
    else:
        total = frame.counts.sum(axis=0, dtype=np.int64) if isinstance(frame, Frame) else np.abs(frame)
        s = robust_scale(total) if scale is None else float(scale)
        idx = (255 * np.clip(total / s, 0, 1)).round().astype(np.uint8)
    return COLOUR_MAPS[cmap][idx]


def render(frame: Frame, style: str = "paper", scale: float | None = None) -> np.ndarray:
    """A frame as a picture in one of `STYLES` (uint8 gray (H, W) or RGB (H, W, 3))."""
    if style == "paper":
        return paper(frame)
    if style == "signed":
        return signed(frame, scale)
    if style in COLOUR_MAPS:
        return coloured(frame, style, scale)
    raise ValueError(f"unknown frame style {style!r}; choose from {', '.join(STYLES)}")


def mosaic(rows: list[list[np.ndarray]], gap: int = 4, background: int = 255) -> np.ndarray:
    """Pictures laid out in rows (each row left to right), `gap` pixels apart; gray ones become RGB
    when any picture is RGB."""
    pics = [p for row in rows for p in row]
    rgb = any(p.ndim == 3 for p in pics)
    rows = [[np.repeat(p[..., None], 3, axis=2) if rgb and p.ndim == 2 else p for p in row] for row in rows]
    h = max(p.shape[0] for p in pics)
    widths = [sum(p.shape[1] for p in row) + gap * (len(row) - 1) for row in rows]
    shape = (len(rows) * h + gap * (len(rows) - 1), max(widths)) + ((3,) if rgb else ())
    out = np.full(shape, background, np.uint8)
    for r, row in enumerate(rows):
        x = 0
        for p in row:
            out[r * (h + gap) : r * (h + gap) + p.shape[0], x : x + p.shape[1]] = p
            x += p.shape[1] + gap
    return out


# -- PNG ----------------------------------------------------------------------------------------------
def png_bytes(image: np.ndarray, level: int = 6) -> bytes:
    """PNG encoding of a uint8 gray (H, W) or RGB (H, W, 3) image (8 bits per sample, no filter)."""
    img = np.ascontiguousarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"PNG needs uint8 (H, W) or (H, W, 3), got {img.dtype} {img.shape}")
    h, w = img.shape[:2]
    if h == 0 or w == 0:
        raise ValueError("PNG needs at least one pixel")
    colour_type = 2 if img.ndim == 3 else 0
    rows = img.reshape(h, -1)
    raw = np.hstack([np.zeros((h, 1), np.uint8), rows]).tobytes()  # filter byte 0 on every row

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, level)) + \
        chunk(b"IEND", b"")


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a PNG whole or not at all (beside its name, then renamed: `safe_write`); a full disk is one
    OSError naming it."""
    from ..safe_write import AtomicOutput

    with AtomicOutput(path, sync=False) as part:
        part.write_bytes(png_bytes(image))


class PngWriter:
    """A sink writing every frame of a run as `frame_000000.png`, ... in `out_dir` (created)."""

    def __init__(self, out_dir: str | os.PathLike, style: str = "paper", scale: float | None = None):
        if style not in STYLES:
            raise ValueError(f"unknown frame style {style!r}; choose from {', '.join(STYLES)}")
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.style, self.scale = style, scale
        self.written = 0

    def write(self, batch) -> None:
        for frame in batch.frames:
            write_png(self.out_dir / f"frame_{self.written:06d}.png", render(frame, self.style, self.scale))
            self.written += 1

    def close(self, stats) -> None:
        pass


# -- representations ----------------------------------------------------------------------------------
def render_representation(rep) -> np.ndarray:
    """A representation (`represent.Representation`) as an RGB picture: the time surface and the
    last-timestamp image in viridis over the newer polarity (max of the channels, 0..1), the count
    image in `hot` (robust scale), the histogram in coolwarm over ON − OFF, the voxel grid's bins side
    by side in coolwarm (one shared robust scale, so the bins compare)."""
    data = rep.data
    if rep.kind in ("timesurface", "timestamp"):
        idx = (255 * np.clip(data.max(axis=0), 0, 1)).round().astype(np.uint8)
        return COLOUR_MAPS["viridis"][idx]
    if rep.kind == "count":
        total = data[0]
        idx = (255 * np.clip(total / robust_scale(total), 0, 1)).round().astype(np.uint8)
        return COLOUR_MAPS["hot"][idx]
    if rep.kind == "histogram":
        return COLOUR_MAPS["coolwarm"][signed(data[1] - data[0])]
    if rep.kind == "voxel":
        s = robust_scale(data)
        return mosaic([[COLOUR_MAPS["coolwarm"][signed(b, s)] for b in data]], background=0)
    raise ValueError(f"no rendering for representation {rep.kind!r}")
