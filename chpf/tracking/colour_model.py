"""The tracked object's colours against its scene's: a re-detection cue learned while tracking.

Region-based 6D trackers (PWP3D, RBOT, ICG) separate an object from its surroundings by two
colour histograms, the object's and the background's, learned online from the frames they
track. chpf's networks were trained on renders; in a dark or strongly lit scene, or at a grazing
view, they see the object about as weakly as a patch of background (after a forced jump,
boxes on the object scored -0.2 to 2.0 decades of log-odds where the best background boxes
scored 0.8 to 2.2). The scene's own colours still tell it apart: learned from the tracked frames
before a jump, the boxes on the object scored 0.27-0.90 by ``box_contrast`` and the best
background boxes at most 0.21 (docs/own-recording.md).

``ColourModel`` keeps the two histograms (``BINS`` per RGB channel), each a running mean over
the frames it is taught (``rate`` the new frame's share): the object's from the pixels inside
the convex hull of its projected outline at a pose that fits it, the background's from the
pixels outside that hull grown by ``MARGIN`` of its size (its border mixes both). Its
``posterior`` is, per pixel, p(object | colour) = h_obj / (h_obj + h_bg) (0.5 for a colour
neither has seen). ``box_contrast`` scores square boxes: the mean posterior in the box's
central ``INNER`` of its side less the mean in the ring between 1 and ``RING`` sides around it.
"""

from __future__ import annotations

import cv2
import numpy as np

from chpf.tracking.silhouette import colour_codes

BINS = 16
"""Histogram bins per RGB channel (RBOT uses 32 for larger images; 16 keeps a 320x240 frame's
object of a few thousand pixels from leaving most of its bins empty)."""
MARGIN = 0.25
"""The object's hull is grown by this share of its box's larger side before the background is
taken from outside it."""
INNER = 0.6
"""The central share of a box's side whose mean posterior counts as the object's."""
RING = 1.6
"""The outer side, in box sides, of the ring whose mean posterior counts as the surroundings'."""
READ_WIDTH = 320
"""Images wider than this are read at every ``stride``-th pixel in both directions (histograms
and box means need no more; at 1280 x 720 reading every pixel cost 8.1 ms to teach and 4.9 ms
for a posterior with 96 boxes, against 0.6 and 0.5 ms at 320 x 240)."""


def stride(width: int) -> int:
    """The step (>= 1) at which the colour model reads an image ``width`` pixels wide."""
    return max(1, width // READ_WIDTH)


def hull_mask(uv: np.ndarray, height: int, width: int, grow: float = 0.0) -> np.ndarray:
    """The filled convex hull (H,W) bool of pixels uv (M,2), dilated by ``grow`` of its box's
    larger side."""
    hull = cv2.convexHull(np.asarray(uv, dtype=np.float32)).reshape(-1, 2)
    mask = np.zeros((height, width), dtype=np.uint8)
    cv2.fillConvexPoly(mask, np.round(hull).astype(np.int32), 1)
    radius = round(grow * float(np.max(hull.max(axis=0) - hull.min(axis=0))))
    if radius > 0:
        mask = cv2.dilate(mask, np.ones((2 * radius + 1, 2 * radius + 1), np.uint8))
    return mask.astype(bool)


class ColourModel:
    """The object's and the background's colour histograms (module docstring); ``rate`` in
    (0, 1]: the share of a newly taught frame in each running mean."""

    def __init__(self, rate: float = 0.2) -> None:
        self.rate = rate
        self.reset()

    def reset(self) -> None:
        """Nothing learned (start of a sequence)."""
        self.object_hist: np.ndarray | None = None  # (BINS^3,) sums to 1
        self.background_hist: np.ndarray | None = None
        # the last image, its posterior and that posterior's integral image (H+1,W+1)
        self._maps: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def ready(self) -> bool:
        """Whether a frame has been taught."""
        return self.object_hist is not None

    def teach(self, rgb: np.ndarray, uv: np.ndarray) -> None:
        """Learn from rgb (H,W,3) uint8 where the object's outline projects to pixels uv (M,2):
        inside its hull the object, outside the grown hull the background (every ``stride``-th
        pixel). A hull without a pixel inside the image teaches nothing."""
        step = stride(rgb.shape[1])
        read = rgb[::step, ::step]
        height, width = read.shape[:2]
        uv = np.asarray(uv, dtype=np.float64) / step
        inside = hull_mask(uv, height, width)
        outside = ~hull_mask(uv, height, width, MARGIN)
        if not inside.any() or not outside.any():
            return
        bins = colour_codes(read, BINS)
        new = [np.bincount(bins[m], minlength=BINS**3) / m.sum() for m in (inside, outside)]
        if self.object_hist is None or self.background_hist is None:
            self.object_hist, self.background_hist = new
        else:
            self.object_hist = (1.0 - self.rate) * self.object_hist + self.rate * new[0]
            self.background_hist = (1.0 - self.rate) * self.background_hist + self.rate * new[1]
        self._maps = None

    def posterior(self, rgb: np.ndarray) -> np.ndarray:
        """p(object | colour) float64 of every ``stride``-th pixel of rgb (H,W,3) uint8 in both
        directions, (H,W) for an image at most ``READ_WIDTH`` wide (kept for the same image
        array)."""
        return self._posterior_maps(rgb)[0]

    def _posterior_maps(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``posterior`` of rgb and its integral image (H+1,W+1), both kept for the same image
        array (box_contrast reads them several times a frame)."""
        if self.object_hist is None or self.background_hist is None:
            raise RuntimeError("ColourModel.posterior before any frame was taught")
        if self._maps is None or self._maps[0] is not rgb:
            total = self.object_hist + self.background_hist
            table = np.divide(
                self.object_hist, total, out=np.full_like(total, 0.5), where=total > 0.0
            )
            step = stride(rgb.shape[1])
            posterior = table[colour_codes(rgb[::step, ::step], BINS)]
            self._maps = (rgb, posterior, cv2.integral(posterior))
        return self._maps[1], self._maps[2]

    def box_contrast(self, rgb: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """Per square box (M,4) (x, y, w, h) pixels of rgb (H,W,3): the mean posterior in its
        central ``INNER`` less the mean in the ring out to ``RING`` sides (parts outside the
        image left out), in [-1, 1]; 0 before any frame was taught."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        if not self.ready:
            return np.zeros(len(boxes))
        posterior, summed = self._posterior_maps(rgb)
        boxes = boxes / stride(rgb.shape[1])  # in the posterior's pixels
        height, width = posterior.shape
        cx, cy = boxes[:, 0] + 0.5 * boxes[:, 2], boxes[:, 1] + 0.5 * boxes[:, 3]
        side = boxes[:, 2]

        def square(scale: float) -> tuple[np.ndarray, np.ndarray]:
            """Sum and pixel count of each box's square of ``scale`` sides, in the image."""
            half = 0.5 * scale * side
            x0 = np.clip(np.round(cx - half), 0, width).astype(np.int64)
            x1 = np.clip(np.round(cx + half), 0, width).astype(np.int64)
            y0 = np.clip(np.round(cy - half), 0, height).astype(np.int64)
            y1 = np.clip(np.round(cy + half), 0, height).astype(np.int64)
            total = summed[y1, x1] - summed[y0, x1] - summed[y1, x0] + summed[y0, x0]
            return total, ((x1 - x0) * (y1 - y0)).astype(np.float64)

        inner_sum, inner_n = square(INNER)
        box_sum, box_n = square(1.0)
        outer_sum, outer_n = square(RING)
        inner = np.divide(inner_sum, inner_n, out=np.zeros_like(inner_sum), where=inner_n > 0)
        ring_n = outer_n - box_n
        ring = np.divide(outer_sum - box_sum, ring_n, out=np.zeros_like(ring_n), where=ring_n > 0)
        return inner - ring
