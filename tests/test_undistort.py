"""Undistortion: the camera models against OpenCV's undistortPoints (cv2.fisheye's for equidistant), the
lookup table against plain Python, ROS camera_info reading, and the stage with the invariant kit."""

from __future__ import annotations

import re
from pathlib import Path

import cv2  # opencv-python-headless, a dev dependency: the reference for the camera models (missing: a failure)
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evstream.camera import CameraModel, from_camera_info
from evstream.events import Geometry, concat
from evstream.pipeline import Pipeline, build
from evstream.testing import (
    assert_bounded_state,
    assert_cameras_independent,
    assert_chunk_invariant,
    random_stream,
)
from evstream.transforms.undistort import lookup_table, undistort_kernel, unpack

DAVIS = Geometry(346, 260)
CAMERAS = {
    "plumb_bob": CameraModel(310.0, 305.0, 170.5, 128.2, "plumb_bob", (-0.32, 0.12, 0.0012, -0.0007, -0.015)),
    "plumb_bob_4": CameraModel(250.0, 252.0, 172.0, 131.0, "plumb_bob", (-0.2, 0.05, 0.0, 0.001)),
    "rational": CameraModel(300.0, 300.0, 173.0, 130.0, "rational_polynomial",
                            (0.4, -0.1, 0.001, 0.0005, 0.02, 0.7, -0.05, 0.03)),
    "rectified": CameraModel(310.0, 305.0, 170.5, 128.2, "plumb_bob", (-0.3, 0.1, 0.001, 0.0, 0.0),
                             R=cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0],
                             P=np.array([[280.0, 0, 160.0, 0], [0, 280.0, 125.0, 0], [0, 0, 1, 0]])),
    "equidistant": CameraModel(200.0, 201.0, 172.0, 129.0, "equidistant", (0.05, -0.01, 0.003, -0.0005)),
}


def opencv(camera: CameraModel, u, v):
    pts = np.stack([u, v], axis=1).astype(np.float64)[:, None, :]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    if camera.fisheye:
        out = cv2.fisheye.undistortPoints(pts, camera.K, np.array(camera.coefficients), R=camera.R, P=camera.P,
                                          criteria=crit)
    else:
        out = cv2.undistortPoints(pts, camera.K, np.array(camera.coefficients), R=camera.R, P=camera.P, criteria=crit)
    return out[:, 0, 0], out[:, 0, 1]


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_points_match_opencv(name):
    camera = CAMERAS[name]
    v, u = np.divmod(np.arange(DAVIS.n_pixels, dtype=np.float64), DAVIS.width)
    ux, uy = camera.undistort_points(u, v)
    ox, oy = opencv(camera, u, v)
    ok = np.isfinite(ux)
    assert ok.mean() > 0.99
    np.testing.assert_allclose(ux[ok], ox[ok], atol=1e-4)
    np.testing.assert_allclose(uy[ok], oy[ok], atol=1e-4)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_lookup_table_is_opencvs_nearest_pixel(name):
    camera = CAMERAS[name]
    lut_x, lut_y = unpack(lookup_table(camera, DAVIS))
    v, u = np.divmod(np.arange(DAVIS.n_pixels, dtype=np.float64), DAVIS.width)
    ox, oy = opencv(camera, u, v)
    rx, ry = np.rint(ox), np.rint(oy)
    inside = (rx >= 0) & (rx < DAVIS.width) & (ry >= 0) & (ry < DAVIS.height)
    # away from a rounding tie or the border, our table and OpenCV's points agree exactly
    clear = (np.abs(ox - np.floor(ox) - 0.5) > 1e-3) & (np.abs(oy - np.floor(oy) - 0.5) > 1e-3)
    assert clear.mean() > 0.99
    assert np.array_equal(lut_x[clear], np.where(inside, rx, -1)[clear].astype(np.int32))
    assert np.array_equal(lut_y[clear], np.where(inside, ry, -1)[clear].astype(np.int32))
    assert 0 < (lut_x < 0).sum() < DAVIS.n_pixels // 2  # a distorted camera loses some border pixels


def test_forward_model_round_trips():
    for camera in CAMERAS.values():
        if not np.allclose(camera.R, np.eye(3)) or not np.allclose(camera.P, camera.K):
            continue
        x, y = np.meshgrid(np.linspace(-0.5, 0.5, 11), np.linspace(-0.4, 0.4, 9))
        u, v = camera.distort_points(x.ravel(), y.ravel())
        ux, uy = camera.undistort_points(u, v)
        np.testing.assert_allclose(ux, camera.fx * x.ravel() + camera.cx, atol=1e-6)
        np.testing.assert_allclose(uy, camera.fy * y.ravel() + camera.cy, atol=1e-6)


# -- the kernel against plain Python --------------------------------------------------------------
@settings(max_examples=2 * settings().max_examples)  # cheap examples: twice the profile
@given(st.integers(0, 2**32 - 1), st.integers(0, 300))
def test_kernel_matches_plain_python(seed, n):
    rng = np.random.default_rng(seed)
    w, h = 11, 7
    lut_x = np.where(rng.random(w * h) < 0.2, -1, rng.integers(0, w, w * h))
    lut_y = np.where(lut_x < 0, -1, rng.integers(0, h, w * h))
    lut = np.where(lut_x < 0, -1, lut_x | (lut_y << 16)).astype(np.int32)
    t = np.sort(rng.integers(0, 10**6, n)).astype(np.int64)
    x, y = rng.integers(0, w, n).astype(np.uint16), rng.integers(0, h, n).astype(np.uint16)
    p = rng.integers(0, 2, n).astype(np.uint8)
    out = (np.empty(n + 1, np.int64), np.empty(n + 1, np.uint16), np.empty(n + 1, np.uint16),
           np.empty(n + 1, np.uint8), np.empty(n + 1, np.intp))
    k = undistort_kernel(t, x, y, p, w, lut, *out)
    ref = [(int(t[i]), int(lut_x[y[i] * w + x[i]]), int(lut_y[y[i] * w + x[i]]), int(p[i]), i) for i in range(n)
           if lut_x[y[i] * w + x[i]] >= 0]
    assert list(zip(*(a[:k].tolist() for a in out))) == ref


# -- camera_info and the stage --------------------------------------------------------------------
CAMERA_INFO = """\
image_width: 346
image_height: 260
camera_name: davis
camera_matrix:
  rows: 3
  cols: 3
  data: [310.0, 0.0, 170.5,
         0.0, 305.0, 128.2, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.32, 0.12, 0.0012, -0.0007, -0.015]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [310.0, 0.0, 170.5, 0.0, 0.0, 305.0, 128.2, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


def test_camera_info_yaml(tmp_path):
    path = tmp_path / "davis.yaml"
    path.write_text(CAMERA_INFO)
    cam = from_camera_info(path)
    ref = CAMERAS["plumb_bob"]
    assert (cam.width, cam.height, cam.model) == (346, 260, "plumb_bob")
    assert np.array_equal(cam.K, ref.K) and cam.coefficients == ref.coefficients
    s = random_stream(2, 3000, DAVIS)
    a = build("stage", {"kind": "undistort", "camera_info": str(path)})(s)
    b = build("stage", {"kind": "undistort", "fx": 310.0, "fy": 305.0, "cx": 170.5, "cy": 128.2,
                        "distortion": [-0.32, 0.12, 0.0012, -0.0007, -0.015]})(s)
    assert np.array_equal(a.to_structured(), b.to_structured()) and 0 < len(a) < len(s)
    lut_x, lut_y = unpack(lookup_table(ref, DAVIS))
    f = s.y.astype(int) * DAVIS.width + s.x
    kept = lut_x[f] >= 0
    assert np.array_equal(a.x, lut_x[f][kept]) and np.array_equal(a.t, s.t[kept])


def test_bad_calibrations_are_one_line_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("camera_matrix: [1, 2\n")
    with pytest.raises(ValueError, match="bad.yaml: not valid YAML"):
        from_camera_info(bad)
    bad.write_text(CAMERA_INFO.replace("cols: 5\n  data: [-0.32, 0.12,", "cols: 5\n  data: ["))
    with pytest.raises(ValueError, match="bad.yaml: distortion_coefficients has 3 numbers"):
        from_camera_info(bad)
    bad.write_text(CAMERA_INFO.replace("plumb_bob", "kannala"))
    with pytest.raises(ValueError, match="unknown distortion model 'kannala'"):
        from_camera_info(bad)
    with pytest.raises(ValueError, match="needs camera_info"):
        build("stage", {"kind": "undistort", "fx": 1.0})
    other = tmp_path / "vga.yaml"
    other.write_text(CAMERA_INFO.replace("image_width: 346", "image_width: 640"))
    with pytest.raises(ValueError, match="^" + re.escape(f"undistort: the camera ({other}) was calibrated at "
                                                         "640x260, the events come from a 346x260 sensor") + "$"):
        build("stage", {"kind": "undistort", "camera_info": str(other)})(random_stream(1, 10, DAVIS))


def test_a_binary_file_as_camera_info_is_one_line(tmp_path):
    """A recording given as camera_info said Python's "'utf-8' codec can't decode byte 0x93 in position 0"."""
    rec = tmp_path / "rec.npy"
    np.save(rec, np.arange(4))
    with pytest.raises(ValueError, match="^" + re.escape(f"{rec}: not a ROS camera_info file (not UTF-8 text: byte "
                                                         "0x93 at offset 0)") + "$"):
        from_camera_info(rec)


def undistorter():
    return build("stage", {"kind": "undistort", "fx": 20.0, "fy": 20.0, "cx": 12.0, "cy": 9.0,
                           "distortion": [-0.4, 0.15, 0.001, 0.002, 0.0]})


def test_invariant_kit():
    s = random_stream(5, 800)

    def outputs(stage, chunks):
        return concat([stage(c) for c in chunks], s.geometry).to_structured()

    assert_chunk_invariant(undistorter, s, 1, apply=outputs)
    assert_bounded_state(undistorter, lambda n: random_stream(3, n), n=1500)
    assert_cameras_independent(undistorter, [random_stream(k, 300) for k in range(3)], 2)
    out = outputs(undistorter(), [s])
    assert 0 < len(out) < len(s)


def test_in_a_toml_pipeline_before_a_framer(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text('[[stage]]\nkind = "undistort"\nfx = 20.0\nfy = 20.0\ncx = 12.0\ncy = 9.0\n'
                 'distortion = [-0.4, 0.15, 0.001, 0.002, 0.0]\n[framer]\nkind = "timesurface"\n')
    pipe = Pipeline.from_toml(p)
    stats = pipe.run([random_stream(1, 2000)])
    assert stats.events_dropped > 0 and stats.frames > 0


@pytest.mark.parametrize("what, said", [("missing.yaml", "no such camera_info file"),
                                        (".", "is a folder, not a camera_info file")])
def test_a_missing_or_folder_camera_info_is_one_line_naming_the_flag(tmp_path, capsys, what, said):
    """Was `evstream: error: [Errno 2] No such file or directory: 'missing.yaml'` (and `[Errno 21] Is a
    directory`), exit 1, while a bad YAML there said `--set camera_info=...: ...`, exit 2."""
    from evstream.cli import main

    path = tmp_path / what
    bar = Path(__file__).resolve().parents[1] / "recordings" / "bar.npz"
    assert main(["replay", str(bar), "--denoise", "undistort", "--set", f"camera_info={path}",
                 "--save", str(tmp_path / "u.rrd")]) == 2
    assert capsys.readouterr().err == f"evstream: error: --set camera_info={path}: {path}: {said}\n"
    with pytest.raises(ValueError, match=f"^{path}: {said}$"):
        from_camera_info(path)
