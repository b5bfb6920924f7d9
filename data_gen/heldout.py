"""The held-out scene family of the test sequences: what the training generator never draws.

A benchmark should measure generalisation, not memory. The training data (``chpf-gen-data
pairs`` / ``ae``) draws backgrounds from six procedural texture kinds (fractal noise, stripes
and checks, marble, clutter of circles/rectangles/lines, gradients, blotches) or a user image
folder; occluders from the built-in objects (mug, box, can, drill) and flat 2D blobs (ellipses,
star polygons, rectangles, strokes); lighting from one white directional light of intensity
1.5-6.0 with ambient 0.15-0.6. The held-out family (``sequences.family: heldout``) draws:

- walls: brick courses with mortar, Voronoi cells with dark seams, concentric rings, or rows of
  glyph-like marks on paper (``WALL_KINDS``);
- occluders: 3D shapes that are none of the built-ins and have holes or crossings no 2D blob
  has: a torus, a capsule (rod), a picture frame and a cross (``OCCLUDER_SHAPES``, BOP ids
  from ``FIRST_OCCLUDER_ID``), one per scene;
- lighting: dim (intensity 0.8-1.4) or glaring (6.5-9.0) grazing light with little ambient
  (0.03-0.12) and a coloured cast (per-channel gains 0.65-1.0, warm or cool), all outside the
  training ranges.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np
import trimesh

FAMILIES = ("training", "heldout")
WALL_KINDS = ("bricks", "voronoi", "rings", "glyphs")
OCCLUDER_SHAPES = ("torus", "capsule", "frame", "cross")
FIRST_OCCLUDER_ID = 101
"""BOP obj_id of the first held-out occluder (the others follow in OCCLUDER_SHAPES order)."""


# ----------------------------------------------------------------------------- walls


def _colour(rng: np.random.Generator, lo: int = 30, hi: int = 230) -> np.ndarray:
    return rng.uniform(lo, hi, 3).astype(np.float32)


def _bricks(rng: np.random.Generator, size: int) -> np.ndarray:
    img = np.empty((size, size, 3), np.float32)
    img[:] = _colour(rng, 150, 230)  # mortar
    bh = int(rng.integers(size // 24, size // 10))
    bw = int(bh * rng.uniform(1.8, 3.2))
    gap = max(2, bh // 8)
    base = _colour(rng, 60, 200)
    for row, y in enumerate(range(0, size, bh)):
        shift = (bw // 2) * (row % 2)
        for x in range(-shift, size, bw):
            c = np.clip(base * rng.uniform(0.75, 1.25, 3), 0, 255)
            cv2.rectangle(img, (x + gap, y + gap), (x + bw - gap, y + bh - gap), c.tolist(), -1)
    return img


def _voronoi(rng: np.random.Generator, size: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    k = int(rng.integers(20, 120))
    seeds = rng.uniform(0, size, (k, 2))
    yy, xx = np.mgrid[0:size, 0:size]
    pix = np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float64)
    d, idx = cKDTree(seeds).query(pix, k=2)
    cols = np.stack([_colour(rng) for _ in range(k)])
    img = cols[idx[:, 0]].reshape(size, size, 3)
    seam = (d[:, 1] - d[:, 0]).reshape(size, size) < rng.uniform(1.5, 4.0) * size / 512
    img[seam] = _colour(rng, 0, 50)
    return img


def _rings(rng: np.random.Generator, size: int) -> np.ndarray:
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    cx, cy = rng.uniform(0.2, 0.8, 2)
    r = np.hypot(xx - cx, yy - cy)
    theta = np.arctan2(yy - cy, xx - cx)
    field = 0.5 + 0.5 * np.sin(2 * np.pi * rng.uniform(6, 25) * r + rng.uniform(0, 3) * theta)
    c0, c1 = _colour(rng), _colour(rng)
    return c0 * (1 - field[..., None]) + c1 * field[..., None]


def _glyphs(rng: np.random.Generator, size: int) -> np.ndarray:
    img = np.empty((size, size, 3), np.float32)
    img[:] = _colour(rng, 190, 250)  # paper
    ink = _colour(rng, 0, 90)
    line = int(rng.integers(max(4, size // 40), max(5, size // 16)))
    for y in range(line, size - line, int(1.6 * line)):
        x = int(rng.integers(0, line))
        while x < size - line:
            w = int(rng.integers(max(2, line // 3), line))
            if rng.random() < 0.85:  # a glyph: a few strokes in its cell
                for _ in range(int(rng.integers(1, 4))):
                    p = (x + int(rng.integers(0, w)), y + int(rng.integers(0, line)))
                    q = (x + int(rng.integers(0, w)), y + int(rng.integers(0, line)))
                    cv2.line(img, p, q, ink.tolist(), max(1, line // 8))
            x += w + int(rng.integers(1, max(2, line // 2)))
    return img


_WALLS = {"bricks": _bricks, "voronoi": _voronoi, "rings": _rings, "glyphs": _glyphs}


def wall_texture(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) uint8 wall of a held-out kind (WALL_KINDS) drawn with ``rng``."""
    kind = WALL_KINDS[int(rng.integers(0, len(WALL_KINDS)))]
    img = _WALLS[kind](rng, size)
    return np.clip(img, 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------- occluders


def _painted(mesh: trimesh.Trimesh, seed: int) -> trimesh.Trimesh:
    """The mesh with two-colour bands along its longest axis as vertex colours."""
    rng = np.random.default_rng(seed)
    v = np.asarray(mesh.vertices)
    axis = int(np.argmax(np.ptp(v, axis=0)))
    band = (np.floor(v[:, axis] / 0.03) % 2).astype(int)
    cols = np.stack([rng.uniform(20, 235, 3), rng.uniform(20, 235, 3)])[band]
    rgba = np.concatenate([cols, np.full((len(v), 1), 255.0)], 1).astype(np.uint8)
    return trimesh.Trimesh(v, mesh.faces, vertex_colors=rgba, process=False)


def _bars(extents: list[tuple[float, float, float]], offsets: list[tuple[float, ...]]):
    parts = []
    for e, o in zip(extents, offsets, strict=True):
        b = trimesh.creation.box(extents=e)
        b.apply_translation(o)
        parts.append(b)
    return trimesh.util.concatenate(parts)


def _shape_mesh(name: str) -> trimesh.Trimesh:
    if name == "torus":
        return trimesh.creation.torus(0.12, 0.05, major_sections=48, minor_sections=16)
    if name == "capsule":
        m = trimesh.creation.capsule(height=0.26, radius=0.065, count=[16, 16])
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        return m
    if name == "frame":
        s, w, d = 0.32, 0.09, 0.03
        return _bars(
            [(s, w, d), (s, w, d), (w, s - 2 * w, d), (w, s - 2 * w, d)],
            [(0, (s - w) / 2, 0), (0, -(s - w) / 2, 0), ((s - w) / 2, 0, 0), (-(s - w) / 2, 0, 0)],
        )
    return _bars([(0.34, 0.1, 0.04), (0.1, 0.3, 0.04)], [(0, 0, 0), (0, 0.05, 0)])  # cross


@cache
def _occluder(index: int):
    from chpf.objects import make_object

    name = OCCLUDER_SHAPES[index]
    mesh = _painted(_shape_mesh(name), seed=index)
    return make_object(mesh, f"heldout_{name}", obj_id=FIRST_OCCLUDER_ID + index)


def occluder_objects() -> list:
    """The held-out occluders as ObjectModels (obj_id FIRST_OCCLUDER_ID + i), fixed meshes."""
    return [_occluder(i) for i in range(len(OCCLUDER_SHAPES))]


def occluder_for_scene(rng: np.random.Generator):
    """The held-out occluder of one scene, drawn with ``rng``."""
    return _occluder(int(rng.integers(0, len(OCCLUDER_SHAPES))))


# ----------------------------------------------------------------------------- lighting


@dataclass(frozen=True)
class Lighting:
    """One scene's light: intensity, ambient, direction (3,) unit (OpenCV camera frame, the way
    the light travels) and tint (3,) per-channel gains of the coloured cast."""

    intensity: float
    ambient: float
    direction: np.ndarray
    tint: np.ndarray

    def apply_tint(self, rgb: np.ndarray) -> np.ndarray:
        """The frame (H, W, 3) uint8 under the coloured cast."""
        return np.clip(rgb.astype(np.float32) * self.tint, 0, 255).astype(np.uint8)


def lighting(rng: np.random.Generator) -> Lighting:
    """A held-out light (module docstring): dim or glaring, grazing, little ambient, tinted."""
    intensity = rng.uniform(0.8, 1.4) if rng.random() < 0.5 else rng.uniform(6.5, 9.0)
    a = rng.uniform(0, 2 * np.pi)
    d = np.array([np.cos(a), np.sin(a), rng.uniform(0.2, 0.6)])  # mostly sideways
    warm = np.array([1.0, rng.uniform(0.8, 0.9), rng.uniform(0.65, 0.8)])
    tint = warm if rng.random() < 0.5 else warm[::-1].copy()  # warm or cool cast
    return Lighting(
        float(intensity), float(rng.uniform(0.03, 0.12)), d / np.linalg.norm(d), tint.copy()
    )
