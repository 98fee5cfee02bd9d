"""A learned denoiser's model file, `MODEL.npz`: weights, normalisation, operating points, provenance.

Arrays (no pickle, `allow_pickle=False` on load): `w1` (hidden × features; one row for a logistic
model), `b1`, `w2`, `b2` (the output layer; unused by a logistic model), `mean` and `std` (feature
standardisation), `keep_grid` and `threshold_grid` (the score threshold that keeps each fraction of the
signal, calibrated on recordings the scoring model was not fitted on), and `meta`, a JSON string:
feature names and version, kind, hidden units, default keep, and what the model was trained on
(recording names and sha256, noise conditions, training metrics).
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...events import shown
from ...safe_write import AtomicOutput
from .features import FEATURE_VERSION, FEATURES, N_FEATURES

DEFAULT_MODEL = Path(__file__).with_name("default_model.npz")
ARRAYS = ("w1", "b1", "w2", "b2", "mean", "std", "keep_grid", "threshold_grid")


class ModelError(ValueError):
    """A model file that cannot be used (one line: the file and the reason)."""


@dataclass
class Model:
    """Weights on standardised features; `score(f) = w2 · relu(w1 f' + b1) + b2` (MLP) or
    `w1[0] · f' + b1[0]` (logistic), f' = (f - mean) / std. Higher = more signal-like."""

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: float
    mean: np.ndarray
    std: np.ndarray
    keep_grid: np.ndarray
    threshold_grid: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def n_hidden(self) -> int:
        return 0 if self.meta.get("kind", "logistic") == "logistic" else int(self.w1.shape[0])

    @property
    def keep(self) -> float:
        return float(self.meta.get("keep", 0.85))

    def threshold(self, keep: float | None = None) -> float:
        """The score threshold expected to keep the fraction `keep` of the signal (interpolated)."""
        k = self.keep if keep is None else float(keep)
        if not 0 < k <= 1:
            raise ValueError(f"keep must be in (0, 1], got {shown(keep)}")
        low, high = float(np.min(self.keep_grid)), float(np.max(self.keep_grid))
        if low < high and not low - 1e-9 <= k <= high + 1e-9:  # np.interp would clamp without a word
            raise ValueError(f"keep {k:g} is outside what this model was calibrated for ({low:g} to {high:g})")
        order = np.argsort(self.keep_grid)
        return float(np.interp(k, self.keep_grid[order], self.threshold_grid[order]))

    def folded(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """(w1, b1, w2, b2) acting on raw features: the standardisation folded into the first layer."""
        w1 = self.w1 / self.std[None, :]
        b1 = self.b1 - w1 @ self.mean
        return (np.ascontiguousarray(w1, np.float64), np.ascontiguousarray(b1, np.float64),
                np.ascontiguousarray(self.w2, np.float64), float(self.b2))

    def score(self, feats: np.ndarray) -> np.ndarray:
        """Scores of a feature matrix (numpy; the stage scores inside its kernel)."""
        z = (feats - self.mean) / self.std
        h = z @ self.w1.T + self.b1
        if self.n_hidden == 0:
            return h[:, 0]
        return np.maximum(h, 0.0) @ self.w2 + self.b2

    def save(self, path) -> None:
        """Write to `path` through a temporary file beside it (a failed write leaves the old file;
        evstream.safe_write)."""
        path = Path(path)
        buf = io.BytesIO()
        arrays = {k: np.asarray(getattr(self, k), np.float64) for k in ARRAYS if k != "b2"}
        arrays["b2"] = np.array([self.b2], np.float64)
        arrays["meta"] = np.array(json.dumps(self.meta, sort_keys=True))
        np.savez(buf, **arrays)
        data = _deterministic_zip(buf.getvalue())
        with AtomicOutput(path) as part:  # a read-only folder or a full disk: one line naming `path`
            Path(part).write_bytes(data)


def _deterministic_zip(data: bytes) -> bytes:
    """The same archive with fixed member timestamps, so that the same model gives the same bytes."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as dst:
        for name in sorted(src.namelist()):
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            dst.writestr(info, src.read(name))
    return out.getvalue()


def load(path=None) -> Model:
    """Read a model file (default: the shipped one). A damaged file, or one of another feature
    version, is a `ModelError` naming the file and the reason."""
    path = Path(path) if path is not None else DEFAULT_MODEL
    try:
        with open(path, "rb") as f:
            if f.read(4) != b"PK\x03\x04":  # numpy would call anything else "pickled data"
                raise ModelError(f"{path}: not an evstream model file (not an .npz archive)")
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in (*ARRAYS, "meta") if k not in z.files]
            if missing:
                raise ModelError(f"{path}: not an evstream model file (missing {', '.join(missing)})")
            arrays = {k: np.asarray(z[k], np.float64) for k in ARRAYS}
            meta = json.loads(str(z["meta"]))
    except ModelError:
        raise
    except FileNotFoundError:
        raise ModelError(f"{path}: no such model file") from None
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as e:
        raise ModelError(f"{path}: not a readable evstream model file ({type(e).__name__}: {e})") from None
    version = meta.get("feature_version")
    if version != FEATURE_VERSION:
        raise ModelError(f"{path}: made for feature version {version}, this evstream computes version "
                         f"{FEATURE_VERSION}: retrain it with `evstream train`")
    if list(meta.get("features", [])) != list(FEATURES):
        raise ModelError(f"{path}: its feature list differs from this evstream's ({', '.join(FEATURES)})")
    w1 = arrays["w1"]
    hidden = w1.shape[0] if w1.ndim == 2 else -1
    shapes_ok = (w1.ndim == 2 and w1.shape[1] == N_FEATURES and arrays["b1"].shape == (hidden,)
                 and arrays["mean"].shape == (N_FEATURES,) and arrays["std"].shape == (N_FEATURES,)
                 and arrays["b2"].shape == (1,) and arrays["keep_grid"].shape == arrays["threshold_grid"].shape
                 and arrays["keep_grid"].ndim == 1 and len(arrays["keep_grid"]) >= 1)
    if meta.get("kind") == "mlp":
        shapes_ok = shapes_ok and arrays["w2"].shape == (hidden,)
    elif meta.get("kind") == "logistic":
        shapes_ok = shapes_ok and hidden == 1
    else:
        raise ModelError(f"{path}: unknown model kind {meta.get('kind')!r} (logistic or mlp)")
    if not shapes_ok:
        raise ModelError(f"{path}: array shapes do not fit a {meta.get('kind')} model of {N_FEATURES} features")
    if not all(np.isfinite(a).all() for a in arrays.values()) or not (arrays["std"] > 0).all():
        raise ModelError(f"{path}: weights or normalisation not finite (std must be > 0)")
    b2 = float(arrays.pop("b2")[0])
    model = Model(b2=b2, meta=meta, **arrays)
    if math.isnan(model.threshold()):
        raise ModelError(f"{path}: no usable operating point")
    return model
