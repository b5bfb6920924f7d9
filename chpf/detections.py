"""2D detections in the BOP 2023 default-detections JSON format.

The file is a JSON list of ``{"scene_id", "image_id", "category_id", "bbox": [x, y, w, h] px,
"score", "time"}`` (extra keys such as ``"segmentation"`` are ignored). ``read_detections`` keeps
the best-scoring box per (scene_id, image_id, category_id); ``category_id`` is the BOP obj_id.

``read_detections_csv`` reads the simpler per-frame CSV ``frame,x,y,w,h[,score]`` of
``chpf-track --images`` / ``--video`` (a header line is optional).

``SimulatedDetector`` makes such detections from ground truth (``chpf-gen-data sequences`` writes
them; ``chpf-track`` runs it on datasets without a detections file). It is NOT a real detector.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from chpf.atomic import atomic_write_text
from chpf.errors import BopFormatError, DatasetError, SourceError

if TYPE_CHECKING:
    from chpf.bop import GtInfo

__all__ = [
    "SIMULATED_DETECTOR_DEFAULTS",
    "SimulatedDetector",
    "read_detections",
    "read_detections_csv",
    "write_detections",
]

# Noise of the simulated detector (fractions of the box size; log-scale size noise).
SIMULATED_DETECTOR_DEFAULTS: dict[str, Any] = {
    "center_noise": 0.05,
    "size_noise": 0.08,
    "miss_prob": 0.05,
    "min_visib_fract": 0.1,
    "score_range": [0.6, 1.0],
}

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


def read_detections_csv(path: str | Path) -> dict[int, tuple[float, float, float, float]]:
    """``{frame: (x, y, w, h)}`` pixels from a CSV of ``frame,x,y,w,h[,score]`` rows (an optional
    header line first; the best score kept per frame, score 1 when absent); SourceError naming
    the file and line when a row is not 5 or 6 numbers with an integer frame."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise SourceError(f"{path}: detections file not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise SourceError(f"{path}: cannot read the detections file ({err})") from None
    best: dict[int, tuple[float, tuple[float, float, float, float]]] = {}
    for n, line in enumerate(lines, start=1):
        cells = [c.strip() for c in line.split(",")]
        if not line.strip() or (n == 1 and cells[0].lower() == "frame"):
            continue
        try:
            values = [float(c) for c in cells]
        except ValueError:
            values = []
        if (
            len(values) not in (5, 6)
            or not all(map(math.isfinite, values))
            or not values[0].is_integer()
        ):
            raise SourceError(
                f"{path}: line {n}: expected frame,x,y,w,h[,score] (numbers, integer frame), "
                f"got {line.strip()!r}"
            )
        frame, score = int(values[0]), values[5] if len(values) == 6 else 1.0
        if frame not in best or score > best[frame][0]:
            best[frame] = (score, (values[1], values[2], values[3], values[4]))
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


class SimulatedDetector:
    """A simulated 2D detector: the visible ground-truth box with noise and missed frames.

    ``cfg``: keys of ``SIMULATED_DETECTOR_DEFAULTS``. Not a real detector: it sees the ground
    truth (``info.bbox_visib`` and ``info.visib_fract``).
    """

    def __init__(self, cfg: dict, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.rng = rng

    def detect(
        self, scene_id: int, im_id: int, obj_id: int, info: GtInfo, width: int, height: int
    ) -> dict | None:
        """A BOP detection dict for one object instance, or None (missed / too occluded)."""
        c, rng = self.cfg, self.rng
        miss = rng.random() < c["miss_prob"]
        noise = rng.standard_normal(4)
        score = float(rng.uniform(*c["score_range"]))
        if miss or info.visib_fract < c["min_visib_fract"] or info.bbox_visib[2] <= 0:
            return None
        x, y, w, h = (float(v) for v in info.bbox_visib)
        w, h = max(w, 1.0), max(h, 1.0)
        cx = x + w / 2 + noise[0] * c["center_noise"] * w
        cy = y + h / 2 + noise[1] * c["center_noise"] * h
        w *= float(np.exp(noise[2] * c["size_noise"]))
        h *= float(np.exp(noise[3] * c["size_noise"]))
        x0, y0 = max(cx - w / 2, 0.0), max(cy - h / 2, 0.0)
        x1, y1 = min(cx + w / 2, width - 1.0), min(cy + h / 2, height - 1.0)
        if x1 - x0 < 1 or y1 - y0 < 1:
            return None
        return {
            "scene_id": int(scene_id),
            "image_id": int(im_id),
            "category_id": int(obj_id),
            "bbox": [round(x0, 2), round(y0, 2), round(x1 - x0, 2), round(y1 - y0, 2)],
            "score": round(score, 4),
            "time": 0.0,
        }
