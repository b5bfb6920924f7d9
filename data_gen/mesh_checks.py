"""Checks of a user's mesh before hours of rendering and training (issue 21, item 4).

``check_mesh(path, unit, ...)`` loads a mesh file and refuses it with a one-line ``MeshError``
(the CLIs print it and exit 2) when it

- has no faces;
- has a diameter outside 1 cm - 2 m (``chpf.objects.check_size``: probably the wrong ``--unit``;
  the message names the unit that fits);
- is degenerate: more than half of its faces have (almost) zero area;
- renders with holes: more than ``MAX_OPEN_EDGE_SHARE`` of its edges (after merging vertices
  that share a position) are open boundary edges or non-manifold (shared by more than two
  faces). A few open edges pass: the built-in mug's handle and the drill's chuck end inside
  other parts, where no camera sees them, and scans often have a few small holes.

It warns (``warnings.warn``, one line, ``MeshWarning``) when the mesh

- has no colour or texture at all (RGB tracking of a uniform object is weak);
- maps onto itself, shape and colours, under a rotation by 180 degrees about one of its
  principal axes, and the symmetries given (BOP ``models_info.json`` convention) do not
  declare it.

``check_object(obj, where)`` runs the same checks on an ``ObjectModel`` already loaded.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from chpf.errors import MeshError
from chpf.objects import ObjectModel, check_size, load_mesh

DEGENERATE_SHARE = 0.5
"""Refuse when more than this share of faces has (almost) zero area."""
MAX_OPEN_EDGE_SHARE = 0.02
"""Refuse when more than this share of edges is open (one face) or non-manifold (> 2 faces)."""
SYMMETRY_TOL = 0.01
"""A rotation maps the surface onto itself when 90 % of the moved surface points lie within
this share of the diameter (plus the sampling's own spacing) of the surface, and their colours
agree."""
COLOUR_TOL = 30.0
"""Median colour difference (0-255, max over channels) below which colours agree."""
NUM_SYMMETRY_POINTS = 4000


class MeshWarning(UserWarning):
    """A mesh is usable but something about it will probably hurt (no colour, undeclared
    symmetry)."""


def check_mesh(
    path: str | Path,
    unit: str = "m",
    symmetries_discrete: list[Any] | None = None,
    symmetries_continuous: list[dict[str, Any]] | None = None,
    allow_size: bool = False,
) -> ObjectModel:
    """Load the mesh file ``path`` (length unit ``unit``) and check it (module docstring).

    Returns the loaded ``ObjectModel``; raises ``MeshError`` (one line naming the file) for a
    refusal, warns ``MeshWarning`` for the rest. ``allow_size`` skips the diameter check.
    """
    obj = load_mesh(path, unit=unit)  # MeshError: missing, unreadable, no faces
    if symmetries_discrete is not None:
        obj.symmetries_discrete = [np.asarray(T, dtype=np.float64) for T in symmetries_discrete]
    if symmetries_continuous is not None:
        obj.symmetries_continuous = [
            {k: np.asarray(s[k], dtype=np.float64) for k in ("axis", "offset")}
            for s in symmetries_continuous
        ]
    check_object(obj, path, unit=unit, allow_size=allow_size)
    return obj


def check_object(
    obj: ObjectModel, where: str | Path, unit: str = "m", allow_size: bool = False
) -> None:
    """The checks of ``check_mesh`` on a loaded object (metres); ``where`` names it in messages."""
    mesh = obj.mesh
    if len(mesh.faces) == 0:
        raise MeshError(f"{where}: mesh has no faces")
    if not allow_size:
        check_size(obj.diameter, where, unit)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    scale = max(obj.diameter, 1e-12)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    tiny = area <= (scale * 1e-6) ** 2
    if tiny.mean() > DEGENERATE_SHARE:
        raise MeshError(
            f"{where}: degenerate mesh: {int(tiny.sum())} of {len(f)} faces have zero area"
        )
    open_edges, bad_edges, edges = _edge_counts(v, f, scale)
    if (open_edges + bad_edges) > MAX_OPEN_EDGE_SHARE * edges:
        raise MeshError(
            f"{where}: mesh would render with holes: {open_edges} open and {bad_edges} "
            f"non-manifold of {edges} edges (more than {MAX_OPEN_EDGE_SHARE:.0%}); "
            "close the holes (e.g. Poisson reconstruction or hole filling in MeshLab)"
        )
    colours = _face_colours(mesh)
    if colours is None:
        warnings.warn(
            f"{where}: mesh has no colour or texture: RGB tracking of a uniform object is weak",
            MeshWarning,
            stacklevel=2,
        )
    axis = undeclared_symmetry(obj, colours)
    if axis is not None:
        warnings.warn(
            f"{where}: mesh looks symmetric under a 180 deg rotation about axis "
            f"({axis[0]:.2f}, {axis[1]:.2f}, {axis[2]:.2f}) that models_info.json does not "
            "declare: retrieval and ADD treat its symmetric poses as errors",
            MeshWarning,
            stacklevel=2,
        )


def _edge_counts(v: np.ndarray, f: np.ndarray, scale: float) -> tuple[int, int, int]:
    """(open, non-manifold, all) edges after merging vertices at the same position (vertices
    are often split along colour or UV seams)."""
    key = np.round(v / (scale * 1e-6)).astype(np.int64)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    ff = inverse.ravel()[f]
    e = np.sort(np.concatenate([ff[:, [0, 1]], ff[:, [1, 2]], ff[:, [2, 0]]]), axis=1)
    e = e[e[:, 0] != e[:, 1]]
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int((counts == 1).sum()), int((counts > 2).sum()), len(counts)


def _face_colours(mesh: Any) -> np.ndarray | None:
    """(F, 3) float colour of each face (mean of its vertices' colours; a texture sampled at
    the UVs), None when the mesh has no colour at all (no visual, or one colour everywhere)."""
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    faces = np.asarray(mesh.faces)
    try:
        if kind == "texture":
            cols = np.asarray(visual.to_color().vertex_colors)[:, :3][faces].mean(1)
        elif kind == "vertex":
            cols = np.asarray(visual.vertex_colors)[:, :3][faces].mean(1)
        elif kind == "face":
            cols = np.asarray(visual.face_colors)[:, :3]
        else:
            return None
    except Exception:  # a texture trimesh cannot sample: coloured, but skip the colour test
        return np.zeros((len(faces), 3))
    cols = cols.astype(np.float64)
    if len(cols) != len(faces) or np.ptp(cols, axis=0).max() == 0:
        return None
    return cols


def _rotation_180(axis: np.ndarray) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    return 2.0 * np.outer(a, a) - np.eye(3)


def _declared(obj: ObjectModel, R: np.ndarray) -> bool:
    """Whether the symmetries of ``obj`` (as a group: a discrete one followed by a rotation
    about a continuous axis) include the rotation ``R``."""
    cands = [np.eye(3)] + [np.asarray(T, dtype=np.float64)[:3, :3] for T in obj.symmetries_discrete]
    axes = [np.asarray(s["axis"], dtype=np.float64) for s in obj.symmetries_continuous]
    axes = [a / max(np.linalg.norm(a), 1e-12) for a in axes]
    for Rd in cands:
        M = R @ Rd.T  # what is left to explain after the discrete symmetry
        if (np.trace(M) - 1.0) / 2.0 > np.cos(np.deg2rad(5.0)):
            return True
        if any(np.linalg.norm(M @ a - a) < 0.05 for a in axes):  # a rotation about that axis
            return True
    return False


def undeclared_symmetry(obj: ObjectModel, colours: np.ndarray | None = None) -> np.ndarray | None:
    """A principal axis (unit (3,)) about which a 180 deg rotation maps the surface (and its
    ``colours``, (F, 3) per face, when given) onto itself and that ``obj``'s symmetries do not
    declare; None when there is none."""
    from scipy.spatial import cKDTree
    from trimesh.sample import sample_surface

    mesh = obj.mesh
    pts, pts_face = sample_surface(mesh, NUM_SYMMETRY_POINTS, seed=1)
    ref, ref_face = sample_surface(mesh, 4 * NUM_SYMMETRY_POINTS, seed=2)
    pts, ref = np.asarray(pts, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    face_col = colours
    centre = pts.mean(0)
    _, vecs = np.linalg.eigh(np.cov((pts - centre).T))
    ref_tree = cKDTree(ref)
    # the sampling's own spacing: distances of unmoved points to the other sample
    tol = 1.5 * float(np.quantile(ref_tree.query(pts)[0], 0.9))
    tol += SYMMETRY_TOL * max(obj.diameter, 1e-12)
    for k in range(3):
        axis = vecs[:, k]
        R = _rotation_180(axis)
        if _declared(obj, R):
            continue
        moved = (pts - centre) @ R.T + centre
        d, nearest = ref_tree.query(moved)
        if np.quantile(d, 0.9) > tol:
            continue
        if face_col is not None:
            diff = np.abs(face_col[pts_face] - face_col[ref_face[nearest]]).max(1)
            if np.median(diff) > COLOUR_TOL or np.mean(diff > COLOUR_TOL) > 0.2:
                continue
        return axis
    return None


def declared_symmetries(path: str | Path) -> tuple[list[Any], list[dict[str, Any]]] | None:
    """(discrete, continuous) symmetries of the mesh file ``path`` in the ``models_info.json``
    beside it (BOP layout, entry of the obj_id in the file name); None when there is none."""
    from chpf.bop import read_models_info
    from chpf.objects import bop_obj_id

    info_path = Path(path).parent / "models_info.json"
    obj_id = bop_obj_id(path)
    if obj_id is None or not info_path.is_file():
        return None
    entry = read_models_info(info_path).get(obj_id)
    if entry is None:
        return None
    return entry.symmetries_discrete, entry.symmetries_continuous


def checked_object(name_or_path: str, unit: str = "m", allow_size: bool = False) -> ObjectModel:
    """``chpf.objects.get_object`` for the commands that start hours of work: a built-in object
    as it is, a mesh file through ``check_mesh`` (checked against the symmetries of a
    ``models_info.json`` beside it, ``declared_symmetries``; returned without symmetries, as
    ``get_object`` gives it), ``centred`` as every crop of it is (``ObjectModel.centred``)."""
    from chpf.objects import BUILTIN_OBJECTS, get_object

    if name_or_path in BUILTIN_OBJECTS:
        return get_object(name_or_path)
    p = Path(name_or_path)
    if not p.is_file():  # the one-line errors of get_object (not found, not a mesh name)
        return get_object(name_or_path, unit=unit, allow_size=allow_size)
    sym = declared_symmetries(p)
    disc, cont = sym if sym is not None else ([], [])
    obj = check_mesh(p, unit, disc, cont, allow_size=allow_size)
    # the declared symmetries serve the check only: the other tools that load a data folder's
    # mesh (get_object: training.codebook, training.evaluate) give a mesh file none, and the
    # object must be the same everywhere
    obj.symmetries_discrete, obj.symmetries_continuous = [], []
    return obj.centred()
