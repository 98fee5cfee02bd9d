"""Camera models for undistortion: pinhole with radial-tangential distortion (ROS `plumb_bob`, 4 or 5
coefficients k1 k2 p1 p2 [k3]; `rational_polynomial`, 8: k1 k2 p1 p2 k3 k4 k5 k6) and the equidistant
fisheye model (ROS `equidistant`, OpenCV `cv::fisheye`: k1 k2 k3 k4), read from a ROS `camera_info`
YAML file or given as OpenCV-style intrinsics (fx, fy, cx, cy, coefficients).

`undistort_points(u, v)` maps distorted pixels to undistorted ones the way OpenCV's `undistortPoints`
(`cv::fisheye::undistortPoints`) does with R and P: normalise with K, invert the distortion, rotate by
R (rectification; identity by default), project with P (the camera_info's projection, else K). The
inversion iterates to convergence (1e-12 in normalised units, at most 100 steps) where OpenCV's
default stops after 5; points where it does not converge, or that the fisheye model sends past 90°,
come back as NaN.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .events import shown

PINHOLE_MODELS = {"plumb_bob": (4, 5), "radtan": (4, 5), "radial-tangential": (4, 5), "rational_polynomial": (8,)}
FISHEYE_MODELS = ("equidistant", "fisheye")
MAX_STEPS = 100
TOLERANCE = 1e-12


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics K (fx, fy, cx, cy), distortion `model` and `coefficients`, rectification R (3×3),
    projection P (3×3, the left part of ROS's 3×4 P), and the image size the calibration is for."""

    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "plumb_bob"
    coefficients: tuple = ()
    width: int | None = None
    height: int | None = None
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    P: np.ndarray | None = None

    def __post_init__(self):
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not np.isfinite(v):
                raise ValueError(f"camera: {name} must be a finite number, got {shown(v)}")
            object.__setattr__(self, name, float(v))
        if self.fx == 0 or self.fy == 0:
            raise ValueError("camera: fx and fy must not be 0")
        d = tuple(float(c) for c in self.coefficients)
        if not all(np.isfinite(d)):
            raise ValueError(f"camera: distortion coefficients must be finite, got {list(d)}")
        if self.model in PINHOLE_MODELS:
            if len(d) == 0:
                d = (0.0,) * 5
            if len(d) not in PINHOLE_MODELS[self.model] and not (self.model == "plumb_bob" and len(d) == 8):
                counts = " or ".join(map(str, PINHOLE_MODELS[self.model]))
                raise ValueError(f"camera: the {self.model} model takes {counts} coefficients, got {len(d)}")
            d = d + (0.0,) * (8 - len(d))
        elif self.model in FISHEYE_MODELS:
            if len(d) not in (0, 4):
                raise ValueError(f"camera: the {self.model} model takes 4 coefficients (k1..k4), got {len(d)}")
            d = d or (0.0,) * 4
        else:
            raise ValueError(f"camera: unknown distortion model {self.model!r}; known: "
                             f"{', '.join([*PINHOLE_MODELS, *FISHEYE_MODELS])}")
        object.__setattr__(self, "coefficients", d)
        R = np.asarray(self.R, np.float64)
        if R.shape != (3, 3) or not np.isfinite(R).all():
            raise ValueError("camera: R must be a finite 3x3 matrix")
        object.__setattr__(self, "R", R)
        P = self.K if self.P is None else np.asarray(self.P, np.float64)
        if P.shape == (3, 4):
            P = P[:, :3]
        if P.shape == (3, 3) and P[2, 2] == 0:  # an uncalibrated camera_info's all-zero P: project with K
            P = self.K
        if P.shape != (3, 3) or not np.isfinite(P).all():
            raise ValueError("camera: P must be a finite 3x3 or 3x4 matrix")
        object.__setattr__(self, "P", P)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], np.float64)

    @property
    def fisheye(self) -> bool:
        return self.model in FISHEYE_MODELS

    # -- the math ----------------------------------------------------------------------------------
    def undistort_points(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted pixel coordinates (float64) of distorted pixels (u, v); NaN where none."""
        xd = (np.asarray(u, np.float64) - self.cx) / self.fx
        yd = (np.asarray(v, np.float64) - self.cy) / self.fy
        x, y = _invert_fisheye(xd, yd, self.coefficients) if self.fisheye else _invert_radtan(xd, yd, self.coefficients)
        w = np.ones_like(x)
        M = self.P @ self.R
        X = M[0, 0] * x + M[0, 1] * y + M[0, 2] * w
        Y = M[1, 0] * x + M[1, 1] * y + M[1, 2] * w
        Z = M[2, 0] * x + M[2, 1] * y + M[2, 2] * w
        with np.errstate(divide="ignore", invalid="ignore"):
            return X / Z, Y / Z

    def distort_points(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """The forward model from normalised undistorted coordinates to distorted pixels (for tests)."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        if self.fisheye:
            k1, k2, k3, k4 = self.coefficients
            r = np.hypot(x, y)
            th = np.arctan(r)
            thd = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
            s = np.where(r > 0, thd / np.where(r > 0, r, 1), 1.0)
            xd, yd = x * s, y * s
        else:
            xd, yd = _distort_radtan(x, y, self.coefficients)
        return self.fx * xd + self.cx, self.fy * yd + self.cy


def _distort_radtan(x, y, d):
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def _invert_radtan(xd, yd, d):
    """Fixed-point inversion as OpenCV's (x = (x_d − tangential(x)) / radial(x)), run to convergence;
    NaN where it does not converge."""
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    x, y = xd.copy(), yd.copy()
    for _ in range(MAX_STEPS):
        r2 = x * x + y * y
        icdist = (1 + r2 * (k4 + r2 * (k5 + r2 * k6))) / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        nx, ny = (xd - dx) * icdist, (yd - dy) * icdist
        step = np.maximum(np.abs(nx - x), np.abs(ny - y))
        x, y = nx, ny
        if not np.any(step > TOLERANCE):
            break
    ex, ey = _distort_radtan(x, y, d)
    bad = ~(np.hypot(ex - xd, ey - yd) < 1e-9) | (icdist <= 0)
    return np.where(bad, np.nan, x), np.where(bad, np.nan, y)


def _invert_fisheye(xd, yd, d):
    """Newton on θ_d = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸), as cv::fisheye::undistortPoints; NaN past 90°."""
    k1, k2, k3, k4 = d
    thd = np.hypot(xd, yd)
    th = np.clip(thd, -np.pi / 2, np.pi / 2)
    for _ in range(MAX_STEPS):
        t2 = th * th
        f = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - thd
        df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + 9 * t2 * k4)))
        step = f / df
        th = th - step
        if not np.any(np.abs(step) > TOLERANCE):
            break
    ok = (np.abs(step) <= 1e-9) & (th >= 0) & (th < np.pi / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(thd > 1e-12, np.tan(th) / thd, 1.0)
    return np.where(ok, xd * s, np.nan), np.where(ok, yd * s, np.nan)


# -- reading ------------------------------------------------------------------------------------------
def _matrix(doc: dict, key: str, rows: int, cols: int | tuple, where: str):
    m = doc.get(key)
    if m is None:
        return None
    data = m.get("data") if isinstance(m, dict) else m
    try:
        a = np.asarray(data, np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {key} is not a list of numbers") from None
    for c in (cols if isinstance(cols, tuple) else (cols,)):
        if a.size == rows * c:
            return a.reshape(rows, c)
    raise ValueError(f"{where}: {key} has {a.size} numbers, a {rows}x{cols} matrix needs {rows * cols}")


def from_camera_info(path: str | os.PathLike) -> CameraModel:
    """A ROS camera_info YAML file (camera_calibration's / camera_info_manager's format)."""
    import yaml

    where = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            doc = yaml.safe_load(f)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise ValueError(f"{where}: not valid YAML{at}: {getattr(e, 'problem', e)}") from None
    except IsADirectoryError:  # a parameter's value, as a bad YAML is (the command line's --set: exit 2)
        raise ValueError(f"{where}: is a folder, not a camera_info file") from None
    except FileNotFoundError:
        raise ValueError(f"{where}: no such camera_info file") from None
    except UnicodeDecodeError as e:  # a binary file given by mistake (a recording, a .npz); was Python's codec line
        raise ValueError(f"{where}: not a ROS camera_info file (not UTF-8 text: byte 0x{e.object[e.start]:02x} at "
                         f"offset {e.start})") from None
    if not isinstance(doc, dict) or "camera_matrix" not in doc:
        raise ValueError(f"{where}: not a ROS camera_info file (no camera_matrix)")
    K = _matrix(doc, "camera_matrix", 3, 3, where)
    D = _matrix(doc, "distortion_coefficients", 1, (4, 5, 8, 0), where)
    R = _matrix(doc, "rectification_matrix", 3, 3, where)
    P = _matrix(doc, "projection_matrix", 3, 4, where)
    try:
        return CameraModel(
            fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], model=str(doc.get("distortion_model", "plumb_bob")),
            coefficients=tuple(D.ravel()) if D is not None else (), width=doc.get("image_width"),
            height=doc.get("image_height"), R=np.eye(3) if R is None else R, P=P,
        )
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
