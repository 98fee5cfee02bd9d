"""Frame statistics as the paper reports them (Tables 5–6): frame rate, mean and variance of events per frame.

Frame rate = frames / duration of the input stream (first to last event, event time), in frames per
second. Mean and variance are over the frames' `n_events` (population variance, ddof 0), computed in
one pass (Welford), so a run of any length is summarised in constant memory. `evstream frames` leaves
out the frames that only the end of the stream closed (`finish()`): their size says where the
recording stops, not how the method frames.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class FrameStats:
    """Running statistics of a framer's output; also a sink (`write(batch)`, `close(stats)`), taking the
    stream's duration from the run statistics it is closed with."""

    frames: int = 0
    mean_events: float = 0.0
    _m2: float = 0.0
    empty_frames: int = 0
    duration_us: int = 0

    def add(self, n_events: int) -> None:
        self.frames += 1
        self.empty_frames += n_events == 0
        delta = n_events - self.mean_events
        self.mean_events += delta / self.frames
        self._m2 += delta * (n_events - self.mean_events)

    def add_frames(self, frames) -> FrameStats:
        for f in frames:
            self.add(f.n_events)
        return self

    @property
    def variance_events(self) -> float:
        return self._m2 / self.frames if self.frames else 0.0

    @property
    def frame_rate_hz(self) -> float:
        return self.frames / (self.duration_us * 1e-6) if self.duration_us > 0 else 0.0

    def as_dict(self) -> dict:
        return {"frames": self.frames, "frame_rate_hz": self.frame_rate_hz, "mean_events": self.mean_events,
                "variance_events": self.variance_events, "empty_frames": self.empty_frames,
                "duration_us": self.duration_us}

    # -- as a sink ---------------------------------------------------------------------------------
    def write(self, batch) -> None:
        self.add_frames(batch.frames)
        self.duration_us = batch.stats.duration_us

    def close(self, stats) -> None:
        self.duration_us = stats.duration_us


def frame_stats(frames, duration_us: int) -> FrameStats:
    """Statistics of a list of frames from a stream lasting `duration_us`."""
    s = FrameStats(duration_us=int(duration_us))
    return s.add_frames(frames)
