"""Object models: mesh loading (.ply/.obj/.stl), model points, diameter, built-in objects.

All geometry is in metres. An ``ObjectModel`` carries the mesh (with vertex colours or a
texture), its diameter, model points for the ADD/ADD-S metrics, its symmetries (BOP
``models_info`` convention) and its BOP object id.

The four built-in objects are procedural, deterministic and vertex-coloured; their colour
patterns are made of flat colour regions (vertices are split along region borders, so colours
do not bleed). Their origin is the centre of their bounding box. They are sized like YCB objects:

=====  ======  ==================================================================  ============
id     name    shape                                                               symmetry
=====  ======  ==================================================================  ============
1      mug     open cup, 5 mm wall, handle on +x, asymmetric print on the -x side  none
2      box     printed cereal-like box 0.19 (x) x 0.06 (y) x 0.25 (z) m            none
3      can     cylinder 0.066 dia x 0.10 m, bands along z, distinct caps           axis z
4      drill   power-drill-like: body along +x, grip and battery below (-z)        none
=====  ======  ==================================================================  ============
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from chpf.errors import ConfigError, MeshError

MESH_SUFFIXES = (".ply", ".obj", ".stl")
DEFAULT_NUM_POINTS = 2000
POINTS_SEED = 0

BUILTIN_OBJECTS: dict[str, int] = {"mug": 1, "box": 2, "can": 3, "drill": 4}
MESH_UNITS: dict[str, float] = {"mm": 0.001, "cm": 0.01, "m": 1.0}
"""Length units of mesh files (``--unit``) and their size in metres."""
CENTRED_TOLERANCE = 1e-6
"""Metres: a bounding box centred this close to the origin counts as centred (``centred``)."""
SIZE_RANGE = (0.01, 2.0)
"""Plausible object diameters (metres): outside it the mesh's unit is probably wrong."""


@dataclass(eq=False)
class ObjectModel:
    """A rigid object (metres).

    ``points`` (M, 3) are model points for the metrics (a seeded area-uniform surface sample,
    M <= 2000 by default). ``symmetries_discrete``: list of (4, 4) object-frame transforms
    (translation in metres); ``symmetries_continuous``: list of ``{"axis": (3,), "offset": (3,)}``
    (offset in metres), as in BOP ``models_info.json``. ``source`` and ``unit``: the mesh file
    and its unit (``load_mesh``), so that data made from it can find it again. ``file_offset``
    (3,) metres: where this model's origin lies in the mesh file's frame (a point p of the model
    is p + file_offset in the file); zero as loaded, the bounding box's centre after
    ``centred()``, whose ``file_fingerprint`` keeps the file's ``object_fingerprint``. Compared
    by identity.
    """

    name: str
    mesh: trimesh.Trimesh
    diameter: float
    points: np.ndarray
    symmetries_discrete: list[np.ndarray] = field(default_factory=list)
    symmetries_continuous: list[dict[str, np.ndarray]] = field(default_factory=list)
    obj_id: int = 0
    source: str | None = None  # the mesh file (absolute path) it was loaded from; None: built-in
    unit: str = "m"  # that file's length unit
    file_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    file_fingerprint: str | None = None  # the file's fingerprint, for a centred() model

    @property
    def num_triangles(self) -> int:
        """Number of faces of the mesh."""
        return len(self.mesh.faces)

    def centred(self) -> ObjectModel:
        """This object with its origin moved to the centre of its bounding box (``file_offset``
        records where that is in the file's frame; symmetries move with it): crops are centred
        on the origin (chpf.crops), so a mesh whose origin lies at its base or a corner would be
        cut by its own crops and placed off its detection box. Itself when already centred
        (within a micrometre)."""
        c = bounding_box_centre(self.mesh.vertices)
        if np.all(np.abs(c) < CENTRED_TOLERANCE):
            return self
        mesh = self.mesh.copy()
        mesh.apply_translation(-c)
        shift = np.eye(4)
        shift[:3, 3] = c  # model -> file frame
        return replace(
            self,
            mesh=mesh,
            points=self.points - c,
            symmetries_discrete=[
                np.linalg.inv(shift) @ np.asarray(T, dtype=np.float64) @ shift
                for T in self.symmetries_discrete
            ],
            symmetries_continuous=[
                {"axis": s["axis"], "offset": np.asarray(s["offset"], dtype=np.float64) - c}
                for s in self.symmetries_continuous
            ],
            file_offset=self.file_offset + c,
            file_fingerprint=self.file_fingerprint or object_fingerprint(self),
        )

    def __repr__(self) -> str:
        return (
            f"ObjectModel(name={self.name!r}, obj_id={self.obj_id}, faces={self.num_triangles}, "
            f"diameter={self.diameter:.4f} m)"
        )


# ----------------------------------------------------------------------------- geometry


def bounding_box_centre(vertices: np.ndarray) -> np.ndarray:
    """The centre (3,) of the axis-aligned bounding box of vertices (V,3), in their units."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    return (v.min(axis=0) + v.max(axis=0)) / 2.0


def mesh_diameter(vertices: np.ndarray) -> float:
    """Largest distance (metres) between two vertices, computed on the convex hull's vertices."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if len(v) < 2:
        return 0.0
    try:
        from scipy.spatial import ConvexHull

        v = v[ConvexHull(v).vertices]
    except Exception:  # flat or degenerate point sets: use all (unique) vertices
        v = np.unique(v, axis=0)
    best = 0.0
    chunk = max(1, 4_000_000 // max(len(v), 1))
    for i in range(0, len(v), chunk):
        d2 = ((v[i : i + chunk, None, :] - v[None, :, :]) ** 2).sum(-1)
        best = max(best, float(d2.max()))
    return float(np.sqrt(best))


def sample_model_points(
    mesh: trimesh.Trimesh, n: int = DEFAULT_NUM_POINTS, seed: int = POINTS_SEED
) -> np.ndarray:
    """(n, 3) float64 points sampled area-uniformly on the surface with a fixed seed (metres).

    A mesh with at most ``n`` distinct vertices and zero area gives its vertices instead.
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = float(area.sum())
    if not np.isfinite(total) or total <= 0.0:
        return np.unique(v, axis=0)[:n].copy()
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(f), size=n, p=area / total)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    a, b, c = 1.0 - s, s * (1.0 - r2), s * r2
    t = tri[idx]
    return a[:, None] * t[:, 0] + b[:, None] * t[:, 1] + c[:, None] * t[:, 2]


def make_object(
    mesh: trimesh.Trimesh,
    name: str,
    obj_id: int = 0,
    symmetries_discrete: list[np.ndarray] | None = None,
    symmetries_continuous: list[dict[str, Any]] | None = None,
    num_points: int = DEFAULT_NUM_POINTS,
) -> ObjectModel:
    """Build an ``ObjectModel`` from a mesh in metres: diameter and model points computed."""
    sym_c = [
        {
            "axis": np.asarray(s["axis"], dtype=np.float64),
            "offset": np.asarray(s["offset"], dtype=np.float64),
        }
        for s in (symmetries_continuous or [])
    ]
    return ObjectModel(
        name=name,
        mesh=mesh,
        diameter=mesh_diameter(mesh.vertices),
        points=sample_model_points(mesh, num_points),
        symmetries_discrete=[np.asarray(T, dtype=np.float64) for T in symmetries_discrete or []],
        symmetries_continuous=sym_c,
        obj_id=int(obj_id),
    )


# ----------------------------------------------------------------------------- loading


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def bop_obj_id(path: str | Path) -> int | None:
    """The obj_id in a mesh file named as BOP names models (``obj_000005.ply``,
    ``obj_000005_textured.obj`` -> 5), None for any other name."""
    found = re.fullmatch(r"obj_(\d+)(?:_.*)?", Path(path).stem)
    return int(found.group(1)) if found else None


def load_mesh(
    path: str | Path,
    unit: str = "m",
    name: str | None = None,
    obj_id: int | None = None,
    num_points: int = DEFAULT_NUM_POINTS,
) -> ObjectModel:
    """Load a .ply / .obj / .stl mesh; ``unit`` is the file's length unit (``MESH_UNITS``);
    ``obj_id`` None = the one in a BOP model name (``bop_obj_id``), else 0.

    Scenes (several geometries) are concatenated. The origin is kept as in the file.
    Raises MeshError (one line naming the file) if the file is missing, unreadable, or has no
    faces; ConfigError for an unknown unit.
    """
    p = Path(path)
    if unit not in MESH_UNITS:
        raise ConfigError(f"{p}: unknown mesh unit {unit!r} (use {', '.join(MESH_UNITS)})")
    if not p.is_file():
        raise MeshError(f"{p}: mesh file not found")
    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshError(f"{p}: unsupported mesh format {suffix!r} (use .ply, .obj or .stl)")
    try:
        loaded = trimesh.load(str(p), file_type=suffix[1:], process=False)
        if isinstance(loaded, trimesh.Scene):
            geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
            loaded = trimesh.util.concatenate(geoms) if geoms else None
    except ImportError:  # trimesh falls back to optional text decoders on binary garbage
        raise MeshError(f"{p}: cannot read mesh (not a valid {suffix} file)") from None
    except Exception as err:
        raise MeshError(f"{p}: cannot read mesh ({_one_line(err)})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{p}: mesh has no faces")
    if not np.all(np.isfinite(loaded.vertices)):
        raise MeshError(f"{p}: mesh has non-finite vertex coordinates")
    if unit != "m":
        loaded.apply_scale(MESH_UNITS[unit])
    if obj_id is None:
        obj_id = bop_obj_id(p) or 0
    obj = make_object(loaded, name or p.stem, obj_id=obj_id, num_points=num_points)
    obj.source, obj.unit = str(p.resolve()), unit
    return obj


def object_fingerprint(obj: ObjectModel) -> str:
    """sha1 hex of the mesh's vertices, faces and colours (vertex/face colours or texture); of a
    ``centred`` model, of its file's fingerprint and ``file_offset`` (data rendered from it
    differs from data rendered from the file's frame)."""
    h = hashlib.sha1()
    if obj.file_fingerprint is not None:
        h.update(obj.file_fingerprint.encode())
        h.update(np.ascontiguousarray(obj.file_offset, dtype=np.float64).tobytes())
        return h.hexdigest()
    mesh = obj.mesh
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    h.update(str(kind).encode())
    if kind == "vertex":
        h.update(np.ascontiguousarray(visual.vertex_colors, dtype=np.uint8).tobytes())
    elif kind == "face":
        h.update(np.ascontiguousarray(visual.face_colors, dtype=np.uint8).tobytes())
    elif kind == "texture":
        uv = getattr(visual, "uv", None)
        if uv is not None:
            h.update(np.ascontiguousarray(uv, dtype=np.float64).tobytes())
        image = texture_image(mesh)
        if image is not None:
            h.update(np.ascontiguousarray(image).tobytes())
    return h.hexdigest()


def texture_image(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """(H, W, 3|4) uint8 base-colour texture of a textured mesh, or None."""
    material = getattr(mesh.visual, "material", None)
    if material is None:
        return None
    image = getattr(material, "image", None)
    if image is None:
        image = getattr(material, "baseColorTexture", None)
    if image is None:
        return None
    mode = getattr(image, "mode", None)  # PIL image: palette / grey / 16-bit -> RGB(A)
    if mode is not None and mode not in ("RGB", "RGBA"):
        has_alpha = mode in ("LA", "PA") or (mode == "P" and "transparency" in image.info)
        image = image.convert("RGBA" if has_alpha else "RGB")
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    return arr.astype(np.uint8, copy=False)


def check_size(diameter: float, where: str | Path, unit: str) -> None:
    """MeshError if ``diameter`` (metres, read with ``unit``) is outside ``SIZE_RANGE``, naming
    the unit that would bring it inside (the one nearest the range's middle)."""
    lo, hi = SIZE_RANGE
    if lo <= diameter <= hi:
        return
    raw = diameter / MESH_UNITS[unit]  # in the file's own numbers
    fits = {u: raw * s for u, s in MESH_UNITS.items() if lo <= raw * s <= hi}
    if fits:
        best = min(fits, key=lambda u: abs(np.log(fits[u] / np.sqrt(lo * hi))))
        hint = f"the file is probably in {best} (--unit {best} gives {fits[best]:.3g} m)"
    else:
        hint = f"no unit ({', '.join(MESH_UNITS)}) makes it plausible"
    raise MeshError(
        f"{where}: diameter {diameter:.4g} m with --unit {unit} is outside 1 cm - 2 m: {hint}; "
        "pass --allow-size to use it as it is"
    )


def get_object(name_or_path: str, unit: str = "m", allow_size: bool = False) -> ObjectModel:
    """A built-in object by name, or a mesh file (``unit`` = file unit); MeshError otherwise,
    also when a mesh's diameter is outside 1 cm - 2 m unless ``allow_size`` (``check_size``)."""
    if name_or_path in BUILTIN_OBJECTS:
        return builtin_object(name_or_path)
    p = Path(name_or_path)
    if p.suffix.lower() in MESH_SUFFIXES or p.exists():
        obj = load_mesh(p, unit=unit)
        if not allow_size:
            check_size(obj.diameter, p, unit)
        return obj
    raise MeshError(
        f"{name_or_path}: neither a built-in object ({', '.join(BUILTIN_OBJECTS)}) "
        "nor a mesh file (.ply, .obj, .stl)"
    )


# ----------------------------------------------------------------------------- built-ins

ColourFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _rgb(*c: int) -> np.ndarray:
    return np.array(c, dtype=np.uint8)


def _solid(colour: np.ndarray) -> ColourFn:
    def fn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.broadcast_to(colour, (len(a), 3)).copy()

    return fn


class _MeshBuilder:
    """Accumulates coloured triangles; ``finish`` makes a vertex-coloured Trimesh.

    Each face has one colour; vertices are shared only between faces of the same colour, so
    colour regions keep sharp borders.
    """

    def __init__(self) -> None:
        self.tris: list[np.ndarray] = []  # (F, 3, 3) corner positions
        self.cols: list[np.ndarray] = []  # (F, 3) uint8

    def add(self, tris: np.ndarray, cols: np.ndarray, transform: np.ndarray | None = None) -> None:
        tris = np.asarray(tris, dtype=np.float64)
        if transform is not None:
            tris = tris @ transform[:3, :3].T + transform[:3, 3]
        self.tris.append(tris)
        self.cols.append(np.asarray(cols, dtype=np.uint8).reshape(-1, 3))

    def quad_grid(
        self,
        origin: np.ndarray,
        eu: np.ndarray,
        ev: np.ndarray,
        nu: int,
        nv: int,
        colour: ColourFn,
        transform: np.ndarray | None = None,
    ) -> None:
        """A planar nu x nv grid of cells; normal = eu x ev; colour(s, t) at cell centres."""
        o, eu, ev = (np.asarray(x, dtype=np.float64) for x in (origin, eu, ev))
        i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        i, j = i.ravel(), j.ravel()

        def pt(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return o + (a / nu)[:, None] * eu + (b / nv)[:, None] * ev

        a, b, c, d = pt(i, j), pt(i + 1, j), pt(i + 1, j + 1), pt(i, j + 1)
        cols = colour((i + 0.5) / nu, (j + 0.5) / nv)
        tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        self.add(tris, np.concatenate([cols, cols]), transform)

    def box(
        self,
        lo: tuple[float, float, float],
        hi: tuple[float, float, float],
        colours: dict[str, ColourFn],
        cell: float = 0.01,
        transform: np.ndarray | None = None,
    ) -> None:
        """Axis-aligned box with outward faces; ``colours`` keys "+x" "-x" "+y" "-y" "+z" "-z"
        get (s, t) in [0, 1]^2 = (right, up) as seen from outside ("+z": s along +x, t along +y;
        "-z": s along +x, t along -y)."""
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        sx, sy, sz = x1 - x0, y1 - y0, z1 - z0

        def n(length: float) -> int:
            return max(1, round(length / cell))

        faces = {
            "+x": ((x1, y0, z0), (0, sy, 0), (0, 0, sz), n(sy), n(sz)),
            "-x": ((x0, y1, z0), (0, -sy, 0), (0, 0, sz), n(sy), n(sz)),
            "+y": ((x1, y1, z0), (-sx, 0, 0), (0, 0, sz), n(sx), n(sz)),
            "-y": ((x0, y0, z0), (sx, 0, 0), (0, 0, sz), n(sx), n(sz)),
            "+z": ((x0, y0, z1), (sx, 0, 0), (0, sy, 0), n(sx), n(sy)),
            "-z": ((x0, y1, z0), (sx, 0, 0), (0, -sy, 0), n(sx), n(sy)),
        }
        for key, (o, eu, ev, nu, nv) in faces.items():
            self.quad_grid(np.array(o), np.array(eu), np.array(ev), nu, nv, colours[key], transform)

    def revolve(
        self,
        radius: float,
        z_edges: np.ndarray,
        nseg: int,
        colour: ColourFn,
        inward: bool = False,
        transform: np.ndarray | None = None,
    ) -> None:
        """Cylinder wall about z between consecutive ``z_edges``; colour(theta, z) per cell."""
        k, j = np.meshgrid(np.arange(nseg), np.arange(len(z_edges) - 1), indexing="ij")
        k, j = k.ravel(), j.ravel()
        th = 2 * np.pi * np.arange(nseg + 1) / nseg
        z = np.asarray(z_edges, dtype=np.float64)

        def pt(kk: np.ndarray, jj: np.ndarray) -> np.ndarray:
            return np.stack([radius * np.cos(th[kk]), radius * np.sin(th[kk]), z[jj]], axis=1)

        a, b, c, d = pt(k, j), pt(k + 1, j), pt(k + 1, j + 1), pt(k, j + 1)
        cols = colour((th[k] + th[k + 1]) / 2, (z[j] + z[j + 1]) / 2)
        t1, t2 = (
            (np.stack([a, c, b], 1), np.stack([a, d, c], 1))
            if inward
            else (
                np.stack([a, b, c], 1),
                np.stack([a, c, d], 1),
            )
        )
        self.add(np.concatenate([t1, t2]), np.concatenate([cols, cols]), transform)

    def disk(
        self,
        z: float,
        r_edges: np.ndarray,
        nseg: int,
        colour: ColourFn,
        up: bool = True,
        transform: np.ndarray | None = None,
    ) -> None:
        """Flat rings at height z between consecutive ``r_edges`` (r_edges[0] may be 0),
        facing +z (``up``) or -z; colour(theta, r) per cell."""
        th = 2 * np.pi * np.arange(nseg + 1) / nseg
        r = np.asarray(r_edges, dtype=np.float64)
        k, j = np.meshgrid(np.arange(nseg), np.arange(len(r) - 1), indexing="ij")
        k, j = k.ravel(), j.ravel()

        def pt(kk: np.ndarray, jj: np.ndarray) -> np.ndarray:
            return np.stack(
                [r[jj] * np.cos(th[kk]), r[jj] * np.sin(th[kk]), np.full(len(kk), z)], axis=1
            )

        a, b, c, d = pt(k, j), pt(k, j + 1), pt(k + 1, j + 1), pt(k + 1, j)
        cols = colour((th[k] + th[k + 1]) / 2, (r[j] + r[j + 1]) / 2)
        t1, t2 = np.stack([a, b, c], 1), np.stack([a, c, d], 1)
        keep2 = r[j] > 0  # the innermost ring of a full disk is a fan of single triangles
        tris = np.concatenate([t1, t2[keep2]])
        cc = np.concatenate([cols, cols[keep2]])
        if not up:
            tris = tris[:, ::-1]
        self.add(tris, cc, transform)

    def finish(self) -> trimesh.Trimesh:
        """Merge corners with equal position and colour; centre at the bounding-box centre."""
        tris = np.concatenate(self.tris)
        cols = np.concatenate(self.cols)
        area = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        keep = area > 1e-12
        tris, cols = tris[keep], cols[keep]
        corners = tris.reshape(-1, 3)
        ccols = np.repeat(cols, 3, axis=0)
        key = np.concatenate([np.round(corners * 1e8), ccols.astype(np.float64)], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        vertices = corners[first]
        vcols = np.concatenate([ccols[first], np.full((len(first), 1), 255, np.uint8)], axis=1)
        faces = inverse.reshape(-1, 3)
        centre = bounding_box_centre(vertices)
        return trimesh.Trimesh(
            vertices=vertices - centre, faces=faces, vertex_colors=vcols, process=False
        )


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    T = np.eye(4)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    T[i, i], T[i, j], T[j, i], T[j, j] = c, -s, s, c
    return T


def _translate(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _bands(edges: list[float], colours: list[np.ndarray]) -> ColourFn:
    """Colour chosen by which interval of ``edges`` the second coordinate falls in."""
    e = np.asarray(edges, dtype=np.float64)
    table = np.stack(colours)

    def fn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        idx = np.clip(np.searchsorted(e, b, side="right") - 1, 0, len(table) - 1)
        return table[idx]

    return fn


def _paint(
    base: np.ndarray, shapes: list[tuple[Callable[..., np.ndarray], np.ndarray]]
) -> ColourFn:
    """Base colour, then each (predicate(a, b) -> bool mask, colour) painted in order."""

    def fn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = np.broadcast_to(base, (len(a), 3)).copy()
        for pred, col in shapes:
            out[pred(a, b)] = col
        return out

    return fn


def _rect(a0: float, a1: float, b0: float, b1: float) -> Callable[..., np.ndarray]:
    return lambda a, b: (a >= a0) & (a <= a1) & (b >= b0) & (b <= b1)


def _circle(ca: float, cb: float, r: float, sa: float = 1.0, sb: float = 1.0):
    """Disc in scaled coordinates (sa, sb convert the face coordinates to metres)."""
    return lambda a, b: ((a - ca) * sa) ** 2 + ((b - cb) * sb) ** 2 <= (r**2)


# palette
WHITE, BLACK = _rgb(235, 235, 230), _rgb(25, 25, 28)
CREAM, RED, BLUE = _rgb(236, 226, 200), _rgb(200, 30, 35), _rgb(30, 60, 165)
NAVY, YELLOW, GREEN = _rgb(25, 40, 110), _rgb(245, 200, 30), _rgb(40, 145, 60)
ORANGE, SILVER, GREY = _rgb(230, 110, 25), _rgb(190, 192, 198), _rgb(95, 95, 100)
DARK, BROWN = _rgb(55, 55, 60), _rgb(110, 60, 25)


def _build_can() -> trimesh.Trimesh:
    radius, height, nseg = 0.033, 0.100, 64
    b = _MeshBuilder()
    z_edges = [0.0, 0.006, 0.030, 0.036, 0.070, 0.074, 0.092, 0.100]
    cols = [SILVER, BLUE, WHITE, RED, YELLOW, GREEN, SILVER]
    b.revolve(radius, np.array(z_edges), nseg, _bands(z_edges, cols))
    top_r = [0.0, 0.012, 0.014, 0.030, radius]
    b.disk(height, np.array(top_r), nseg, _bands(top_r, [_rgb(215, 215, 220), GREY, SILVER, DARK]))
    bot_r = [0.0, 0.025, radius]
    b.disk(0.0, np.array(bot_r), nseg, _bands(bot_r, [DARK, _rgb(180, 110, 60)]), up=False)
    return b.finish()


def _build_box() -> trimesh.Trimesh:
    sx, sy, sz = 0.19, 0.06, 0.25
    cell = 0.0079
    # s, t in [0, 1] over each face; convert to metres with the face size for round shapes
    front = _paint(
        _rgb(215, 55, 30),
        [
            (_rect(0.06, 0.94, 0.80, 0.94), YELLOW),
            (_rect(0.12, 0.22, 0.83, 0.91), RED),
            (_rect(0.30, 0.40, 0.83, 0.91), RED),
            (_rect(0.48, 0.52, 0.83, 0.91), RED),
            (_rect(0.62, 0.80, 0.83, 0.91), RED),
            (_circle(0.40, 0.42, 0.055, sx, sz), WHITE),
            (_circle(0.40, 0.42, 0.035, sx, sz), _rgb(200, 150, 60)),
            (_circle(0.80, 0.62, 0.018, sx, sz), BLUE),
            (_rect(0.0, 1.0, 0.0, 0.08), GREEN),
        ],
    )
    back = _paint(
        WHITE,
        [
            (_rect(0.10, 0.90, 0.86, 0.90), DARK),
            (_rect(0.10, 0.70, 0.78, 0.82), DARK),
            (_rect(0.10, 0.85, 0.70, 0.74), DARK),
            (_rect(0.10, 0.55, 0.62, 0.66), DARK),
            (_rect(0.08, 0.35, 0.10, 0.35), GREEN),
            (
                lambda a, b: (a > 0.6) & (a < 0.92) & (b > 0.08) & (b < 0.22) & ((a * 60) % 2 < 1),
                BLACK,
            ),
        ],
    )
    left = _paint(
        BLUE,
        [(_rect(0.0, 1.0, 0.70, 0.75), WHITE), (_rect(0.0, 1.0, 0.80, 0.85), WHITE)],
    )
    right = _paint(YELLOW, [(_rect(0.3, 0.7, 0.05, 0.40), RED)])
    top = _paint(ORANGE, [(_rect(0.0, 0.2, 0.0, 1.0), BROWN)])
    bottom = _paint(_rgb(150, 150, 150), [(_rect(0.0, 0.3, 0.0, 0.4), BLACK)])
    b = _MeshBuilder()
    b.box(
        (0.0, 0.0, 0.0),
        (sx, sy, sz),
        {"-y": front, "+y": back, "-x": left, "+x": right, "+z": top, "-z": bottom},
        cell=cell,
    )
    return b.finish()


def _build_mug() -> trimesh.Trimesh:
    r_out, r_in, height, floor = 0.041, 0.0365, 0.095, 0.007
    nseg = 72
    b = _MeshBuilder()

    # print on the -x side (theta ~ pi), opposite the handle (+x): arc length u (m) from its
    # centre, height z (m); asymmetric so that it also fixes the mirror image
    def arc(th: np.ndarray) -> np.ndarray:
        return (th - np.pi) * r_out

    outer = _paint(
        CREAM,
        [
            (lambda th, z: z > 0.087, NAVY),
            (lambda th, z: (arc(th) + 0.006) ** 2 + (z - 0.056) ** 2 <= 0.013**2, RED),
            (lambda th, z: (np.abs(arc(th)) <= 0.022) & (z >= 0.026) & (z <= 0.035), BLUE),
            (
                lambda th, z: (np.abs(arc(th) - 0.017) <= 0.005) & (np.abs(z - 0.070) <= 0.005),
                GREEN,
            ),
        ],
    )
    b.revolve(r_out, np.arange(0.0, height + 1e-9, 0.005), nseg, outer)
    inner_col = _rgb(205, 220, 235)
    b.revolve(r_in, np.array([floor, 0.05, height]), nseg, _solid(inner_col), inward=True)
    b.disk(height, np.array([r_in, r_out]), nseg, _solid(NAVY), up=True)
    b.disk(floor, np.array([0.0, 0.02, r_in]), nseg, _solid(inner_col), up=True)
    b.disk(
        0.0,
        np.array([0.0, 0.03, r_out]),
        nseg,
        _bands([0.0, 0.03], [_rgb(170, 150, 120), BROWN]),
        up=False,
    )

    # handle: elliptic tube swept along a half ellipse in the xz plane, ends inside the wall
    m, n_sides = 16, 10
    xc, zc, ax, az = r_out - 0.004, 0.050, 0.032, 0.026
    phi = np.linspace(np.pi / 2, -np.pi / 2, m + 1)
    path = np.stack([xc + ax * np.cos(phi), np.zeros_like(phi), zc + az * np.sin(phi)], 1)
    tang = np.stack([-ax * np.sin(phi), np.zeros_like(phi), az * np.cos(phi)], 1)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    binorm = np.array([0.0, 1.0, 0.0])
    normal = np.cross(binorm, tang)
    psi = 2 * np.pi * np.arange(n_sides + 1) / n_sides
    ring = (
        path[:, None, :]
        + 0.0055 * np.cos(psi)[None, :, None] * normal[:, None, :]
        + 0.008 * np.sin(psi)[None, :, None] * binorm
    )  # (m+1, n_sides+1, 3)
    k, s = np.meshgrid(np.arange(m), np.arange(n_sides), indexing="ij")
    k, s = k.ravel(), s.ravel()
    a, bb, c, d = ring[k, s], ring[k + 1, s], ring[k + 1, s + 1], ring[k, s + 1]
    tris = np.concatenate([np.stack([a, bb, c], 1), np.stack([a, c, d], 1)])
    centres = np.concatenate([(path[k] + path[k + 1]) / 2] * 2)
    fn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    flip = ((tris.mean(1) - centres) * fn).sum(1) < 0
    tris[flip] = tris[flip][:, ::-1]
    b.add(tris, np.broadcast_to(NAVY, (len(tris), 3)))
    return b.finish()


def _build_drill() -> trimesh.Trimesh:
    b = _MeshBuilder()
    along_x = _rot("y", np.pi / 2)  # maps the builders' z axis onto +x
    # motor housing: cylinder radius 0.028 along x from -0.08 to 0.06 (theta measured in the
    # cylinder frame: after the rotation, theta = pi/2 points to +y)
    r_body = 0.028

    def body_colour(th: np.ndarray, z: np.ndarray) -> np.ndarray:
        x = z - 0.08  # cylinder-frame z -> drill x
        out = np.broadcast_to(YELLOW, (len(th), 3)).copy()
        out[x > 0.035] = BLACK
        side = np.abs(np.angle(np.exp(1j * (th - np.pi / 2))))  # distance from +y direction
        logo = (side < 0.45) & (x > -0.045) & (x < 0.012)
        out[logo] = WHITE
        out[logo & (x > -0.035) & (x < 0.0) & (side < 0.2)] = RED
        vents = (side > 1.2) & (side < 1.9) & (x < -0.06) & ((np.floor(x / 0.004)) % 2 == 0)
        out[vents] = BLACK
        return out

    body_t = _translate(-0.08, 0.0, 0.0) @ along_x
    b.revolve(r_body, np.arange(0.0, 0.1401, 0.01), 32, body_colour, transform=body_t)
    b.disk(
        0.0,
        np.array([0.0, 0.015, r_body]),
        32,
        _bands([0.0, 0.015], [DARK, BLACK]),
        up=False,
        transform=body_t,
    )
    b.disk(0.14, np.array([0.0, r_body]), 32, _solid(BLACK), up=True, transform=body_t)
    # chuck and bit
    chuck_t = _translate(0.06, 0.0, 0.0) @ along_x
    b.revolve(
        0.016,
        np.array([0.0, 0.025, 0.035]),
        24,
        _bands([0.0, 0.025], [DARK, SILVER]),
        transform=chuck_t,
    )
    b.disk(0.035, np.array([0.0, 0.005, 0.016]), 24, _solid(SILVER), up=True, transform=chuck_t)
    bit_t = _translate(0.095, 0.0, 0.0) @ along_x
    b.revolve(0.004, np.array([0.0, 0.05]), 12, _solid(_rgb(205, 205, 215)), transform=bit_t)
    b.disk(0.05, np.array([0.0, 0.004]), 12, _solid(_rgb(205, 205, 215)), up=True, transform=bit_t)
    # grip: black with yellow side panels; red trigger on its front (+x) face
    grip_side = _paint(BLACK, [(_rect(0.25, 0.75, 0.15, 0.75), YELLOW)])
    b.box(
        (-0.055, -0.015, -0.135),
        (-0.02, 0.015, -0.015),
        {"+x": _solid(BLACK), "-x": _solid(BLACK), "+y": grip_side, "-y": _solid(BLACK),
         "+z": _solid(BLACK), "-z": _solid(BLACK)},
        cell=0.01,
    )  # fmt: skip
    b.box(
        (-0.02, -0.006, -0.05),
        (-0.008, 0.006, -0.03),
        {k: _solid(RED) for k in ("+x", "-x", "+y", "-y", "+z", "-z")},
        cell=0.01,
    )
    # battery: black with a yellow band on top edge and a green gauge on its rear face
    bat_side = _paint(BLACK, [(_rect(0.0, 1.0, 0.75, 1.0), YELLOW)])
    bat_rear = _paint(
        BLACK, [(_rect(0.3, 0.7, 0.4, 0.6), GREEN), (_rect(0.0, 1.0, 0.75, 1.0), YELLOW)]
    )
    b.box(
        (-0.075, -0.033, -0.175),
        (0.005, 0.033, -0.135),
        {"+x": bat_side, "-x": bat_rear, "+y": bat_side, "-y": bat_side,
         "+z": _solid(BLACK), "-z": _solid(GREY)},
        cell=0.01,
    )  # fmt: skip
    return b.finish()


_BUILDERS: dict[str, Callable[[], trimesh.Trimesh]] = {
    "mug": _build_mug,
    "box": _build_box,
    "can": _build_can,
    "drill": _build_drill,
}


def builtin_object(name: str) -> ObjectModel:
    """A built-in procedural object ("mug", "box", "can", "drill"); a fresh copy each call."""
    if name not in BUILTIN_OBJECTS:
        raise MeshError(
            f"{name}: unknown built-in object (choose from {', '.join(BUILTIN_OBJECTS)})"
        )
    mesh = _BUILDERS[name]()
    sym_c: list[dict[str, Any]] = []
    if name == "can":
        sym_c = [{"axis": (0.0, 0.0, 1.0), "offset": (0.0, 0.0, 0.0)}]
    return make_object(mesh, name, obj_id=BUILTIN_OBJECTS[name], symmetries_continuous=sym_c)
