"""Sources: where event chunks come from (files, MCAP logs, Zenoh). One module per format family.

`open_source(path_or_uri)` picks the reader by content (magic bytes), using the extension only as a
hint. A new file format is one new module here with a `probe(head: bytes, path) -> bool` and an
`open(path, **options)`; add its name to `_FORMAT_NAMES`. Readers are imported as `open_source` reaches them
in the probing order (a native file imports no MCAP or HDF5 library: start-up time); `FORMATS` imports all.
"""

from __future__ import annotations

import importlib
import os
import zipfile

from evstream.events import EventError

from ._base import EventWarning, as_geometry

# Readers, most specific magic first; each module has probe(head, path) and open(path, **options).
# N-MNIST binaries have no magic at all: they come last and need their extension.
_FORMAT_NAMES = ("native", "numpy_files", "hdf5", "aedat4", "aedat2", "matlab", "mcap_log", "dat", "prophesee_raw",
                 "text", "nmnist")


def _formats():
    """The reader modules in probing order, each imported when first reached."""
    for name in _FORMAT_NAMES:
        yield importlib.import_module(f"{__name__}.{name}")


def __getattr__(name: str):
    if name == "FORMATS":  # every reader module, in probing order
        return list(_formats())
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")



def open_source(uri: str | os.PathLike, **options):
    """Open a recording for replay; raises EventError naming the file when nothing can read it."""
    path = os.fspath(uri)
    if path.startswith("file://"):
        path = path[len("file://"):]
    if not os.path.exists(path):
        raise EventError(f"{path}: no such file")
    if os.path.isdir(path):
        raise EventError(f"{path}: is a directory, not a recording")
    if not os.path.isfile(path):  # a FIFO, socket or device: opening one may block forever, seeking fails
        raise EventError(f"{path}: not a regular file (a pipe, socket or device); save the stream to a file first")
    with open(path, "rb") as f:
        head = f.read(4096)
    if not head:
        raise EventError(f"{path}: empty file")
    if options.get("geometry") is not None:  # (width, height) or "WxH" work for every reader
        options["geometry"] = as_geometry(options["geometry"])
    for fmt in _formats():
        if fmt.probe(head, path):
            return fmt.open(path, **options)
    if head.startswith(b"PK\x03\x04") and not zipfile.is_zipfile(path):  # an .npz cut short: say so
        raise EventError(f"{path}: truncated or corrupt zip (.npz): no zip directory before the file ends at "
                         f"byte {os.path.getsize(path)}")
    known = ", ".join(fmt.NAME for fmt in _formats())
    raise EventError(f"{path}: unrecognised format (first bytes {head[:8]!r}); readable formats: {known}")


__all__ = ["FORMATS", "EventWarning", "open_source"]
