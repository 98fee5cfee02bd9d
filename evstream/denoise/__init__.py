"""Denoise stages, one module per method family; importing this package declares them all.

`--denoise NAME` builds the registered stage kind NAME (`none` runs no stage). A new filter is one
new module here with a `@register("stage", "name")` class, declared below: the module is imported when
its stage is first built (or listed with its parameters), so a command imports only the filters it runs.
"""

from ..pipeline import declare
from .base import Classifier

MODULES = {  # module -> the stage kinds it registers (tests/test_pipeline.py checks both ways)
    "baf": ("baf",), "cascade": ("paper",), "density": ("density",), "dwf": ("dwf",), "hotpixel": ("hotpixel",),
    "khodamoradi": ("khodamoradi",), "learned": ("learned",), "oracle": ("truth", "keep_signal"),
    "refractory": ("refractory",), "stcf": ("stcf",), "timeseries": ("dc",), "ynoise": ("ynoise",),
}
for _module, _kinds in MODULES.items():
    declare("stage", f"{__name__}.{_module}", *_kinds)

__all__ = ["Classifier"]
