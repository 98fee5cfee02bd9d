"""evstream: a streaming pipeline for event cameras (sources -> denoise/framing stages -> sinks).

The Python API (docs/api.md) is here: `open`/`read` a recording, `stage`/`framer`/`build_pipeline` by
name, `classify`/`clean` chunks, streams or structured arrays, `open_sink` to write, `Denoise` and
`Represent` as tonic-style transforms, `catalogue` to list every stage and framer.
"""

from . import _start  # noqa: F401 - first: Ctrl-C while the package loads (evstream/_start.py)
from .api import (
    Denoise,
    Represent,
    as_geometry,
    batches,
    build_pipeline,
    catalogue,
    classify,
    clean,
    framer,
    from_structured,
    info,
    open,  # noqa: F401 - evstream.open, not in __all__ (below)
    read,
    set_params,
    stage,
    subscribe,
)
from .events import EventChunk, EventError, Frame, Geometry, NoiseClass, concat
from .pipeline import Batch, Pipeline, RunStats
from .writers import SinkWriter, archive, convert, open_sink

__version__ = "0.1.0"
# `open` is left out of the star-import list: `from evstream import *` must not shadow the builtin
__all__ = [
    "Batch", "Denoise", "EventChunk", "EventError", "Frame", "Geometry", "NoiseClass", "Pipeline", "Represent",
    "RunStats", "SinkWriter", "archive", "as_geometry", "batches", "build_pipeline", "catalogue", "classify", "clean",
    "concat", "convert", "framer", "from_structured", "info", "open_sink", "read", "set_params", "stage", "subscribe",
]
