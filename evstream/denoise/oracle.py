"""Stages that need no model: the ground-truth oracle and `KeepSignal`."""

from __future__ import annotations

from dataclasses import dataclass

from ..events import EventChunk, NoiseClass
from ..pipeline import register


@register("stage", "truth")
@dataclass
class TruthStage:
    """Copies ground-truth `label` into `cls`: shows what a perfect denoiser would do (synthetic data)."""

    def __call__(self, chunk: EventChunk) -> EventChunk:
        if chunk.label is None:
            raise ValueError("the 'truth' stage needs labelled events (synthetic or injected noise)")
        return chunk.replace(cls=chunk.label.copy())

    def params(self) -> dict:
        return {}


@register("stage", "keep_signal")
@dataclass
class KeepSignal:
    """Drops every event not classed SIGNAL — the one denoise stage that removes events."""

    drops_events = True  # as the transforms say it (not a field: no annotation)

    def __call__(self, chunk: EventChunk) -> EventChunk:
        if chunk.cls is None:
            return chunk
        return chunk.of_class(NoiseClass.SIGNAL)

    def params(self) -> dict:
        return {}
