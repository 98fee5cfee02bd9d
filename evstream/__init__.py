"""evstream: a streaming pipeline for event cameras (sources -> denoise/framing stages -> sinks)."""

from .events import EventChunk, EventError, Frame, Geometry, NoiseClass, concat
from .pipeline import Batch, Pipeline, RunStats

__version__ = "0.1.0"
__all__ = [
    "Batch", "EventChunk", "EventError", "Frame", "Geometry", "NoiseClass", "Pipeline", "RunStats",
    "concat",
]
