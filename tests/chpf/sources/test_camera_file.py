"""Camera files for chpf-track --camera: each accepted layout, and the refusals."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from chpf.errors import ImageSizeError, SourceError
from chpf.sources.camera import read_camera
from tests.helpers import DEMO_K


def _is_demo_camera(path) -> bool:
    """The file reads as the demo's K at 320x240."""
    cam = read_camera(path)
    return np.array_equal(cam.K, DEMO_K) and (cam.width, cam.height) == (320, 240)


def test_k_as_nested_json_and_as_nine_yaml_numbers(tmp_path):
    a = tmp_path / "cam.json"
    a.write_text(json.dumps({"K": DEMO_K.tolist(), "width": 320, "height": 240}))
    cam = read_camera(a)
    np.testing.assert_array_equal(cam.K, DEMO_K)
    assert (cam.width, cam.height, cam.depth_scale) == (320, 240, None)
    b = tmp_path / "cam.yaml"
    b.write_text("K: [" + ", ".join(f"{v:g}" for v in DEMO_K.ravel()) + "]\n")
    cam = read_camera(b)
    np.testing.assert_array_equal(cam.K, DEMO_K)
    assert cam.width is None


def test_fx_fy_cx_cy_as_in_bop_camera_json(tmp_path):
    path = tmp_path / "camera.json"
    path.write_text(
        json.dumps(
            {
                "fx": 500,
                "fy": 510,
                "cx": 319.5,
                "cy": 239.5,
                "width": 640,
                "height": 480,
                "depth_scale": 0.1,
            }
        )
    )
    cam = read_camera(path)
    np.testing.assert_array_equal(
        cam.K, [[500.0, 0.0, 319.5], [0.0, 510.0, 239.5], [0.0, 0.0, 1.0]]
    )
    assert (cam.width, cam.height, cam.depth_scale) == (640, 480, 0.1)


def test_ros_camera_info_yaml(tmp_path):
    path = tmp_path / "ost.yaml"
    path.write_text(
        "image_width: 320\nimage_height: 240\ncamera_name: cam\ncamera_matrix:\n  rows: 3\n"
        "  cols: 3\n  data: [300, 0, 159.5, 0, 300, 119.5, 0, 0, 1]\n"
        "distortion_model: plumb_bob\n"
    )
    assert _is_demo_camera(path)


def test_opencv_calibration_yaml_written_by_filestorage(tmp_path):
    path = tmp_path / "calib.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 320)
    fs.write("image_height", 240)
    fs.write("camera_matrix", DEMO_K)
    fs.write("distortion_coefficients", np.zeros((1, 5)))
    fs.release()
    assert path.read_text().startswith("%YAML")  # OpenCV 5 writes "%YAML 1.2"
    assert _is_demo_camera(path)


def test_opencv_calibration_yaml_of_older_opencv(tmp_path):
    """The "%YAML:1.0" files of OpenCV's calibration sample (not YAML that PyYAML reads)."""
    path = tmp_path / "out_camera_data.yml"
    path.write_text(
        "%YAML:1.0\n---\nimage_width: 320\nimage_height: 240\n"
        "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        "   data: [ 3.0e+02, 0., 159.5, 0., 3.0e+02, 119.5, 0., 0., 1. ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n"
        "   data: [ 0., 0., 0., 0., 0. ]\n"
    )
    assert _is_demo_camera(path)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('{"focal": 300}', "unknown camera file layout"),
        ("[1, 2, 3]", "unknown camera file layout"),
        ('{"K": [1, 2, 3, 4, 5, 6, 7, 8]}', "9 numbers"),
        ('{"K": [0, 0, 1, 0, 300, 1, 0, 0, 1]}', "positive focals"),
        ('{"fx": 1, "fy": 1, "cx": 1, "cy": 1, "width": 320}', "not both"),
        ("K: [1, 2\n  nope: {", "neither JSON nor YAML"),
    ],
)
def test_bad_camera_files_name_the_file(tmp_path, text, needle):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(SourceError, match=needle) as err:
        read_camera(path)
    assert str(err.value).startswith(str(path))
    with pytest.raises(SourceError, match="not found"):
        read_camera(tmp_path / "none.json")


def test_size_check_against_the_frames(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({"K": DEMO_K.tolist(), "width": 640, "height": 480}))
    cam = read_camera(path)
    with pytest.raises(SourceError, match=r"says 640x480 but the frames of .*frames are 320x240"):
        cam.check_size(320, 240, tmp_path / "frames")
    path.write_text(json.dumps({"K": DEMO_K.tolist()}))  # no size: the principal point decides
    read_camera(path).check_size(320, 240, tmp_path / "frames")
    with pytest.raises(ImageSizeError, match=r"cam\.json: frames of"):
        read_camera(path).check_size(640, 480, tmp_path / "frames")
