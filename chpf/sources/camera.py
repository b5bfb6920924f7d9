"""Camera files for ``--camera``: the intrinsics K and, optionally, the image size.

Accepted layouts (JSON or YAML; the format is told by the content, not the suffix):

- ``K``: a 3x3 nested list or 9 numbers, row-major (``cam_K`` too, as in BOP's
  scene_camera.json);
- ``fx``, ``fy``, ``cx``, ``cy`` (as in BOP's camera.json);
- ``camera_matrix`` with ``rows``, ``cols``, ``data`` (ROS camera_info YAML), or OpenCV's
  calibration YAML (``%YAML:1.0`` header, ``camera_matrix: !!opencv-matrix``), read with
  ``cv2.FileStorage``.

Optional: ``width`` / ``height`` (or ``image_width`` / ``image_height``) in pixels, checked
against the frames, and ``depth_scale`` (mm per depth unit, as BOP's). Distortion coefficients
are not used: give undistorted frames.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from chpf.errors import ImageSizeError, SourceError
from chpf.geometry import check_image_size

LAYOUTS = "K (3x3 or 9 numbers), fx/fy/cx/cy, or camera_matrix (rows, cols, data)"


@dataclass(frozen=True)
class Camera:
    """Intrinsics read from ``path``: K (3,3) pixels; width, height pixels or None;
    depth_scale mm per depth unit or None."""

    path: Path
    K: np.ndarray
    width: int | None = None
    height: int | None = None
    depth_scale: float | None = None

    def check_size(self, width: int, height: int, frames: Path) -> None:
        """SourceError when the file's size differs from the frames' (``frames`` names them);
        ImageSizeError when the principal point does not fit a ``width`` x ``height`` image."""
        if self.width is not None and (self.width, self.height) != (width, height):
            raise SourceError(
                f"{self.path}: camera file says {self.width}x{self.height} but the frames of "
                f"{frames} are {width}x{height}"
            )
        try:
            check_image_size(width, height, self.K)
        except ImageSizeError as err:
            raise ImageSizeError(f"{self.path}: frames of {frames}: {err}") from None


def read_camera(path: str | Path) -> Camera:
    """The Camera of a camera file (layouts: module docstring); SourceError naming the file when
    it is missing, unreadable, of an unknown layout or holds an invalid K."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SourceError(f"{path}: camera file not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise SourceError(f"{path}: cannot read the camera file ({err})") from None
    data = _opencv_yaml(path) if text.lstrip().startswith("%YAML") else _json_or_yaml(path, text)
    if not isinstance(data, dict):
        raise SourceError(f"{path}: unknown camera file layout (expected a mapping with {LAYOUTS})")
    K = _intrinsics(data, path)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise SourceError(f"{path}: K must be a finite 3x3 matrix with positive focals, got {K}")
    width = _first(data, ("width", "image_width"))
    height = _first(data, ("height", "image_height"))
    if (width is None) != (height is None):
        raise SourceError(f"{path}: gives the image width or height but not both")
    size = None if width is None else (_positive_int(width, path), _positive_int(height, path))
    scale = data.get("depth_scale")
    if scale is not None and not (_is_number(scale) and scale > 0):
        raise SourceError(f"{path}: depth_scale must be a number > 0 (mm per unit), got {scale!r}")
    return Camera(
        path,
        K,
        None if size is None else size[0],
        None if size is None else size[1],
        None if scale is None else float(scale),
    )


def _json_or_yaml(path: Path, text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        pass
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        raise SourceError(f"{path}: camera file is neither JSON nor YAML") from None


def _opencv_yaml(path: Path) -> dict[str, Any]:
    """The entries of an OpenCV FileStorage YAML as plain values (matrices as arrays)."""
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error:
        raise SourceError(f"{path}: not a readable OpenCV YAML file") from None
    try:
        if not fs.isOpened():
            raise SourceError(f"{path}: not a readable OpenCV YAML file")
        out: dict[str, Any] = {}
        root = fs.root()
        for key in root.keys():
            node = fs.getNode(key)
            if node.isMap() and not node.getNode("data").empty():
                out[key] = node.mat()
            elif node.isReal() or node.isInt():
                out[key] = node.real()
        return out
    finally:
        fs.release()


def _first(data: dict[str, Any], keys: tuple[str, ...]) -> Any:
    return next((data[k] for k in keys if data.get(k) is not None), None)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.number)) and not isinstance(v, bool) and np.isfinite(v)


def _positive_int(v: Any, path: Path) -> int:
    if not (_is_number(v) and float(v).is_integer() and v > 0):
        raise SourceError(f"{path}: image width and height must be positive integers, got {v!r}")
    return int(v)


def _matrix(value: Any, path: Path, key: str) -> np.ndarray:
    """A 3x3 float matrix from nested lists, 9 numbers, an array or {rows, cols, data}."""
    if isinstance(value, dict):
        rows, cols = value.get("rows"), value.get("cols")
        if (rows, cols) != (3, 3):
            raise SourceError(f"{path}: {key} must have rows: 3 and cols: 3, got {rows}x{cols}")
        value = value.get("data")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SourceError(f"{path}: {key} must hold 9 numbers") from None
    if arr.size != 9:
        raise SourceError(f"{path}: {key} must hold 9 numbers (3x3), got {arr.size}")
    return arr.reshape(3, 3)


def _intrinsics(data: dict[str, Any], path: Path) -> np.ndarray:
    for key in ("K", "cam_K", "camera_matrix"):
        if data.get(key) is not None:
            return _matrix(data[key], path, key)
    if all(k in data for k in ("fx", "fy", "cx", "cy")):
        vals = [data[k] for k in ("fx", "fy", "cx", "cy")]
        if not all(_is_number(v) for v in vals):
            raise SourceError(f"{path}: fx, fy, cx, cy must be numbers")
        fx, fy, cx, cy = (float(v) for v in vals)
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    raise SourceError(f"{path}: unknown camera file layout (expected {LAYOUTS})")
