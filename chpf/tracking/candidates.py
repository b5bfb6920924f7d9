"""The candidate distribution phi_cand: where reinvigorated particles come from.

Orientations are uniform on SO(3) (or come from a ``RotationSource``, e.g.
chpf.tracking.codebook_candidates.CodebookRotations); the projection (u, v) of the translation
is uniform in the 2D detection box (or, with ``uv_fraction`` < 1, in the box's central part:
that fraction of its width and height around its centre); the depth z is

- RGB: uniform in ``z_range`` metres, or, when ``box_extent`` (the object's typical projected
  extent in metres) is known, uniform in ``z_box_factors`` times the depth at which the object
  would fill the box: z_box = fx * box_extent / max(w, h);
- RGB-D: the measured depth at (u, v) plus a uniform offset in ``depth_offset`` (the surface is
  in front of the centre). A measured depth beyond the RGB rule's far end is background seen
  past the object (the box is larger than the object would be there: nearer it may be, when
  the box shows only the visible part) and counts as a hole. Holes: the median of the valid
  depths in a small window around (u, v), else of the valid depths in the whole box, else the
  RGB rule.

A frame without a detection may carry a search region (``Frame.region``,
chpf.tracking.search_region): then (u, v) is uniform in the region's area less the border a
detection's box leaves around its central part, (1 - uv_fraction) / 2 of the object's box on
each side (for a detection, area = object box, this is the rule above), and the depth rules
read the region's box (the object's projected box at the estimate) as a detection's box.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal, Protocol

import numpy as np

from chpf.geometry import random_rotations
from chpf.tracking.types import Box, Frame

VISIBLE_PART_SPARE = 0.1
"""How far (a share of the belief's projected side) a detection of the visible part may lie
outside the belief's box and still count as inside it, and how far inside the belief's
projected outline, on every side, it may lie before it says the belief is too near
(``CandidateSampler.visible_part``, ``_too_near``)."""


Pose = tuple[np.ndarray, np.ndarray]
"""A pose: R (3,3), t (3,) metres (camera frame)."""

OutlineBox = Callable[[np.ndarray, np.ndarray, np.ndarray], Box | None]
"""The box (x, y, w, h) pixels of the object's projected outline at R (3,3), t (3,) metres
with intrinsics K (3,3); None when it has none."""


class RotationSource(Protocol):
    """Where phi_cand's orientations come from: n egocentric R (n,3,3) for translations t (n,3)."""

    def sample(
        self, n: int, frame: Frame, t: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray: ...


def valid_box(box: Box | None) -> Box | None:
    """The box as 4 floats if finite with positive width and height, else None."""
    if box is None:
        return None
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.shape[0] != 4 or not np.all(np.isfinite(b)) or b[2] <= 0 or b[3] <= 0:
        return None
    return (float(b[0]), float(b[1]), float(b[2]), float(b[3]))


def corners(box: Box) -> np.ndarray:
    """Box (x, y, w, h) pixels as its corners (4,) (x0, y0, x1, y1)."""
    return np.array([box[0], box[1], box[0] + box[2], box[1] + box[3]])


def inner_margins(inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """How far boxes ``inner`` lie inside boxes ``outer``, both (..., 4) corners (x0, y0, x1,
    y1) pixels: (..., 4) from the left, top, right and bottom side (negative: outside)."""
    inner, outer = np.asarray(inner), np.asarray(outer)
    return np.concatenate([inner[..., :2] - outer[..., :2], outer[..., 2:] - inner[..., 2:]], -1)


def backproject(u: np.ndarray, v: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera-frame points (n,3) at pixels (u, v) (n,) and depths z (n,) metres."""
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=-1)


def box_translations(boxes: np.ndarray, K: np.ndarray, box_extent: float) -> np.ndarray:
    """Translations (M,3) metres of an object of extent ``box_extent`` metres at the centres of
    boxes (M,4) (x, y, w, h) pixels, at the depth where it spans each box's longer side."""
    boxes = np.asarray(boxes, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    z = K[0, 0] * box_extent / np.maximum(boxes[:, 2], boxes[:, 3])
    u = boxes[:, 0] + 0.5 * (boxes[:, 2] - 1.0)
    v = boxes[:, 1] + 0.5 * (boxes[:, 3] - 1.0)
    return backproject(u, v, z, K)


def _median_valid(values: np.ndarray) -> np.ndarray:
    """Row-wise median of the positive entries of (n, m); nan where a row has none."""
    vals = np.where(values > 0, values, np.nan)
    out = np.full(values.shape[0], np.nan)
    has = np.any(values > 0, axis=1)
    if np.any(has):
        out[has] = np.nanmedian(vals[has], axis=1)
    return out


@dataclass
class CandidateSampler:
    """phi_cand for one object (see the module docstring); all lengths in metres."""

    z_range: tuple[float, float] = (0.3, 2.0)
    box_extent: float | None = None
    z_box_factors: tuple[float, float] = (0.75, 1.35)
    depth_offset: tuple[float, float] = (0.0, 0.05)
    depth_window: int = 3
    use_depth: bool = True
    uv_fraction: float = 1.0
    rotations: RotationSource | None = None  # None: uniform on SO(3)
    occluded_box: bool = False  # a detection of the visible part: draw from the belief's scale
    occluded_rule: Literal["inside", "around"] = "around"  # visible_part's reading
    outline_box: OutlineBox | None = None  # the belief's projected outline box (_too_near)

    def belief_box(self, t: np.ndarray, K: np.ndarray) -> Box | None:
        """The square box (x, y, w, h) pixels that the object at translation t (3,) metres
        spans (side fx * box_extent / z around the projection of t); None without an extent
        or in front of the camera."""
        if self.box_extent is None or self.box_extent <= 0 or t[2] <= 0:
            return None
        side = K[0, 0] * self.box_extent / t[2]
        u = K[0, 0] * t[0] / t[2] + K[0, 2]
        v = K[1, 1] * t[1] / t[2] + K[1, 2]
        return (u - side / 2, v - side / 2, side, side)

    def box_for(self, frame: Frame, estimate: Pose | None) -> Box | None:
        """The box phi_cand draws from (``visible_part``'s first box, or the detection)."""
        found = self.visible_part(frame, estimate)
        return valid_box(frame.box) if found is None else found[0]

    def visible_part(self, frame: Frame, estimate: Pose | None) -> tuple[Box, Box] | None:
        """(``occluded_box``, RGB frames) the object's box and the area its centre lies in when
        the detection is read as the visible part of the believed object, else None.

        The detection is such a part when it is smaller than the belief's box (side s) by more
        than 10 % and lies inside it (``VISIBLE_PART_SPARE`` of s spare; then both boxes are
        the belief's). With ``occluded_rule`` "around" such a detection must not say that the
        belief is too near (``_too_near``), and one that pokes out of the box but overlaps it
        is a part too (the belief is off): then the object is the square of side s centred on
        the detection, and its centre lies where such a square still holds the whole
        detection (the area spanned by the squares of side s flush with the detection's
        sides). A box of the visible part would put RGB candidates too far away (their z comes
        from the box's size) and off-centre. With depth the candidates' z is measured at (u,
        v), so the visible part's box serves: the belief's box would put some of them on the
        occluder."""
        det = valid_box(frame.box)
        if not self.occluded_box or det is None or estimate is None or frame.depth is not None:
            return None
        K = np.asarray(frame.K, dtype=np.float64)
        bel = self.belief_box(np.asarray(estimate[1], dtype=np.float64), K)
        if bel is None or max(det[2], det[3]) >= 0.9 * bel[2]:
            return None
        side, tol = bel[2], VISIBLE_PART_SPARE * bel[2]
        margins = inner_margins(corners(det), corners(bel))
        if np.all(margins >= -tol):
            if self.occluded_rule == "inside" or not self._too_near(det, estimate, K):
                return bel, bel
            return None
        if self.occluded_rule == "inside" or np.any(margins >= side):  # apart: no overlap
            return None
        cx, cy = det[0] + 0.5 * det[2], det[1] + 0.5 * det[3]
        obj = (cx - 0.5 * side, cy - 0.5 * side, side, side)
        x0, y0 = det[0] + det[2] - side, det[1] + det[3] - side
        area = (x0, y0, 2 * side - det[2], 2 * side - det[3])
        return obj, area

    def _z_rgb_range(self, box: Box, K: np.ndarray) -> tuple[float, float]:
        """The RGB rule's depth range (lo, hi) metres for a box (module docstring)."""
        if self.box_extent is not None and self.box_extent > 0:
            z_box = K[0, 0] * self.box_extent / max(box[2], box[3])
            return self.z_box_factors[0] * z_box, self.z_box_factors[1] * z_box
        return self.z_range[0], self.z_range[1]

    def _z_depth(
        self, u: np.ndarray, v: np.ndarray, box: Box, depth: np.ndarray, z_max: float
    ) -> np.ndarray:
        """Measured depth (n,) at (u, v), robust to holes and to background farther than
        ``z_max`` metres (nan where nothing valid at all)."""
        h, w = depth.shape

        def usable(d: np.ndarray) -> np.ndarray:  # background and holes -> 0
            return np.where(d <= z_max, d, 0.0)

        r = int(self.depth_window)
        offs = np.arange(-r, r + 1)
        ui = np.clip(np.rint(u).astype(np.int64)[:, None, None] + offs[None, None, :], 0, w - 1)
        vi = np.clip(np.rint(v).astype(np.int64)[:, None, None] + offs[None, :, None], 0, h - 1)
        patch = usable(depth[vi, ui].reshape(u.shape[0], -1))
        centre = usable(depth[np.clip(np.rint(v).astype(np.int64), 0, h - 1),
                              np.clip(np.rint(u).astype(np.int64), 0, w - 1)])  # fmt: skip
        z = np.where(centre > 0, centre, _median_valid(patch))
        if np.any(np.isnan(z)):
            x0, y0 = max(int(np.floor(box[0])), 0), max(int(np.floor(box[1])), 0)
            x1, y1 = min(int(np.ceil(box[0] + box[2])), w), min(int(np.ceil(box[1] + box[3])), h)
            region = usable(depth[y0:y1, x0:x1]) if (x1 > x0 and y1 > y0) else np.zeros(0)
            good = region[region > 0]
            z = np.where(np.isnan(z), np.median(good) if good.size else np.nan, z)
        return z

    def _too_near(self, det: Box, estimate: Pose, K: np.ndarray) -> bool:
        """Whether the detection det (x, y, w, h) lies inside the box of the belief's projected
        outline (``outline_box``; else the belief's square box) by more than
        ``VISIBLE_PART_SPARE`` of its longer side on every side: an occluder hides the object
        from one or two sides, so what this says is a belief too near, not a visible part."""
        R, t = (np.asarray(a, dtype=np.float64) for a in estimate)
        box = self.outline_box(R, t, K) if self.outline_box is not None else None
        box = box or self.belief_box(t, K)
        if box is None:
            return False
        margins = inner_margins(corners(det), corners(box))
        return bool(margins.min() > VISIBLE_PART_SPARE * max(box[2], box[3]))

    def _framed(self, frame: Frame, estimate: Pose | None) -> tuple[Frame, Box | None]:
        """``frame`` with the box phi_cand draws from as its box (the rotation source reads it
        too), and the area its candidates' centres lie in (None: the box's central part)."""
        found = self.visible_part(frame, estimate)
        return (frame, None) if found is None else (replace(frame, box=found[0]), found[1])

    def _centres(
        self, n: int, frame: Frame, rng: np.random.Generator, area: Box | None = None
    ) -> tuple[np.ndarray, np.ndarray, Box, Box]:
        """n candidate centres u, v (n,) pixels, the object's box (the depth rule's) and the
        area they lie in (the depth holes' fallback): from the detection (in ``area`` when
        given), else from the search region (module docstring); ValueError when the frame has
        neither."""
        margin = 0.5 * (1.0 - self.uv_fraction)
        obj = valid_box(frame.box)
        if obj is not None and area is None:
            u = obj[0] + (margin + self.uv_fraction * rng.random(n)) * obj[2]
            v = obj[1] + (margin + self.uv_fraction * rng.random(n)) * obj[3]
            return u, v, obj, obj
        if obj is None:
            if frame.region is None:
                raise ValueError(
                    "CandidateSampler needs a frame with a valid box or a search region"
                )
            obj, area = frame.region.box, frame.region.area
        assert area is not None
        bx, by = margin * obj[2], margin * obj[3]
        span_u, span_v = max(area[2] - 2.0 * bx, 0.0), max(area[3] - 2.0 * by, 0.0)
        u = area[0] + min(bx, 0.5 * area[2]) + span_u * rng.random(n)
        v = area[1] + min(by, 0.5 * area[3]) + span_v * rng.random(n)
        return u, v, obj, area

    def translations(
        self,
        n: int,
        frame: Frame,
        rng: np.random.Generator,
        estimate: Pose | None = None,
    ) -> np.ndarray:
        """n translations t (n,3) from phi_cand (what PoseRBPF's particles are) in the box of
        ``box_for(frame, estimate)``; the frame needs a valid box or a search region."""
        return self._translations(n, *self._framed(frame, estimate), rng)

    def _translations(
        self, n: int, frame: Frame, area: Box | None, rng: np.random.Generator
    ) -> np.ndarray:
        """n translations t (n,3) from the frame's box (or region), centres in ``area``."""
        u, v, box, area = self._centres(n, frame, rng, area)
        K = np.asarray(frame.K, dtype=np.float64)
        lo, hi = self._z_rgb_range(box, K)
        z_rgb = rng.uniform(lo, hi, n)
        if self.use_depth and frame.depth is not None:
            z_meas = self._z_depth(u, v, area, np.asarray(frame.depth), hi)
            offset = rng.uniform(self.depth_offset[0], self.depth_offset[1], n)
            z = np.where(np.isnan(z_meas), z_rgb, z_meas + offset)
        else:
            z = z_rgb
        return backproject(u, v, z, K)

    def sample(
        self,
        n: int,
        frame: Frame,
        rng: np.random.Generator,
        estimate: Pose | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """n poses (R (n,3,3), t (n,3)) from phi_cand; the frame needs a valid box or a search
        region.
        ``estimate``: the belief's pose (R (3,3), t (3,) metres; ``box_for``), None when there
        is none."""
        frame, area = self._framed(frame, estimate)
        t = self._translations(n, frame, area, rng)
        if self.rotations is None:
            return random_rotations(n, rng), t
        return self.rotations.sample(n, frame, t, rng), t
