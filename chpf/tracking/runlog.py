"""Per-frame tracking log: a CSV with one row per processed frame, flushed as it goes.

Columns: scene_id, im_id, obj_id, has_box, ok, weighed, alpha, sum_L, sum_C, ess, err_add,
err_adds (metres; nan without ground truth), then ms_<stage> for the stages in STAGES (nan when
a method has no such stage). A rerun reopens the file, cuts a partial last line (a run killed
mid-write) and reports which (scene_id, im_id, obj_id) are already logged.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from chpf.errors import DatasetError
from chpf.resumable_csv import ResumableCsv
from chpf.tracking.types import TrackResult

STAGES = (
    "init",
    "predict",
    "likelihood",
    "crop",
    "encode",
    "ch_encode",
    "lookup",
    "head",
    "depth",
    "anneal",
    "weigh",
    "estimate",
    "resample",
    "total",
)
NETWORK_STAGES = ("encode", "ch_encode", "head")
"""Stages spent inside the ONNX networks (the rest is the filter's own work)."""
KEYS = ("scene_id", "im_id", "obj_id")
COLUMNS = (
    *KEYS,
    "has_box",
    "ok",
    "weighed",
    "alpha",
    "sum_L",
    "sum_C",
    "ess",
    "err_add",
    "err_adds",
    *(f"ms_{s}" for s in STAGES),
)


def _num(x: float) -> str:
    x = float(x)
    return "nan" if math.isnan(x) else f"{x:.6g}"


@dataclass
class LogRow:
    """One parsed log row (numbers as floats, flags as bools)."""

    scene_id: int
    im_id: int
    obj_id: int
    values: dict[str, float]


class FrameLog(ResumableCsv):
    """Append-only per-frame log (see the module docstring and ``chpf.resumable_csv``)."""

    def __init__(self, path: str | Path) -> None:
        super().__init__(path, ",".join(COLUMNS), _log_keys)

    def append(
        self,
        key: tuple[int, int, int],
        has_box: bool,
        result: TrackResult,
        err_add: float = float("nan"),
        err_adds: float = float("nan"),
    ) -> None:
        """Write one frame's row and flush it."""
        cells = [str(int(k)) for k in key]
        cells += [str(int(has_box)), str(int(result.ok)), str(int(result.weighed))]
        cells += [_num(v) for v in (result.alpha, result.sum_L, result.sum_C, result.ess)]
        cells += [_num(err_add), _num(err_adds)]
        cells += [_num(result.stage_ms.get(s, float("nan"))) for s in STAGES]
        self.append_line((int(key[0]), int(key[1]), int(key[2])), ",".join(cells))


def _log_keys(path: Path, text: str) -> list[tuple[int, int, int]]:
    return [(r.scene_id, r.im_id, r.obj_id) for r in parse_log(text, path)]


def read_log(path: str | Path) -> list[LogRow]:
    """All rows of a frame log; DatasetError on a file with other columns."""
    path = Path(path)
    return parse_log(path.read_text(encoding="utf-8"), path)


def parse_log(text: str, path: Path) -> list[LogRow]:
    """Rows of a frame log's text (partial lines skipped); DatasetError naming ``path`` on a
    file with other columns."""
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None:
        return []
    if tuple(header) != COLUMNS:
        raise DatasetError(f"{path}: not a chpf-track frame log (unexpected columns)")
    rows = []
    for cells in reader:
        if len(cells) != len(COLUMNS):
            continue  # a partial line of an interrupted run
        vals = {c: float(v) for c, v in zip(COLUMNS[3:], cells[3:], strict=True)}
        rows.append(LogRow(int(cells[0]), int(cells[1]), int(cells[2]), vals))
    return rows


def log_arrays(rows: list[LogRow]) -> dict[str, np.ndarray]:
    """Columns of log rows as arrays (keys as int64, the rest float64)."""
    out: dict[str, np.ndarray] = {
        "scene_id": np.array([r.scene_id for r in rows], np.int64),
        "im_id": np.array([r.im_id for r in rows], np.int64),
        "obj_id": np.array([r.obj_id for r in rows], np.int64),
    }
    for c in COLUMNS[3:]:
        out[c] = np.array([r.values[c] for r in rows], np.float64)
    return out
