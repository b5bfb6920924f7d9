"""2D detections in the BOP 2023 default-detections JSON format.

The file is a JSON list of ``{"scene_id", "image_id", "category_id", "bbox": [x, y, w, h] px,
"score", "time"}`` (extra keys such as ``"segmentation"`` are ignored). ``read_detections`` keeps
the best-scoring box per (scene_id, image_id, category_id); ``category_id`` is the BOP obj_id.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from chpf.cli import atomic_write_text
from chpf.errors import BopFormatError, DatasetError

__all__ = ["read_detections", "write_detections"]

_INT_KEYS = ("scene_id", "image_id", "category_id")


def _check(det: Any, path: str | Path, i: int) -> tuple[tuple[int, int, int], tuple, float]:
    where = f"{path}: detection {i}"
    if not isinstance(det, dict):
        raise BopFormatError(f"{where}: expected a JSON object")
    ids = []
    for k in _INT_KEYS:
        v = det.get(k)
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if not isinstance(v, int) or isinstance(v, bool):
            raise BopFormatError(f"{where}: {k!r} must be an integer, got {v!r}")
        ids.append(v)
    bbox = det.get("bbox")
    if not isinstance(bbox, (list, tuple)) or len(bbox) != 4 or not all(_finite(v) for v in bbox):
        raise BopFormatError(f"{where}: 'bbox' must be 4 finite numbers [x, y, w, h]")
    score = det.get("score", 1.0)
    if not _finite(score):
        raise BopFormatError(f"{where}: 'score' must be a finite number, got {score!r}")
    return (ids[0], ids[1], ids[2]), tuple(float(v) for v in bbox), float(score)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def read_detections(
    path: str | Path,
) -> dict[tuple[int, int, int], tuple[float, float, float, float]]:
    """``{(scene_id, im_id, obj_id): (x, y, w, h)}`` pixels, best score kept per key."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: detections file not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise BopFormatError(f"{path}: invalid JSON ({err})") from None
    if not isinstance(data, list):
        raise BopFormatError(f"{path}: expected a JSON list of detections")
    best: dict[tuple[int, int, int], tuple[float, tuple]] = {}
    for i, det in enumerate(data):
        key, bbox, score = _check(det, path, i)
        if key not in best or score > best[key][0]:
            best[key] = (score, bbox)
    return {k: v[1] for k, v in sorted(best.items())}


def write_detections(path: str | Path, detections: list[dict[str, Any]]) -> None:
    """Write detections (list of dicts in the format above) atomically, one per line."""
    out = []
    for i, det in enumerate(detections):
        key, bbox, score = _check(det, path, i)
        d = dict(det)
        d.update(zip(_INT_KEYS, key, strict=True))
        d["bbox"] = list(bbox)
        d["score"] = score
        d["time"] = float(det.get("time", -1.0))
        out.append(d)
    body = ",\n".join("  " + json.dumps(d, sort_keys=True) for d in out)
    atomic_write_text(path, "[\n" + body + ("\n]\n" if out else "]\n"))
