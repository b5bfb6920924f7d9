"""The silhouette: how well a hypothesis's projected outline fits the image.

Neither network sees a wrong depth well: their crops are scale-normalised, so a hypothesis 5 %
too far shows the object only 5 % larger in its crop, and the autoencoder's cosine barely
moves (docs/chpf-ablations.md). The object's outline does: projected at the true pose, its
silhouette separates the object from its surroundings; moved along the ray (or turned), it
cuts through one or the other. For N hypotheses R (N,3,3), t (N,3) metres:

1. project the bundle's outline points (chpf.tracking.model_outline, scaled by
   ``outline_scale``) at each pose and take their 2D convex hull;
2. sample ``samples`` points evenly along the hull with its outward normals n;
3. the alignment a, one of two cues:
   - ``SilhouetteRegion`` (CH-PF's default): the contrast 1 - BC(h_in, h_out) of the colour
     histograms of two bands of points just inside and just outside the hull, as
     region-based trackers (PWP3D, RBOT) separate an object from its background;
   - ``SilhouetteEdges``: the mean |grad I(u) . n| over the samples (Sobel gradients of the
     grey image, bilinear; 0 off the image);
4. CH-PF's option ``chpf.c_silhouette`` (a power p) adds C_sil = 1 - (a / max a)^p, the max
   over the hypotheses weighed together and the box's single-frame estimate: the evidence
   against a hypothesis whose outline fits the image worse than the best of them does.

For a convex object the hull is the silhouette; for another it is the silhouette's hull, whose
straight runs over concavities cross background. A background of long straight edges (a brick
wall) offers a box's outline places to lie on: there the edges mislead, the region contrast
does not (its colours lie on both sides of a wrong outline; docs/chpf-ablations.md).
"""

from __future__ import annotations

import cv2
import numpy as np

from chpf.bundle import Bundle
from chpf.tracking.model_outline import project_outline


def outline_scale(bundle: Bundle, points: np.ndarray, views: int = 500) -> float:
    """Factor that shrinks the outline points (M,3) (object frame) to the object's size.

    The points come from depth pixels of the codebook's crops, each the mean of an f x f block
    valid when at least half of it is (chpf.bundle): a block that the silhouette covers from
    ceil(f/2) of its f sub-columns on is counted, so the silhouette spreads on average by
    (0.5 - (ceil(f/2) - 0.5) / f) pixels per side, and the hull of the points from many views
    takes the outermost of them. This is the median, over ``views`` codebook entries, of the
    entry's silhouette extent (occupied columns and rows, less that spread) over the extent of
    the points projected at the entry's pose."""
    if len(points) < 2:
        return 1.0
    f = max(bundle.spec.size // bundle.depth_size, 1)
    spread = 2.0 * (0.5 - (np.ceil(f / 2.0) - 0.5) / f)
    idx = np.unique(np.linspace(0, bundle.codebook_size - 1, views).round().astype(np.int64))
    t = np.broadcast_to(bundle.spec.translation, (len(idx), 3))
    uv = project_outline(points, bundle.grid.rotations[idx], t, bundle.depth_K, 1e-6)
    sides = uv.max(axis=1) - uv.min(axis=1)  # (V,2) projected extents, pixels
    ratios = []
    for depth, projected in zip(bundle.codebook_depth(idx), sides, strict=True):
        mask = depth > 0
        if not mask.any():
            continue
        for axis, side in ((0, projected[0]), (1, projected[1])):
            occupied = np.flatnonzero(mask.any(axis=axis))
            ratios.append((occupied[-1] - occupied[0] + 1 - spread) / max(side, 1e-6))
    return float(np.median(ratios)) if ratios else 1.0


def edge_gradients(rgb: np.ndarray) -> np.ndarray:
    """Sobel gradients (2,H,W) float32 (x, y) of the grey image of rgb (H,W,3) uint8, per
    pixel in grey levels / 255."""
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    return np.stack(
        [cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)]
    )


def hull_samples(uv: np.ndarray, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``samples`` points (N,S,2) evenly spaced along the 2D convex hull of each point set uv
    (N,M,2) pixels, and the hull's outward unit normals (N,S,2) there. A hull of fewer than 3
    vertices gives its points' mean with zero normals."""
    hulls = [cv2.convexHull(p.astype(np.float32)).reshape(-1, 2) for p in uv]
    n, h_max = len(hulls), max(len(h) for h in hulls)
    verts = np.empty((n, h_max + 1, 2))  # each hull closed, padded with its first vertex
    count = np.array([len(h) for h in hulls])
    for i, h in enumerate(hulls):
        verts[i, : len(h)] = h
        verts[i, len(h) :] = h[0]
    edges = np.diff(verts, axis=1)  # (N,H,2); the padding's edges have length 0
    lengths = np.linalg.norm(edges, axis=2)
    cum = np.concatenate([np.zeros((n, 1)), np.cumsum(lengths, axis=1)], axis=1)  # (N,H+1)
    total = np.maximum(cum[:, -1:], 1e-9)
    at = (np.arange(samples) + 0.5) / samples * total  # (N,S)
    # one searchsorted for all rows: row i's positions shifted by 2 i (each row spans [0, 1])
    shift = 2.0 * np.arange(n)[:, None]
    flat = np.searchsorted((cum / total + shift).ravel(), (at / total + shift).ravel(), "right")
    seg = np.clip(flat.reshape(n, samples) - 1 - np.arange(n)[:, None] * (h_max + 1), 0, h_max - 1)
    rows = np.arange(n)[:, None]
    frac = (at - cum[rows, seg]) / np.maximum(lengths[rows, seg], 1e-9)
    points = verts[rows, seg] + frac[..., None] * edges[rows, seg]
    # cv2.convexHull orders the points clockwise in image coordinates (y down), so the
    # outward normal of an edge (dx, dy) is (dy, -dx) up to orientation: fix it by the centre
    normals = np.stack([edges[rows, seg, 1], -edges[rows, seg, 0]], axis=-1)
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-9)
    valid = np.arange(h_max)[None, :] < count[:, None]  # (N,H)
    centre = (verts[:, :h_max] * valid[..., None]).sum(axis=1) / count[:, None]
    outward = np.sign(np.sum((points - centre[:, None]) * normals, axis=-1, keepdims=True))
    normals = normals * np.where(outward == 0, 1.0, outward)
    flat_hull = count < 3
    if flat_hull.any():
        points[flat_hull] = uv[flat_hull].mean(axis=1, keepdims=True)
        normals[flat_hull] = 0.0
    return points, normals


def sample_bilinear(grad: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Gradients (P,2) of grad (2,H,W) at points (P,2) pixels (x, y), bilinear; 0 outside."""
    h, w = grad.shape[1:]
    x, y = points[:, 0], points[:, 1]
    inside = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, h - 2)
    fx = np.clip(x - x0, 0.0, 1.0)[None]
    fy = np.clip(y - y0, 0.0, 1.0)[None]
    g = (
        grad[:, y0, x0] * (1 - fx) * (1 - fy)
        + grad[:, y0, x0 + 1] * fx * (1 - fy)
        + grad[:, y0 + 1, x0] * (1 - fx) * fy
        + grad[:, y0 + 1, x0 + 1] * fx * fy
    )
    return np.where(inside[None], g, 0.0).T


class SilhouetteEdges:
    """How well each pose hypothesis's outline meets the image's edges (module docstring).

    points: (M,3) metres, object frame, the outline points at the object's size (the bundle's
    ``outline_points`` times ``outline_scale``). samples: points along the hull.
    """

    def __init__(self, points: np.ndarray, samples: int = 64) -> None:
        self.points = np.asarray(points, dtype=np.float64)
        self.samples = int(samples)

    def alignment(
        self, rgb: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray, z_min: float
    ) -> np.ndarray:
        """Alignment a (N,) >= 0 of hypotheses R (N,3,3), t (N,3) metres on rgb (H,W,3) uint8
        with intrinsics K (3,3): mean |grad I . n| over ``samples`` points of the projected
        outline's hull (grey levels / 255 per pixel, Sobel; the outline's depths clamped to at
        least z_min metres)."""
        grad = edge_gradients(rgb)
        uv = project_outline(self.points, R, t, np.asarray(K, dtype=np.float64), z_min)
        pts, normals = hull_samples(uv, self.samples)  # (N,S,2) each
        g = sample_bilinear(grad, pts.reshape(-1, 2)).reshape(pts.shape)
        return np.abs(np.sum(g * normals, axis=-1)).mean(axis=1)


def colour_codes(rgb: np.ndarray, bins: int) -> np.ndarray:
    """Colour bin (...) int64 of each pixel of rgb (..., 3) uint8: ``bins`` levels per channel,
    bins**3 codes."""
    q = rgb.astype(np.int64) * bins // 256
    return (q[..., 0] * bins + q[..., 1]) * bins + q[..., 2]


class SilhouetteRegion:
    """How well each pose hypothesis's outline separates the object's colours from the
    background's: the region contrast 1 - BC(h_in, h_out), BC the Bhattacharyya coefficient of
    the colour histograms of two bands of points, just inside and just outside the projected
    outline's hull (offsets along its normals, fractions of the hull's mean radius). At the
    true pose the inner band is the object and the outer band its surroundings; a hypothesis
    too near (too large) puts background in both, too far (too small) object in both, so the
    contrast falls either way. Unlike the edges, a textured background (a brick wall) does
    not offer the outline places to lie on: its colours are on both sides of a wrong outline.

    points: (M,3) metres, object frame, as SilhouetteEdges'. samples: points along the hull.
    offsets: the bands' distances from the hull, fractions of its mean radius. bins: colour
    levels per channel.
    """

    def __init__(
        self,
        points: np.ndarray,
        samples: int = 64,
        offsets: tuple[float, ...] = (0.04, 0.1, 0.2),
        bins: int = 4,
    ) -> None:
        self.points = np.asarray(points, dtype=np.float64)
        self.samples = int(samples)
        self.offsets = np.asarray(offsets, dtype=np.float64)
        self.bins = int(bins)

    def alignment(
        self, rgb: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray, z_min: float
    ) -> np.ndarray:
        """Region contrast a (N,) in [0, 1] of hypotheses R (N,3,3), t (N,3) metres on rgb
        (H,W,3) uint8 with intrinsics K (3,3) (the outline's depths clamped to at least z_min
        metres); points off the image take the nearest border pixel."""
        h, w = rgb.shape[:2]
        uv = project_outline(self.points, R, t, np.asarray(K, dtype=np.float64), z_min)
        pts, normals = hull_samples(uv, self.samples)  # (N,S,2) each
        radius = np.linalg.norm(pts - pts.mean(axis=1, keepdims=True), axis=-1).mean(axis=1)
        step = self.offsets[None, :, None, None] * radius[:, None, None, None] * normals[:, None]
        n, nbins = pts.shape[0], self.bins**3
        hists = []
        for sign in (-1.0, 1.0):  # inside, outside
            xy = np.rint(pts[:, None] + sign * step).astype(np.int64)  # (N,B,S,2)
            x = np.clip(xy[..., 0], 0, w - 1)
            y = np.clip(xy[..., 1], 0, h - 1)
            codes = colour_codes(rgb[y, x], self.bins)  # only the sampled pixels
            flat = codes.reshape(n, -1) + np.arange(n)[:, None] * nbins
            counts = np.bincount(flat.ravel(), minlength=n * nbins).reshape(n, nbins)
            hists.append(counts / counts.sum(axis=1, keepdims=True))
        return 1.0 - np.sqrt(hists[0] * hists[1]).sum(axis=1)


def silhouette_counter_evidence(alignment: np.ndarray, power: float) -> np.ndarray:
    """C_sil (N,) in [0, 1] of alignments (N,) >= 0: 1 - (a / max a)^power; 0 for every
    hypothesis when no outline fits at all (every a is 0)."""
    top = float(np.max(alignment)) if alignment.size else 0.0
    if top <= 0.0:
        return np.zeros_like(alignment, dtype=np.float64)
    return 1.0 - (alignment / top) ** power
