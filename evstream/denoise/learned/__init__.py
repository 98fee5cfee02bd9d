"""The learned denoiser: causal per-event features (`features`), a small model on them (`model`),
the stage that scores a stream (`stage`) and the training that fits it to recordings (`train`)."""

from .features import FEATURE_VERSION, FEATURES
from .model import Model, ModelError, load
from .stage import LearnedFilter

__all__ = ["FEATURES", "FEATURE_VERSION", "LearnedFilter", "Model", "ModelError", "load"]
