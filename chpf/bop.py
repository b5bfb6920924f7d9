"""Read and write BOP datasets as the BOP toolkit lays them out (real ``ycbv`` reads as it is).

Layout::

    ROOT/models/models_info.json, ROOT/models/obj_{obj_id:06d}.ply
    ROOT/{split}/{scene_id:06d}/scene_camera.json, scene_gt.json, scene_gt_info.json
    ROOT/{split}/{scene_id:06d}/rgb/{im_id:06d}.png|jpg      RGB (stored BGR by OpenCV)
    ROOT/{split}/{scene_id:06d}/depth/{im_id:06d}.png        uint16, depth_mm = raw * depth_scale
    ROOT/{split}/{scene_id:06d}/mask_visib/{im_id:06d}_{gt_idx:06d}.png   0/255 (also mask/)

Files hold millimetres; everything in memory is in metres. The conversion happens only here.
JSON keys are integer ids written as strings; writers sort them numerically and put one id per
line like the BOP toolkit's ``save_json``. All writes are atomic.

Errors: malformed or incomplete JSON -> ``BopFormatError``; missing files or folders ->
``DatasetError``; an image whose size disagrees with its camera or with the other images of the
same frame -> ``ImageSizeError``. Each message is one line naming the file.

Size rule: if a camera entry has ``width``/``height`` (not in ``ycbv``, allowed here) the image
must have exactly that size; in any case its size must be within 20 % of (2 cx + 1, 2 cy + 1)
(``chpf.geometry.check_image_size``), and the rgb, depth and mask images of one frame must have
the same size.

Results CSV and detections live in ``chpf.results`` and ``chpf.detections`` and are re-exported.
"""

from __future__ import annotations

import copy
import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from chpf.atomic import atomic_write_bytes, atomic_write_text
from chpf.detections import read_detections, write_detections
from chpf.errors import BopFormatError, DatasetError, ImageSizeError
from chpf.geometry import check_image_size
from chpf.results import ResultRow, ResultsAppender, read_results_csv, write_results_csv

__all__ = [
    "DETECTIONS_SIM",
    "MODELS_INFO",
    "SCENE_CAMERA",
    "SCENE_GT",
    "SCENE_GT_INFO",
    "SEQUENCES_INFO",
    "BopDataset",
    "BopScene",
    "CameraInfo",
    "GtInfo",
    "GtPose",
    "ModelInfo",
    "ResultRow",
    "ResultsAppender",
    "depth_path",
    "gt_info_from_masks",
    "mask_visib_path",
    "model_info_from_object",
    "model_path",
    "models_dir",
    "read_depth",
    "read_detections",
    "read_results_csv",
    "read_rgb",
    "rgb_path",
    "scene_dir",
    "write_depth",
    "write_detections",
    "write_mask",
    "write_models_info",
    "write_results_csv",
    "write_rgb",
    "write_scene_camera",
    "write_scene_gt",
    "write_scene_gt_info",
]

MM = 1000.0  # millimetres per metre
RGB_EXTS = (".png", ".jpg", ".jpeg")


# ----------------------------------------------------------------------------- records


@dataclass(eq=False)
class CameraInfo:
    """One image's camera. ``K`` (3,3) pixels; ``depth_scale`` mm per depth unit;
    ``R_w2c`` (3,3), ``t_w2c`` (3,) metres (optional); ``width``/``height`` px (optional)."""

    K: np.ndarray
    depth_scale: float = 1.0
    R_w2c: np.ndarray | None = None
    t_w2c: np.ndarray | None = None
    width: int | None = None
    height: int | None = None


@dataclass(eq=False)
class GtPose:
    """Ground-truth pose of one object instance: object-to-camera ``R`` (3,3), ``t`` (3,) metres."""

    obj_id: int
    R: np.ndarray
    t: np.ndarray


@dataclass
class GtInfo:
    """Per-instance statistics of ``scene_gt_info.json``; boxes are (x, y, w, h) pixels,
    (-1, -1, -1, -1) when empty."""

    bbox_obj: tuple[float, float, float, float]
    bbox_visib: tuple[float, float, float, float]
    px_count_all: int
    px_count_visib: int
    visib_fract: float
    px_count_valid: int = 0


@dataclass(eq=False)
class ModelInfo:
    """One entry of ``models_info.json`` in metres: ``diameter``; discrete symmetries (4,4) with
    translation in metres; continuous ones as ``dict(axis=(3,), offset=(3,) m)``; optional
    bounding box ``min_xyz`` (3,) and ``size_xyz`` (3,) metres."""

    obj_id: int
    diameter: float
    symmetries_discrete: list[np.ndarray] = field(default_factory=list)
    symmetries_continuous: list[dict[str, np.ndarray]] = field(default_factory=list)
    min_xyz: np.ndarray | None = None
    size_xyz: np.ndarray | None = None


# ----------------------------------------------------------------------------- paths

SCENE_CAMERA = "scene_camera.json"
SCENE_GT = "scene_gt.json"
SCENE_GT_INFO = "scene_gt_info.json"
MODELS_INFO = "models_info.json"
DETECTIONS_SIM = "detections_sim.json"
"""Boxes of the simulated detector, per scene and for the root (written by chpf-gen-data)."""
SEQUENCES_INFO = "sequences_info.json"
"""The settings a chpf-gen-data sequences root was made with."""


def models_dir(root: str | Path) -> Path:
    """``ROOT/models``."""
    return Path(root) / "models"


def model_path(root: str | Path, obj_id: int) -> Path:
    """``ROOT/models/obj_{obj_id:06d}.ply``."""
    return models_dir(root) / f"obj_{obj_id:06d}.ply"


def recorded_target_obj_id(root: str | Path) -> int:
    """The obj_id ``chpf-gen-data sequences`` gave its target object in the BOP root ``root``
    (its ``sequences_info.json``): a mesh file without a BOP name has obj_id 0 in its bundle and
    gets the first id after the built-ins' there."""
    info = json.loads((Path(root) / SEQUENCES_INFO).read_text(encoding="utf-8"))
    return int(next(o["obj_id"] for o in info["objects"] if o["role"] == "target"))


def scene_dir(root: str | Path, split: str, scene_id: int) -> Path:
    """``ROOT/{split}/{scene_id:06d}``."""
    return Path(root) / split / f"{scene_id:06d}"


def rgb_path(scene_path: str | Path, im_id: int, ext: str = ".png") -> Path:
    """``SCENE/rgb/{im_id:06d}{ext}``."""
    return Path(scene_path) / "rgb" / f"{im_id:06d}{ext}"


def depth_path(scene_path: str | Path, im_id: int) -> Path:
    """``SCENE/depth/{im_id:06d}.png``."""
    return Path(scene_path) / "depth" / f"{im_id:06d}.png"


def mask_visib_path(
    scene_path: str | Path, im_id: int, gt_idx: int, kind: str = "mask_visib"
) -> Path:
    """``SCENE/{kind}/{im_id:06d}_{gt_idx:06d}.png`` (``kind`` = mask_visib or mask)."""
    return Path(scene_path) / kind / f"{im_id:06d}_{gt_idx:06d}.png"


# ----------------------------------------------------------------------------- JSON parsing


def _load_json(path: Path) -> Any:
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise BopFormatError(f"{path}: invalid JSON ({err})") from None
    except OSError as err:
        raise DatasetError(f"{path}: cannot read ({err.strerror})") from None


def _id_dict(data: Any, path: Path, what: str) -> dict[int, Any]:
    """Top-level ``{"<int>": ...}`` -> ``{int: ...}`` sorted by id."""
    if not isinstance(data, dict):
        raise BopFormatError(f"{path}: expected a JSON object keyed by {what} id")
    out: dict[int, Any] = {}
    for key, value in data.items():
        try:
            out[int(key)] = value
        except ValueError:
            raise BopFormatError(f"{path}: key {key!r} is not an integer {what} id") from None
    return dict(sorted(out.items()))


def _is_num(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _nums(entry: dict, key: str, n: int, path: Path, where: str, required: bool = True):
    """``entry[key]`` as a float64 array of ``n`` finite numbers (None if absent and optional)."""
    if key not in entry:
        if required:
            raise BopFormatError(f"{path}: {where}: missing {key!r}")
        return None
    value = entry[key]
    if not isinstance(value, list) or len(value) != n or not all(_is_num(v) for v in value):
        got = f"{len(value)} items" if isinstance(value, list) else type(value).__name__
        raise BopFormatError(f"{path}: {where}: {key!r} must be a list of {n} numbers, got {got}")
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise BopFormatError(f"{path}: {where}: {key!r} has non-finite values")
    return arr


def _num(entry: dict, key: str, path: Path, where: str, default: float | None = None) -> float:
    if key not in entry:
        if default is None:
            raise BopFormatError(f"{path}: {where}: missing {key!r}")
        return default
    value = entry[key]
    if not _is_num(value) or not math.isfinite(value):
        raise BopFormatError(f"{path}: {where}: {key!r} must be a finite number, got {value!r}")
    return float(value)


def _int(entry: dict, key: str, path: Path, where: str, default: int | None = None) -> int:
    if key not in entry:
        if default is None:
            raise BopFormatError(f"{path}: {where}: missing {key!r}")
        return default
    value = entry[key]
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool):
        raise BopFormatError(f"{path}: {where}: {key!r} must be an integer, got {value!r}")
    return value


def _obj(value: Any, path: Path, where: str) -> dict:
    if not isinstance(value, dict):
        raise BopFormatError(f"{path}: {where}: expected a JSON object")
    return value


def read_scene_camera(path: str | Path) -> dict[int, CameraInfo]:
    """Parse ``scene_camera.json`` -> ``{im_id: CameraInfo}`` (metres)."""
    path = Path(path)
    cams: dict[int, CameraInfo] = {}
    for im_id, raw in _id_dict(_load_json(path), path, "image").items():
        where = f"image {im_id}"
        e = _obj(raw, path, where)
        K = _nums(e, "cam_K", 9, path, where).reshape(3, 3)
        scale = _num(e, "depth_scale", path, where, default=1.0)
        if scale <= 0:
            raise BopFormatError(f"{path}: {where}: 'depth_scale' must be positive, got {scale}")
        R = _nums(e, "cam_R_w2c", 9, path, where, required=False)
        t = _nums(e, "cam_t_w2c", 3, path, where, required=False)
        if (R is None) != (t is None):
            raise BopFormatError(f"{path}: {where}: 'cam_R_w2c' and 'cam_t_w2c' must come together")
        width = _int(e, "width", path, where, default=-1)
        height = _int(e, "height", path, where, default=-1)
        cams[im_id] = CameraInfo(
            K=K,
            depth_scale=scale,
            R_w2c=None if R is None else R.reshape(3, 3),
            t_w2c=None if t is None else t / MM,
            width=None if width < 0 else width,
            height=None if height < 0 else height,
        )
    return cams


def read_scene_gt(path: str | Path) -> dict[int, list[GtPose]]:
    """Parse ``scene_gt.json`` -> ``{im_id: [GtPose, ...]}`` (metres)."""
    path = Path(path)
    out: dict[int, list[GtPose]] = {}
    for im_id, raw in _id_dict(_load_json(path), path, "image").items():
        if not isinstance(raw, list):
            raise BopFormatError(f"{path}: image {im_id}: expected a list of instances")
        poses = []
        for k, inst in enumerate(raw):
            where = f"image {im_id} instance {k}"
            e = _obj(inst, path, where)
            R = _nums(e, "cam_R_m2c", 9, path, where).reshape(3, 3)
            t = _nums(e, "cam_t_m2c", 3, path, where) / MM
            poses.append(GtPose(obj_id=_int(e, "obj_id", path, where), R=R, t=t))
        out[im_id] = poses
    return out


def read_scene_gt_info(path: str | Path) -> dict[int, list[GtInfo]]:
    """Parse ``scene_gt_info.json`` -> ``{im_id: [GtInfo, ...]}``."""
    path = Path(path)
    out: dict[int, list[GtInfo]] = {}
    for im_id, raw in _id_dict(_load_json(path), path, "image").items():
        if not isinstance(raw, list):
            raise BopFormatError(f"{path}: image {im_id}: expected a list of instances")
        infos = []
        for k, inst in enumerate(raw):
            where = f"image {im_id} instance {k}"
            e = _obj(inst, path, where)
            infos.append(
                GtInfo(
                    bbox_obj=tuple(_nums(e, "bbox_obj", 4, path, where).tolist()),
                    bbox_visib=tuple(_nums(e, "bbox_visib", 4, path, where).tolist()),
                    px_count_all=_int(e, "px_count_all", path, where),
                    px_count_visib=_int(e, "px_count_visib", path, where),
                    visib_fract=_num(e, "visib_fract", path, where),
                    px_count_valid=_int(e, "px_count_valid", path, where, default=0),
                )
            )
        out[im_id] = infos
    return out


_BBOX_KEYS = ("min_x", "min_y", "min_z", "size_x", "size_y", "size_z")


def read_models_info(path: str | Path) -> dict[int, ModelInfo]:
    """Parse ``models_info.json`` -> ``{obj_id: ModelInfo}`` (mm -> m)."""
    path = Path(path)
    out: dict[int, ModelInfo] = {}
    for obj_id, raw in _id_dict(_load_json(path), path, "object").items():
        where = f"object {obj_id}"
        e = _obj(raw, path, where)
        diameter = _num(e, "diameter", path, where)
        if diameter <= 0:
            raise BopFormatError(f"{path}: {where}: 'diameter' must be positive, got {diameter}")
        disc = []
        for k, sym in enumerate(_list(e, "symmetries_discrete", path, where)):
            T = _nums({"T": sym}, "T", 16, path, f"{where} symmetries_discrete[{k}]").reshape(4, 4)
            T[:3, 3] /= MM
            disc.append(T)
        cont = []
        for k, sym in enumerate(_list(e, "symmetries_continuous", path, where)):
            w = f"{where} symmetries_continuous[{k}]"
            s = _obj(sym, path, w)
            axis = _nums(s, "axis", 3, path, w)
            if np.linalg.norm(axis) == 0:
                raise BopFormatError(f"{path}: {w}: 'axis' is the zero vector")
            offset = _nums(s, "offset", 3, path, w, required=False)
            offset = np.zeros(3) if offset is None else offset / MM
            cont.append({"axis": axis, "offset": offset})
        box = None
        if all(k in e for k in _BBOX_KEYS):
            box = np.array([_num(e, k, path, where) for k in _BBOX_KEYS]) / MM
        out[obj_id] = ModelInfo(
            obj_id=obj_id,
            diameter=diameter / MM,
            symmetries_discrete=disc,
            symmetries_continuous=cont,
            min_xyz=None if box is None else box[:3],
            size_xyz=None if box is None else box[3:],
        )
    return out


def _list(entry: dict, key: str, path: Path, where: str) -> list:
    value = entry.get(key, [])
    if not isinstance(value, list):
        raise BopFormatError(f"{path}: {where}: {key!r} must be a list")
    return value


# ----------------------------------------------------------------------------- JSON writing


def _floats(a: np.ndarray, scale: float = 1.0) -> list[float]:
    return [float(x) * scale for x in np.asarray(a, dtype=np.float64).ravel()]


def _dump_bop_json(content: dict[int, Any]) -> str:
    """BOP toolkit style: one id per line, numeric key order, inner keys sorted."""
    items = sorted(content.items())
    lines = [f'  "{k}": {json.dumps(v, sort_keys=True)}' for k, v in items]
    return "{\n" + ",\n".join(lines) + ("\n}" if lines else "}") + "\n"


def write_scene_camera(path: str | Path, cameras: dict[int, CameraInfo]) -> None:
    """Write ``scene_camera.json`` (metres -> mm)."""
    content = {}
    for im_id, cam in cameras.items():
        e: dict[str, Any] = {"cam_K": _floats(cam.K), "depth_scale": float(cam.depth_scale)}
        if cam.R_w2c is not None and cam.t_w2c is not None:
            e["cam_R_w2c"] = _floats(cam.R_w2c)
            e["cam_t_w2c"] = _floats(cam.t_w2c, MM)
        if cam.width is not None and cam.height is not None:
            e["width"], e["height"] = int(cam.width), int(cam.height)
        content[int(im_id)] = e
    atomic_write_text(path, _dump_bop_json(content))


def write_scene_gt(path: str | Path, gt: dict[int, list[GtPose]]) -> None:
    """Write ``scene_gt.json`` (metres -> mm)."""
    content = {
        int(im_id): [
            {"cam_R_m2c": _floats(p.R), "cam_t_m2c": _floats(p.t, MM), "obj_id": int(p.obj_id)}
            for p in poses
        ]
        for im_id, poses in gt.items()
    }
    atomic_write_text(path, _dump_bop_json(content))


def write_scene_gt_info(path: str | Path, gt_info: dict[int, list[GtInfo]]) -> None:
    """Write ``scene_gt_info.json``."""

    def entry(g: GtInfo) -> dict[str, Any]:
        return {
            "bbox_obj": [_num_out(v) for v in g.bbox_obj],
            "bbox_visib": [_num_out(v) for v in g.bbox_visib],
            "px_count_all": int(g.px_count_all),
            "px_count_valid": int(g.px_count_valid),
            "px_count_visib": int(g.px_count_visib),
            "visib_fract": float(g.visib_fract),
        }

    content = {int(im_id): [entry(g) for g in infos] for im_id, infos in gt_info.items()}
    atomic_write_text(path, _dump_bop_json(content))


def _num_out(v: float) -> int | float:
    """Integers stay integers in the JSON (BOP boxes are integer pixels)."""
    v = float(v)
    return int(v) if v.is_integer() else v


def write_models_info(path: str | Path, models_info: dict[int, ModelInfo]) -> None:
    """Write ``models_info.json`` (metres -> mm)."""
    content = {}
    for obj_id, m in models_info.items():
        e: dict[str, Any] = {"diameter": float(m.diameter) * MM}
        if m.min_xyz is not None and m.size_xyz is not None:
            box = np.concatenate([np.ravel(m.min_xyz), np.ravel(m.size_xyz)]) * MM
            e.update({k: float(v) for k, v in zip(_BBOX_KEYS, box, strict=True)})
        if m.symmetries_discrete:
            syms = []
            for T in m.symmetries_discrete:
                T = np.array(T, dtype=np.float64).reshape(4, 4)
                T[:3, 3] *= MM
                syms.append(_floats(T))
            e["symmetries_discrete"] = syms
        if m.symmetries_continuous:
            e["symmetries_continuous"] = [
                {"axis": _floats(s["axis"]), "offset": _floats(s.get("offset", np.zeros(3)), MM)}
                for s in m.symmetries_continuous
            ]
        content[int(obj_id)] = e
    atomic_write_text(path, _dump_bop_json(content))


# ----------------------------------------------------------------------------- images


def _encode(path: Path, img: np.ndarray) -> None:
    ext = path.suffix.lower()
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if ext in (".jpg", ".jpeg") else []
    ok, buf = cv2.imencode(ext, img, params)
    if not ok:
        raise ValueError(f"{path}: cannot encode image as {ext}")
    atomic_write_bytes(path, buf.tobytes())


def write_rgb(path: str | Path, img: np.ndarray) -> None:
    """Write an RGB uint8 (H,W,3) image as png or jpg (by the file suffix)."""
    img = np.asarray(img)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"{path}: rgb must be uint8 (H,W,3), got {img.dtype} {img.shape}")
    _encode(Path(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))


def write_depth(path: str | Path, depth_m: np.ndarray, depth_scale: float = 0.1) -> None:
    """Write depth (H,W) metres as uint16 png with raw = round(depth_mm / depth_scale).

    Missing (0, negative or non-finite) stays 0. Round-trips within ``depth_scale / 2`` mm.
    """
    d = np.asarray(depth_m, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"{path}: depth must be (H,W), got {d.shape}")
    raw = np.where(np.isfinite(d) & (d > 0), d, 0.0) * MM / depth_scale
    raw = np.rint(raw)
    top = np.iinfo(np.uint16).max
    if raw.max(initial=0) > top:
        raise DatasetError(
            f"{path}: depth {d.max():.3f} m exceeds uint16 with depth_scale {depth_scale} mm "
            f"(at most {top * depth_scale / MM:.2f} m; raise depth.depth_scale)"
        )
    _encode(Path(path), raw.astype(np.uint16))


def write_mask(path: str | Path, mask: np.ndarray) -> None:
    """Write a boolean (H,W) mask as a 0/255 uint8 png."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"{path}: mask must be (H,W), got {m.shape}")
    _encode(Path(path), np.where(m > 0, 255, 0).astype(np.uint8))


def _read_image(path: Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    data = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(data, flags) if data.size else None
    if img is None:
        raise DatasetError(f"{path}: cannot decode image")
    return img


def read_rgb(path: str | Path) -> np.ndarray:
    """(H,W,3) uint8 RGB of a colour image file; DatasetError if missing, undecodable or not
    8-bit."""
    path = Path(path)
    img = _read_image(path, cv2.IMREAD_COLOR)
    if img.dtype != np.uint8:
        raise DatasetError(f"{path}: expected an 8-bit colour image, got {img.dtype}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_depth(path: str | Path, depth_scale: float) -> np.ndarray:
    """(H,W) float32 metres of a single-channel depth image, depth_mm = raw * ``depth_scale``
    (0 = missing); DatasetError if missing, undecodable or not a uint16 / uint8 image."""
    path = Path(path)
    raw = _read_image(path, cv2.IMREAD_UNCHANGED)
    if raw.ndim != 2 or raw.dtype not in (np.uint16, np.uint8):
        raise DatasetError(f"{path}: depth must be a single-channel uint16 png, got {raw.dtype}")
    return (raw.astype(np.float32) * np.float32(depth_scale / MM)).astype(np.float32)


def image_size(path: str | Path) -> tuple[int, int] | None:
    """(height, width) of a png/jpg from its header without decoding; None if not found."""
    path = Path(path)
    if not path.is_file():
        return None
    with open(path, "rb") as f:
        head = f.read(24)
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            w, h = struct.unpack(">II", head[16:24])
            return int(h), int(w)
        if head[:2] == b"\xff\xd8":
            f.seek(2)
            return _jpeg_size(f)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return None if img is None else img.shape[:2]


def _jpeg_size(f) -> tuple[int, int] | None:
    sof = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
    while True:
        b = f.read(1)
        while b and b != b"\xff":
            b = f.read(1)
        while b == b"\xff":
            b = f.read(1)
        if not b:
            return None
        marker = b[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue
        seg = f.read(2)
        if len(seg) < 2:
            return None
        length = struct.unpack(">H", seg)[0]
        if marker in sof:
            data = f.read(5)
            if len(data) < 5:
                return None
            h, w = struct.unpack(">HH", data[1:5])
            return int(h), int(w)
        f.seek(length - 2, 1)


# ----------------------------------------------------------------------------- helpers for writers


def _bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        return (-1, -1, -1, -1)
    x0, y0 = int(xs.min()), int(ys.min())
    # BOP toolkit misc.calc_2d_bbox: width = x_max - x_min (no +1)
    return (x0, y0, int(xs.max()) - x0, int(ys.max()) - y0)


def gt_info_from_masks(
    mask: np.ndarray, mask_visib: np.ndarray, depth: np.ndarray | None = None
) -> GtInfo:
    """``GtInfo`` from the full (unoccluded) and visible (H,W) bool masks of one instance.

    ``bbox_obj`` is the box of the full mask inside the image (the BOP toolkit uses the projected
    model, which may extend past the border); ``px_count_valid`` counts full-mask pixels with
    depth > 0 (all of them if ``depth`` is None).
    """
    mask = np.asarray(mask, dtype=bool)
    mask_visib = np.asarray(mask_visib, dtype=bool)
    n_all = int(mask.sum())
    n_vis = int(mask_visib.sum())
    n_valid = n_all if depth is None else int((mask & (np.asarray(depth) > 0)).sum())
    return GtInfo(
        bbox_obj=_bbox(mask),
        bbox_visib=_bbox(mask_visib),
        px_count_all=n_all,
        px_count_visib=n_vis,
        visib_fract=n_vis / n_all if n_all else 0.0,
        px_count_valid=n_valid,
    )


def model_info_from_object(obj: Any) -> ModelInfo:
    """``ModelInfo`` of a ``chpf.objects.ObjectModel`` (diameter, bounds, symmetries; metres)."""
    lo, hi = np.asarray(obj.mesh.bounds, dtype=np.float64)
    return ModelInfo(
        obj_id=int(obj.obj_id),
        diameter=float(obj.diameter),
        symmetries_discrete=[np.asarray(T, dtype=np.float64) for T in obj.symmetries_discrete],
        symmetries_continuous=[
            {"axis": np.asarray(s["axis"], float), "offset": np.asarray(s["offset"], float)}
            for s in obj.symmetries_continuous
        ],
        min_xyz=lo,
        size_xyz=hi - lo,
    )


# ----------------------------------------------------------------------------- reading


class BopScene:
    """One scene folder: cameras, ground truth (empty if absent) and lazily read images."""

    def __init__(self, path: str | Path, scene_id: int | None = None) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise DatasetError(f"{self.path}: scene folder not found")
        if scene_id is None:
            try:
                scene_id = int(self.path.name)
            except ValueError:
                raise DatasetError(f"{self.path}: scene folder name is not an integer") from None
        self.scene_id = int(scene_id)
        self.cameras: dict[int, CameraInfo] = read_scene_camera(self.path / SCENE_CAMERA)
        gt_file = self.path / SCENE_GT
        info_file = self.path / SCENE_GT_INFO
        self.gt: dict[int, list[GtPose]] = read_scene_gt(gt_file) if gt_file.is_file() else {}
        self.gt_info: dict[int, list[GtInfo]] = (
            read_scene_gt_info(info_file) if info_file.is_file() else {}
        )
        for im_id, infos in self.gt_info.items():
            if im_id in self.gt and len(infos) != len(self.gt[im_id]):
                raise BopFormatError(
                    f"{info_file}: image {im_id} has {len(infos)} instances but scene_gt.json "
                    f"has {len(self.gt[im_id])}"
                )

    def __repr__(self) -> str:
        return f"BopScene({str(self.path)!r}, {len(self.cameras)} images)"

    def image_ids(self) -> list[int]:
        """Sorted image ids of ``scene_camera.json``."""
        return sorted(self.cameras)

    def camera(self, im_id: int) -> CameraInfo:
        """Camera of one image; DatasetError if ``scene_camera.json`` has no entry."""
        try:
            return self.cameras[im_id]
        except KeyError:
            raise DatasetError(f"{self.path / SCENE_CAMERA}: no camera for image {im_id}") from None

    def rgb_path(self, im_id: int) -> Path:
        """Path of the colour image (png, else jpg); the png path if neither exists."""
        for ext in RGB_EXTS:
            p = rgb_path(self.path, im_id, ext)
            if p.is_file():
                return p
        return rgb_path(self.path, im_id, ".png")

    def depth_path(self, im_id: int) -> Path:
        return depth_path(self.path, im_id)

    def rgb(self, im_id: int) -> np.ndarray:
        """(H,W,3) uint8 RGB; DatasetError if missing, ImageSizeError if the size disagrees."""
        cam = self.camera(im_id)
        path = self.rgb_path(im_id)
        img = read_rgb(path)
        self._check_size(path, img.shape[:2], cam, others=[self.depth_path(im_id)])
        return img

    def depth(self, im_id: int) -> np.ndarray | None:
        """(H,W) float32 metres (0 = missing), or None if the scene has no depth image."""
        cam = self.camera(im_id)
        path = self.depth_path(im_id)
        if not path.is_file():
            return None
        depth = read_depth(path, cam.depth_scale)
        self._check_size(path, depth.shape, cam, others=[self.rgb_path(im_id)])
        return depth

    def mask_visib(self, im_id: int, gt_idx: int) -> np.ndarray:
        """(H,W) bool visible mask of instance ``gt_idx``."""
        return self._mask(im_id, gt_idx, "mask_visib")

    def mask(self, im_id: int, gt_idx: int) -> np.ndarray:
        """(H,W) bool full (unoccluded) mask of instance ``gt_idx``."""
        return self._mask(im_id, gt_idx, "mask")

    def _mask(self, im_id: int, gt_idx: int, kind: str) -> np.ndarray:
        cam = self.camera(im_id)
        path = mask_visib_path(self.path, im_id, gt_idx, kind)
        m = _read_image(path, cv2.IMREAD_GRAYSCALE)
        self._check_size(path, m.shape, cam, others=[self.rgb_path(im_id), self.depth_path(im_id)])
        return m > 127

    def _check_size(
        self, path: Path, hw: tuple[int, int], cam: CameraInfo, others: list[Path]
    ) -> None:
        h, w = int(hw[0]), int(hw[1])
        if cam.width is not None and cam.height is not None and (w, h) != (cam.width, cam.height):
            raise ImageSizeError(
                f"{path}: image is {w}x{h} but the camera says {cam.width}x{cam.height}"
            )
        try:
            check_image_size(w, h, cam.K)
        except ImageSizeError as err:
            raise ImageSizeError(f"{path}: {err}") from None
        for other in others:
            size = image_size(other)
            if size is not None and (int(size[0]), int(size[1])) != (h, w):
                raise ImageSizeError(
                    f"{path}: image is {w}x{h} but {other.name} in {other.parent.name}/ "
                    f"is {size[1]}x{size[0]}"
                )


class BopDataset:
    """A BOP dataset root: ``models/`` and split folders of scenes."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: dataset folder not found")
        has_models = (models_dir(self.root) / MODELS_INFO).is_file()
        has_scenes = any(
            (d / SCENE_CAMERA).is_file() for s in _subdirs(self.root) for d in _subdirs(s)
        )
        if not (has_models or has_scenes):
            raise DatasetError(
                f"{self.root}: not a BOP dataset (no models/models_info.json and no "
                "SPLIT/SCENE/scene_camera.json)"
            )
        self._models_info: dict[int, ModelInfo] | None = None

    def __repr__(self) -> str:
        return f"BopDataset({str(self.root)!r})"

    @property
    def models_info_path(self) -> Path:
        return models_dir(self.root) / MODELS_INFO

    def models_info(self) -> dict[int, ModelInfo]:
        """``{obj_id: ModelInfo}`` from ``models/models_info.json`` (metres), cached."""
        if self._models_info is None:
            self._models_info = read_models_info(self.models_info_path)
        return self._models_info

    @property
    def sequences_info_path(self) -> Path:
        return self.root / SEQUENCES_INFO

    def recorded_fingerprints(self) -> dict[int, str]:
        """``{obj_id: mesh fingerprint}`` recorded by ``chpf-gen-data sequences`` in
        ``sequences_info.json`` (``chpf.objects.object_fingerprint``); {} when there is none."""
        path = self.sequences_info_path
        if not path.is_file():
            return {}
        data = _load_json(path)
        objects = data.get("objects") if isinstance(data, dict) else None
        return {
            o["obj_id"]: str(o["fingerprint"])
            for o in (objects if isinstance(objects, list) else [])
            if isinstance(o, dict) and isinstance(o.get("obj_id"), int) and o.get("fingerprint")
        }

    def model_path(self, obj_id: int) -> Path:
        """``ROOT/models/obj_{obj_id:06d}.ply``."""
        return model_path(self.root, obj_id)

    def load_object(self, obj_id: int) -> Any:
        """``ObjectModel`` of ``obj_id``: mesh mm -> m; diameter and symmetries from models_info."""
        infos = self.models_info()
        if obj_id not in infos:
            raise DatasetError(f"{self.models_info_path}: no entry for object {obj_id}")
        path = self.model_path(obj_id)
        if not path.is_file():
            raise DatasetError(f"{path}: model file not found")
        from chpf.objects import load_mesh  # lazy: reading images/JSON needs no mesh code

        obj = copy.copy(load_mesh(path, unit="mm", name=f"obj_{obj_id:06d}", obj_id=obj_id))
        info = infos[obj_id]
        obj.diameter = info.diameter
        obj.symmetries_discrete = [T.copy() for T in info.symmetries_discrete]
        obj.symmetries_continuous = [
            {"axis": s["axis"].copy(), "offset": s["offset"].copy()}
            for s in info.symmetries_continuous
        ]
        return obj

    def split_path(self, split: str) -> Path:
        return self.root / split

    def scene_ids(self, split: str = "test") -> list[int]:
        """Sorted ids of the scene folders (6-digit names) of ``split``."""
        path = self.split_path(split)
        if not path.is_dir():
            raise DatasetError(f"{path}: split folder not found")
        return sorted(int(d.name) for d in _subdirs(path) if d.name.isdigit())

    def scene(self, split: str, scene_id: int) -> BopScene:
        """Open one scene of ``split``."""
        return BopScene(scene_dir(self.root, split, scene_id), scene_id)


def _subdirs(path: Path) -> list[Path]:
    try:
        return [d for d in path.iterdir() if d.is_dir()]
    except OSError:
        return []
