"""Occluders, reframing and appearance changes drawn onto training crops, batch by batch.

The renderer's occluders (built-in objects, 2D blobs) and lighting are a closed family: a
classifier trained on them alone learned that family's look, and called far fewer occluded
true poses aligned under occluders and lighting it had never seen (docs/chpf-ablations.md).
This module adds, at training time, what the renderer never draws: occluders of arbitrary
shapes (rotated rectangles, ellipses, random polygons, thick strokes) filled with a flat
colour, noise, a colour gradient or a piece of another crop of the batch, then a colour cast,
brightness, contrast and gamma change, blur and sensor noise. The labels stay: occlusion and
lighting are not evidence against a pose. Reframing zooms and shifts a crop by a few per cent
(a crop cut at a slightly wrong translation, as a particle's is): the labels stay there too,
since the pairs' labels ignore the crop jitter that the data was cut with.

Crops are float ``(B, 3, S, S)`` in [0, 1]; the occluder masks are drawn with OpenCV on the CPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from chpf.config_schema import Invalid, Section, setting

SHAPES = ("rectangle", "ellipse", "polygon", "stroke")
FILLS = ("colour", "noise", "gradient", "patch")


@dataclass
class BatchAugment(Section):
    """What the classifier's observed crops get at training time (all off by default).

    Attributes:
        occluder_share: share of crops that get occluders (0 = off).
        max_occluders: up to this many occluders per such crop (1 or more, uniform).
        occluder_area: [lo, hi] area of one occluder's bounding box, as a fraction of the crop.
        colour_cast: per-channel gains drawn from [1 - colour_cast, 1] (0 = off).
        brightness: [lo, hi] gain of the whole crop.
        contrast: [lo, hi] contrast factor about the crop's mean.
        gamma: [lo, hi] exponent applied to the [0, 1] intensities.
        blur_share: share of crops blurred with a Gaussian of sigma in ``blur_sigma`` (pixels).
        blur_sigma: [lo, hi] blur sigma in pixels.
        noise_std: max std of additive Gaussian pixel noise (drawn in [0, noise_std]).
        zoom_sigma: std of the log of a per-crop zoom factor (0.05: about 5 % larger or
            smaller; 0 = off).
        shift_sigma: std of a per-crop shift along x and y, as a fraction of the crop's side.
    """

    occluder_share: float = setting(0.0, ge=0.0, le=1.0)
    max_occluders: int = setting(2, ge=1)
    occluder_area: tuple[float, float] = setting((0.05, 0.45), gt=0.0, le=1.0)
    colour_cast: float = setting(0.0, ge=0.0, le=1.0)
    brightness: tuple[float, float] = setting((1.0, 1.0), gt=0.0)
    contrast: tuple[float, float] = setting((1.0, 1.0), gt=0.0)
    gamma: tuple[float, float] = setting((1.0, 1.0), gt=0.0)
    blur_share: float = setting(0.0, ge=0.0, le=1.0)
    blur_sigma: tuple[float, float] = setting((0.5, 1.5), gt=0.0)
    noise_std: float = setting(0.0, ge=0.0)
    zoom_sigma: float = setting(0.0, ge=0.0, le=0.5)
    shift_sigma: float = setting(0.0, ge=0.0, le=0.5)

    def check(self) -> None:
        for key in ("occluder_area", "brightness", "contrast", "gamma", "blur_sigma"):
            lo, hi = getattr(self, key)
            if lo > hi:
                raise Invalid(key, f"needs lo <= hi, got [{lo}, {hi}]")

    @property
    def active(self) -> bool:
        """Whether any augmentation is on."""
        return self != BatchAugment()


def occluder_mask(size: int, area: float, rng: np.random.Generator) -> np.ndarray:
    """One occluder of a random SHAPES kind: bool (size, size), its bounding box ``area`` of
    the crop (a fraction), its centre in the crop's central 80 % (where the object is)."""
    side = np.sqrt(area) * size
    w, h = side * np.exp(rng.normal(0.0, 0.35, 2))
    cx, cy = rng.uniform(0.1, 0.9, 2) * size
    angle = rng.uniform(0.0, 180.0)
    canvas = np.zeros((size, size), np.uint8)
    kind = SHAPES[rng.integers(len(SHAPES))]
    if kind == "rectangle":
        box = cv2.boxPoints(((cx, cy), (w, h), angle))
        cv2.fillPoly(canvas, [np.round(box).astype(np.int32)], 1)
    elif kind == "ellipse":
        cv2.ellipse(canvas, ((cx, cy), (w, h), angle), 1, -1)
    elif kind == "polygon":
        n = int(rng.integers(3, 9))
        theta = np.sort(rng.uniform(0.0, 2 * np.pi, n))
        radius = rng.uniform(0.3, 1.0, n) * side / 2
        pts = np.stack([cx + radius * np.cos(theta), cy + radius * np.sin(theta)], axis=1)
        cv2.fillPoly(canvas, [np.round(pts).astype(np.int32)], 1)
    else:  # a thick stroke through the centre
        n = int(rng.integers(1, 4))
        pts = np.array([cx, cy]) + rng.uniform(-1.0, 1.0, (n + 1, 2)) * side
        pts[int(rng.integers(n + 1))] = cx, cy
        thickness = max(2, round(float(side) * rng.uniform(0.15, 0.4)))
        cv2.polylines(canvas, [np.round(pts).astype(np.int32)], False, 1, thickness)
    return canvas.astype(bool)


def _fill(x: torch.Tensor, i: int, rng: np.random.Generator) -> torch.Tensor:
    """Content (3, S, S) for an occluder on crop i of the batch x (B, 3, S, S)."""
    size = x.shape[-1]
    kind = FILLS[rng.integers(len(FILLS))]
    colour = torch.from_numpy(rng.uniform(0.0, 1.0, (3, 1, 1))).to(x)
    if kind == "colour":
        return colour.expand(3, size, size)
    if kind == "noise":
        noise = torch.from_numpy(rng.uniform(0.0, 1.0, (3, size, size))).to(x)
        return 0.5 * colour + 0.5 * noise
    if kind == "gradient":
        other = torch.from_numpy(rng.uniform(0.0, 1.0, (3, 1, 1))).to(x)
        ramp = torch.linspace(0.0, 1.0, size, dtype=x.dtype, device=x.device)
        ramp = ramp[None, :, None] if rng.random() < 0.5 else ramp[None, None, :]
        return colour + (other - colour) * ramp
    j = (i + 1 + int(rng.integers(max(1, x.shape[0] - 1)))) % x.shape[0]
    return torch.roll(x[j], shifts=tuple(int(s) for s in rng.integers(0, size, 2)), dims=(1, 2))


def add_occluders(x: torch.Tensor, cfg: BatchAugment, rng: np.random.Generator) -> torch.Tensor:
    """Occluders on a ``cfg.occluder_share`` of the crops x (B, 3, S, S) in [0, 1] (a copy)."""
    if cfg.occluder_share <= 0:
        return x
    out = x.clone()
    size = x.shape[-1]
    lo, hi = cfg.occluder_area
    for i in np.flatnonzero(rng.random(x.shape[0]) < cfg.occluder_share):
        for _ in range(int(rng.integers(1, cfg.max_occluders + 1))):
            mask = torch.from_numpy(occluder_mask(size, rng.uniform(lo, hi), rng)).to(x.device)
            out[i] = torch.where(mask, _fill(x, int(i), rng), out[i])
    return out


def _gaussian_blur(x: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """x (B, 3, S, S) blurred with a per-crop Gaussian of std sigma (B,) pixels."""
    r = int(np.ceil(3 * float(sigma.max())))
    offsets = torch.arange(-r, r + 1, dtype=x.dtype, device=x.device)
    k = torch.exp(-0.5 * (offsets[None] / sigma[:, None]) ** 2)
    k = (k / k.sum(1, keepdim=True)).repeat_interleave(3, 0)  # (B*3, 2r+1)
    b, c, h, w = x.shape
    y = x.reshape(1, b * c, h, w)
    y = F.conv2d(F.pad(y, (r, r, 0, 0), mode="replicate"), k[:, None, None, :], groups=b * c)
    y = F.conv2d(F.pad(y, (0, 0, r, r), mode="replicate"), k[:, None, :, None], groups=b * c)
    return y.reshape(b, c, h, w)


def _uniform(rng: np.random.Generator, span: tuple[float, float], shape: tuple[int, ...]):
    return rng.uniform(span[0], span[1], shape)


def change_appearance(x: torch.Tensor, cfg: BatchAugment, rng: np.random.Generator) -> torch.Tensor:
    """Colour cast, brightness, contrast, gamma, blur and noise per crop of x (B, 3, S, S)."""
    b = x.shape[0]

    def per_crop(values: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(values).to(x).reshape(b, -1, 1, 1)

    gain = per_crop(_uniform(rng, cfg.brightness, (b,)))
    gain = gain * per_crop(rng.uniform(1.0 - cfg.colour_cast, 1.0, (b, 3)))
    y = x * gain
    mean = y.mean(dim=(1, 2, 3), keepdim=True)
    y = ((y - mean) * per_crop(_uniform(rng, cfg.contrast, (b,))) + mean).clamp(0.0, 1.0)
    y = y ** per_crop(_uniform(rng, cfg.gamma, (b,)))
    if cfg.blur_share > 0:
        blurred = rng.random(b) < cfg.blur_share
        if blurred.any():
            sigma = torch.from_numpy(_uniform(rng, cfg.blur_sigma, (int(blurred.sum()),))).to(x)
            idx = torch.from_numpy(np.flatnonzero(blurred)).to(x.device)
            y = y.index_copy(0, idx, _gaussian_blur(y[idx], sigma))
    if cfg.noise_std > 0:
        std = per_crop(rng.uniform(0.0, cfg.noise_std, (b,)))
        y = y + torch.randn_like(y) * std
    return y.clamp(0.0, 1.0)


def reframe(x: torch.Tensor, cfg: BatchAugment, rng: np.random.Generator) -> torch.Tensor:
    """The crops x (B, 3, S, S) each zoomed by exp(N(0, zoom_sigma)) about its centre and
    shifted by N(0, shift_sigma) crop sides along x and y (the edge pixels fill what comes in)."""
    if cfg.zoom_sigma <= 0 and cfg.shift_sigma <= 0:
        return x
    b = x.shape[0]
    inv_zoom = np.exp(-rng.normal(0.0, cfg.zoom_sigma, b))
    shift = rng.normal(0.0, cfg.shift_sigma, (b, 2))
    theta = np.zeros((b, 2, 3))
    theta[:, 0, 0] = theta[:, 1, 1] = inv_zoom
    theta[:, :, 2] = -2.0 * shift * inv_zoom[:, None]  # output (u, v) -> input, in [-1, 1] units
    grid = F.affine_grid(torch.from_numpy(theta).to(x), list(x.shape), align_corners=False)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)


def augment_batch(x: torch.Tensor, cfg: BatchAugment, rng: np.random.Generator) -> torch.Tensor:
    """Reframing, occluders, then appearance changes, on the crops x (B, 3, S, S) in [0, 1]."""
    if not cfg.active:
        return x
    return change_appearance(add_occluders(reframe(x, cfg, rng), cfg, rng), cfg, rng)
