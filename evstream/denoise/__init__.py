"""Denoise stages, one module per method family; importing this package registers them all.

`--denoise NAME` builds the registered stage kind NAME (`none` runs no stage). A new filter is one
new module here with a `@register("stage", "name")` class, imported below.
"""

from . import (  # noqa: F401  (importing a module registers its stages)
    baf,
    cascade,
    density,
    dwf,
    hotpixel,
    khodamoradi,
    learned,
    oracle,
    refractory,
    stcf,
    timeseries,
    ynoise,
)
from .base import Classifier

__all__ = ["Classifier"]
