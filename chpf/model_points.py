"""Model points of the ADD / ADD-S metrics, chosen as the field's toolkits choose them.

- ``vertices`` (default): the model's own vertices, from ``models_eval/obj_XXXXXX.ply`` when
  the dataset has that folder, else ``models/obj_XXXXXX.ply`` (millimetres), as the bop_toolkit
  does;
- a point file (``--points FILE``): one point per line, three numbers in metres, such as the
  YCB-Video toolbox's ``models/<name>/points.xyz``;
- ``sample``: the seeded 2,000-point area-uniform surface sample of ``chpf.objects`` (only on
  request: on a 446-vertex mug it scored ADD-S AUC 6 points higher than the vertices).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from chpf.bop import BopDataset
from chpf.errors import DatasetError, MeshError

__all__ = ["POINT_SOURCES", "eval_model_path", "model_points", "read_point_file"]

POINT_SOURCES = ("vertices", "sample")
"""Named sources of model points; anything else given as a source is a point file."""


def eval_model_path(ds: BopDataset, obj_id: int) -> Path:
    """``models_eval/obj_XXXXXX.ply`` when the dataset has ``models_eval/``, else the model."""
    eval_dir = ds.root / "models_eval"
    return eval_dir / f"obj_{obj_id:06d}.ply" if eval_dir.is_dir() else ds.model_path(obj_id)


def _ply_vertices(path: Path) -> np.ndarray:
    """(M, 3) vertices of a PLY file in metres (the file in millimetres, as BOP's)."""
    if not path.is_file():
        raise MeshError(f"{path}: model file not found")
    try:
        mesh = trimesh.load(str(path), file_type="ply", process=False, force="mesh")
        v = np.asarray(mesh.vertices, dtype=np.float64)
    except Exception as err:
        raise MeshError(f"{path}: cannot read model vertices ({type(err).__name__})") from None
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.all(np.isfinite(v)):
        raise MeshError(f"{path}: no finite vertices")
    return v / 1000.0


def read_point_file(path: str | Path) -> np.ndarray:
    """(M, 3) points of a text file of three numbers per line (metres); DatasetError if not."""
    p = Path(path)
    try:
        pts = np.loadtxt(p, dtype=np.float64, ndmin=2)
    except OSError as err:
        raise DatasetError(f"{p}: cannot read point file ({err.strerror or err})") from None
    except ValueError:
        raise DatasetError(f"{p}: not a point file (three numbers per line expected)") from None
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise DatasetError(f"{p}: not a point file (three finite numbers per line expected)")
    return pts


def model_points(ds: BopDataset, obj_id: int, source: str | Path = "vertices") -> np.ndarray:
    """(M, 3) model points in metres of ``obj_id`` from ``source`` (see the module docstring)."""
    if source == "vertices":
        return _ply_vertices(eval_model_path(ds, obj_id))
    if source == "sample":
        return np.asarray(ds.load_object(obj_id).points, dtype=np.float64)
    return read_point_file(source)
