"""``--poses FILE.jsonl``: one JSON line per tracked frame, method and object, flushed as it goes.

Each line is a JSON object::

    {"scene_id": 1, "frame": 42, "time": 1.4, "method": "chpf", "obj_id": 2, "object": "box",
     "ok": true, "R": [[...], [...], [...]], "t": [x, y, z], "alpha": 0.12, "ess": 31.5,
     "has_box": false, "region": [96.5, 40.2, 120.0, 150.3], "ms": 28.1}

``frame``: the frame's id (BOP im_id, image file number or position, video position); ``time``:
seconds from the source's start; ``R`` (3x3, row-major rows) and ``t`` (metres) are the pose
object-to-camera (OpenCV camera), null when there is no estimate; ``alpha``, ``ess`` are null
when not computed; ``ms`` is the method's time for the frame and object; ``has_box``: the
frame gave this object a detection box; ``region``: the search region (x, y, w, h) pixels
that stood in for it (chpf.tracking.search_region; null on a frame with a detection or with
``search.box_source: detections``). With several objects a frame's lines follow the objects'
order (``obj_id`` and ``object`` tell them apart). The file is written from the
start of the run (replacing an older one) and each line is written whole and flushed, so a
program reading it as it grows only ever sees complete lines.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from chpf.atomic import naming
from chpf.outdir import check_out_file
from chpf.sources.frame import SourceFrame
from chpf.tracking.run_dataset import ObjectResult


def _num(x: float, digits: int = 6) -> float | None:
    return None if not math.isfinite(float(x)) else round(float(x), digits)


class PoseStream:
    """A FrameSink (chpf.tracking.run_dataset) writing the lines above to ``path``."""

    def __init__(self, path: str | Path, names: dict[int, str]) -> None:
        """``names``: {obj_id: object name} of the tracked objects."""
        self.path = check_out_file(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.names = {int(k): v for k, v in names.items()}
        with naming(self.path):
            self.file = open(self.path, "w", encoding="utf-8")

    def write(
        self, scene_id: int, frame: SourceFrame, method: str, results: list[ObjectResult]
    ) -> None:
        text = ""
        for obj in results:
            result = obj.result
            ok = bool(result.ok and result.R is not None and result.t is not None)
            line = {
                "scene_id": int(scene_id),
                "frame": int(frame.index),
                "time": _num(frame.time),
                "method": method,
                "obj_id": int(obj.obj_id),
                "object": self.names.get(int(obj.obj_id), ""),
                "ok": ok,
                "R": [[_num(v, 9) for v in row] for row in result.R] if ok else None,
                "t": [_num(v, 9) for v in result.t] if ok else None,
                "alpha": _num(result.alpha),
                "ess": _num(result.ess),
                "has_box": obj.has_box,
                "region": None if result.region is None else [_num(v, 2) for v in result.region],
                "ms": _num(obj.ms, 3),
            }
            text += json.dumps(line) + "\n"
        with naming(self.path):
            self.file.write(text)
            self.file.flush()

    def close(self, completed: bool) -> None:
        """Close the file (its lines stay, also after a run that stopped early)."""
        self.file.close()
