"""Scale-normalised object crops: the crop convention shared by codebooks, training and tracking.

A codebook entry renders the object at rotation ``R_allo`` and translation (0, 0, D_r) with
``spec.K`` (focal f_r, principal point at the crop centre (S-1)/2) into an S x S image. At run
time, the observed crop for a hypothesis at translation t = (x, y, z) is the square centred on
the projection (u, v) of t, of side S * (D_r / z) * (f_obs / f_r) image pixels, resampled to
S x S: crop pixel (i, j) (column, row; pixel centres at integers) reads image pixel

    (u + (i - (S-1)/2) * s_x,  v + (j - (S-1)/2) * s_y),   s_x = (D_r / z) * fx / f_r,
                                                            s_y = (D_r / z) * fy / f_r.

Compare such a crop with the codebook entry of the allocentric rotation
``R_allo = R_ray(t)^T @ R`` (see ``chpf.geometry.egocentric_to_allocentric``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from chpf.errors import ConfigError

_CROP_KEYS = ("size", "render_distance", "focal")


@dataclass(frozen=True)
class CropSpec:
    """Crop size S (pixels), render distance D_r (metres) and focal f_r (pixels).

    Build it with ``CropSpec.for_object(diameter)`` (D_r = 4 * diameter, f_r = 3.6 * S: the
    object's diameter spans 90% of the crop) or with keywords. D_r and f_r must be > 0.
    """

    size: int = 64
    render_distance: float = 0.0
    focal: float = 0.0

    def __post_init__(self) -> None:
        if int(self.size) != self.size or self.size < 2:
            raise ConfigError(f"CropSpec: size must be an integer >= 2, got {self.size!r}")
        if not (np.isfinite(self.render_distance) and self.render_distance > 0):
            raise ConfigError(
                f"CropSpec: render_distance must be > 0, got {self.render_distance!r}"
            )
        if not (np.isfinite(self.focal) and self.focal > 0):
            raise ConfigError(f"CropSpec: focal must be > 0, got {self.focal!r}")
        object.__setattr__(self, "size", int(self.size))
        object.__setattr__(self, "render_distance", float(self.render_distance))
        object.__setattr__(self, "focal", float(self.focal))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsics of the crop camera (OpenCV convention)."""
        c = (self.size - 1) / 2.0
        return np.array([[self.focal, 0.0, c], [0.0, self.focal, c], [0.0, 0.0, 1.0]])

    @property
    def translation(self) -> np.ndarray:
        """(3,) the codebook object translation (0, 0, D_r), metres."""
        return np.array([0.0, 0.0, self.render_distance])

    @classmethod
    def for_object(cls, diameter: float, size: int = 64) -> CropSpec:
        """D_r = 4 * diameter, f_r = 0.9 * S * D_r / diameter (= 3.6 * S)."""
        if not (np.isfinite(diameter) and diameter > 0):
            raise ConfigError(f"CropSpec.for_object: diameter must be > 0, got {diameter!r}")
        d_r = 4.0 * float(diameter)
        return cls(size=int(size), render_distance=d_r, focal=0.9 * size * d_r / float(diameter))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict {"size", "render_distance", "focal"}."""
        return {"size": self.size, "render_distance": self.render_distance, "focal": self.focal}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CropSpec:
        """Inverse of ``to_dict``; ConfigError on missing or unknown keys."""
        if not isinstance(d, dict):
            raise ConfigError(f"crop spec must be a mapping, got {type(d).__name__}")
        unknown = sorted(set(d) - set(_CROP_KEYS))
        missing = [k for k in _CROP_KEYS if k not in d]
        if unknown or missing:
            raise ConfigError(f"crop spec: unknown keys {unknown}, missing keys {missing}")
        try:
            return cls(
                size=int(d["size"]),
                render_distance=float(d["render_distance"]),
                focal=float(d["focal"]),
            )
        except (TypeError, ValueError) as err:
            raise ConfigError(f"crop spec: bad value ({err})") from None


@dataclass
class CropBatch:
    """Rendered codebook-convention crops: rgb (N,S,S,3) uint8, depth (N,S,S) float32 metres
    (0 = empty), mask (N,S,S) bool."""

    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray

    def __len__(self) -> int:
        return len(self.rgb)


def crop_affines(t: np.ndarray, K: np.ndarray, spec: CropSpec) -> np.ndarray:
    """(N, 2, 3) float64 affines mapping CROP pixel (i, j, 1) -> IMAGE pixel (x, y).

    t (N, 3) (or (3,)) metres, z > 0; K (3, 3) of the observed image. Centre = projection of t;
    scale s = (D_r / z) * (f_obs / f_r) image pixels per crop pixel (fx for x, fy for y).
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    K = np.asarray(K, dtype=np.float64)
    z = t[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (K[0, 0] * t[:, 0] + K[0, 1] * t[:, 1]) / z + K[0, 2]
        v = K[1, 1] * t[:, 1] / z + K[1, 2]
        sx = spec.render_distance / z * K[0, 0] / spec.focal
        sy = spec.render_distance / z * K[1, 1] / spec.focal
    c = (spec.size - 1) / 2.0
    A = np.zeros((len(t), 2, 3))
    A[:, 0, 0], A[:, 0, 2] = sx, u - c * sx
    A[:, 1, 1], A[:, 1, 2] = sy, v - c * sy
    return A


def extract_crops(
    image: np.ndarray,
    affines: np.ndarray,
    size: int,
    interpolation: int = cv2.INTER_LINEAR,
    border: float = 0,
) -> np.ndarray:
    """Crops (N, S, S[, C]) of ``image`` (H, W[, C]) through ``affines`` (N, 2, 3) (crop -> image).

    One ``cv2.warpAffine(..., WARP_INVERSE_MAP)`` per crop; outside the image = ``border``.
    Same dtype as the image. A uint8 RGB image is warped as RGBA when the crops are many
    enough to pay for the conversion (``_via_rgba``): OpenCV's four-channel kernel is over
    twice as fast, and the colour channels come out byte for byte the same.
    """
    img = np.asarray(image)
    A = np.asarray(affines, dtype=np.float64).reshape(-1, 2, 3)
    if not img.flags.c_contiguous:
        img = np.ascontiguousarray(img)
    if img.dtype == bool:
        crops = extract_crops(img.view(np.uint8), A, size, cv2.INTER_NEAREST, int(bool(border)))
        return crops.astype(bool)
    if _via_rgba(img, len(A), size):
        rgba = cv2.cvtColor(img, cv2.COLOR_RGB2RGBA)
        out = _warp_each(rgba, A, size, interpolation, border)
        return cv2.cvtColor(out.reshape(-1, size, 4), cv2.COLOR_RGBA2RGB).reshape(-1, size, size, 3)
    return _warp_each(img, A, size, interpolation, border)


def _via_rgba(img: np.ndarray, n: int, size: int) -> bool:
    """Whether ``extract_crops`` warps the uint8 RGB ``img`` as RGBA for n crops of ``size``:
    when the crops' pixels add up to at least 1/16 of the image's (measured here with OpenCV
    5.0: converting a 640x480 frame costs 41 us and saves 13 us per 64x64 crop)."""
    return (
        img.dtype == np.uint8
        and img.ndim == 3
        and img.shape[2] == 3
        and n * size * size * 16 >= img.shape[0] * img.shape[1]
    )


def _warp_each(
    img: np.ndarray, A: np.ndarray, size: int, interpolation: int, border: float
) -> np.ndarray:
    """``extract_crops``' loop: one warpAffine per affine of A (N, 2, 3) into (N, S, S[, C])."""
    out = np.empty((len(A), size, size, *img.shape[2:]), dtype=img.dtype)
    flags = interpolation | cv2.WARP_INVERSE_MAP
    channels = img.shape[2] if img.ndim == 3 else 1
    value = (border,) * min(channels, 4)
    finite = np.isfinite(A).all(axis=(1, 2))
    for k in range(len(A)):
        if not finite[k]:
            out[k] = border
            continue
        cv2.warpAffine(
            img,
            A[k],
            (size, size),
            dst=out[k],
            flags=flags,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=value,
        )
    return out


_shared: dict[int, Any] = {}


def _shared_renderer(size: int) -> Any:
    """A process-wide Renderer(size, size), created on first use."""
    from chpf.render import Renderer

    r = _shared.get(size)
    if r is None or getattr(r, "_r", None) is None:
        r = Renderer(size, size)
        _shared[size] = r
    return r


def render_crops(
    renderer: Any,
    obj: Any,
    R_allo: np.ndarray,
    spec: CropSpec,
    light_intensity: float = 3.0,
    ambient: float = 0.3,
    light_direction: np.ndarray | None = None,
    rgb: bool = True,
    antialias: bool = True,
) -> CropBatch:
    """Codebook-convention renders of ``obj`` at rotations ``R_allo`` (N, 3, 3).

    The object is at (0, 0, D_r) with ``spec.K`` in an S x S image. ``renderer``: a
    ``chpf.render.Renderer`` (any size: it renders S x S for these calls) or None for a shared
    one. ``rgb=False`` skips the colour pass (rgb is then all zeros); ``antialias=False``
    renders aliased colour in a single pass (2-3x faster, see ``Renderer.render``).
    """
    R_allo = np.asarray(R_allo, dtype=np.float64).reshape(-1, 3, 3)
    S = spec.size
    r = renderer if renderer is not None else _shared_renderer(S)
    n = len(R_allo)
    rgb_out = np.zeros((n, S, S, 3), np.uint8)
    depth = np.zeros((n, S, S), np.float32)
    mask = np.zeros((n, S, S), bool)
    K, t = spec.K, spec.translation
    for k in range(n):
        out = r.render(
            [(obj, R_allo[k], t)],
            K,
            light_intensity=light_intensity,
            ambient=ambient,
            light_direction=light_direction,
            rgb=rgb,
            size=(S, S),
            antialias=antialias,
        )
        rgb_out[k] = out.rgb
        depth[k] = out.depth
        mask[k] = out.masks[0]
    return CropBatch(rgb=rgb_out, depth=depth, mask=mask)
