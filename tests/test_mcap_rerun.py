"""An archive with `--points --frames` as Rerun 0.41 and ROS 2 tools see it: `/tf_static` holds the
transforms that connect the point cloud's frame to a root (ROS 2 CDR, decoded by mcap_ros2), the points
carry their class colours, and the real web viewer (headless Chromium) draws them in its 3D view."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from evstream.sinks.colours import CLASS_COLOURS
from evstream.sinks.rerun_viewer import serve_file
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from evstream.chromium import CHROMIUM, HeadlessChromium, colour_counts, wait_until

ROOT = Path(__file__).resolve().parents[1]
TURNTABLE = ROOT / "recordings" / "turntable.npz"
VIEW_3D = (0.13, 0.06, 0.46, 0.74)  # the 3D view in Rerun's default layout for this archive (left column)
RENDER_TIMEOUT_S = 120.0


def archive(tmp_path: Path, *flags: str) -> Path:
    out = tmp_path / "a.mcap"
    subprocess.run([sys.executable, "-m", "evstream.cli", "archive", str(TURNTABLE), str(out), "--denoise", "truth",
                    "--keep-noise", *flags], check=True, capture_output=True, cwd=tmp_path)
    return out


def test_points_archive_has_static_transforms_and_class_colours(tmp_path):
    path = archive(tmp_path, "--points", "--frames")
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        tf = [decoded for *_, decoded in reader.iter_decoded_messages(topics=["/tf_static"])]
        f.seek(0)
        clouds = [PointCloud.FromString(m.data)
                  for _, _, m in make_reader(f).iter_messages(topics=["/camera/events/points"])]
    assert len(tf) == 1
    edges = [(t.header.frame_id, t.child_frame_id) for t in tf[0].transforms]
    assert edges == [("world", "camera"), ("camera", "camera_image_plane")]
    for t in tf[0].transforms:
        r = t.transform.rotation
        assert (r.x, r.y, r.z, r.w) == (0, 0, 0, 1) and t.transform.translation.x == 0
    assert clouds and all(c.frame_id == "camera" for c in clouds)
    fields = {fl.name: fl.offset for fl in clouds[0].fields}
    assert set(fields) == {"x", "y", "z", "class", "red", "green", "blue", "alpha"}
    raw = np.frombuffer(b"".join(c.data for c in clouds), np.uint8).reshape(-1, clouds[0].point_stride)
    cls = raw[:, fields["class"]]
    rgb = raw[:, [fields["red"], fields["green"], fields["blue"]]]
    assert set(np.unique(cls)) == {0, 1, 2}
    for c, colour in CLASS_COLOURS.items():
        assert (rgb[cls == int(c)] == colour).all()
    assert (raw[:, fields["alpha"]] == 255).all()


def test_points_archive_without_frames_has_only_the_world_transform(tmp_path):
    path = archive(tmp_path, "--points")
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        (*_, tf), = reader.iter_decoded_messages(topics=["/tf_static"])
    assert [(t.header.frame_id, t.child_frame_id) for t in tf.transforms] == [("world", "camera")]


@pytest.mark.skipif(CHROMIUM is None or shutil.which("bash") is None,
                    reason="no Chromium binary (apt-get install chromium)")
def test_rerun_web_viewer_draws_the_archived_point_cloud_in_class_colours(tmp_path):
    path = archive(tmp_path, "--points", "--frames")
    server, url = serve_file(path, log_dir=tmp_path)
    browser = None
    try:
        browser = HeadlessChromium(tmp_path / "profile", tmp_path / "chromium.log")
        session = browser.open(url, RENDER_TIMEOUT_S)
        png = tmp_path / "archive.png"
        colours = {c.name: rgb for c, rgb in CLASS_COLOURS.items()}
        # re-shot until drawn, each shot within the time left (a loaded machine draws a frame in minutes)
        drawn = wait_until(browser, session, png, lambda png: min(colour_counts(png, colours, VIEW_3D).values()) >= 100,
                           RENDER_TIMEOUT_S, alive=lambda: server.poll() is None)
        assert server.poll() is None, "the rerun server stopped"
        assert drawn, f"class colours in the 3D view: {colour_counts(png, colours, VIEW_3D)} (screenshot {png})"
    finally:
        if browser is not None:
            browser.close()
        server.terminate()
        server.wait(timeout=10)
