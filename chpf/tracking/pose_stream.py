"""``--poses FILE.jsonl``: one JSON line per tracked frame and method, flushed as it goes.

Each line is a JSON object::

    {"scene_id": 1, "frame": 42, "time": 1.4, "method": "chpf", "obj_id": 2, "object": "box",
     "ok": true, "R": [[...], [...], [...]], "t": [x, y, z], "alpha": 0.12, "ess": 31.5,
     "has_box": false, "ms": 28.1}

``frame``: the frame's id (BOP im_id, image file number or position, video position); ``time``:
seconds from the source's start; ``R`` (3x3, row-major rows) and ``t`` (metres) are the pose
object-to-camera (OpenCV camera), null when there is no estimate; ``alpha``, ``ess`` are null
when not computed; ``ms`` is the method's time for the frame. The file is written from the
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
from chpf.tracking.types import TrackResult


def _num(x: float, digits: int = 6) -> float | None:
    return None if not math.isfinite(float(x)) else round(float(x), digits)


class PoseStream:
    """A FrameSink (chpf.tracking.run_dataset) writing the lines above to ``path``."""

    def __init__(self, path: str | Path, obj_id: int, object_name: str) -> None:
        self.path = check_out_file(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.obj_id = int(obj_id)
        self.object_name = object_name
        with naming(self.path):
            self.file = open(self.path, "w", encoding="utf-8")

    def write(
        self, scene_id: int, frame: SourceFrame, method: str, result: TrackResult, ms: float
    ) -> None:
        ok = bool(result.ok and result.R is not None and result.t is not None)
        line = {
            "scene_id": int(scene_id),
            "frame": int(frame.index),
            "time": _num(frame.time),
            "method": method,
            "obj_id": self.obj_id,
            "object": self.object_name,
            "ok": ok,
            "R": [[_num(v, 9) for v in row] for row in result.R] if ok else None,
            "t": [_num(v, 9) for v in result.t] if ok else None,
            "alpha": _num(result.alpha),
            "ess": _num(result.ess),
            "has_box": frame.box is not None,
            "ms": _num(ms, 3),
        }
        with naming(self.path):
            self.file.write(json.dumps(line) + "\n")
            self.file.flush()

    def close(self, completed: bool) -> None:
        """Close the file (its lines stay, also after a run that stopped early)."""
        self.file.close()
