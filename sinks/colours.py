"""The noise classes' colours, shared by every sink that draws events (the Rerun viewer, MCAP point clouds),
so a class looks the same in Rerun, Foxglove and the docs' pictures."""

from __future__ import annotations

from evstream.events import NoiseClass

CLASS_COLOURS = {  # RGB, apart on a dark background and for common colour blindness
    NoiseClass.SIGNAL: (80, 170, 255),  # light blue
    NoiseClass.BACKGROUND: (255, 150, 30),  # orange
    NoiseClass.HOT_PIXEL: (240, 40, 200),  # magenta
}
