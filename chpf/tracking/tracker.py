"""The Python API for robot code: a Tracker around one filter and a bundle's likelihoods.

Example::

    from chpf.tracking import Tracker
    tracker = Tracker.from_bundle("chpf/assets/bundles/box", method="chpf", n_particles=50)
    for rgb, K, box in frames:                    # box = (x, y, w, h) pixels or None
        result = tracker.step(rgb, K=K, box=box)  # result.R (3,3), result.t (3,) metres
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from chpf.bundle import Bundle
from chpf.errors import BundleError, ConfigError, ImageSizeError
from chpf.tracking.bundle_likelihood import BundleLikelihood
from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.codebook_candidates import CodebookRotations
from chpf.tracking.config import METHODS, MODALITIES, TrackConfig, make_config
from chpf.tracking.methods import Filter, make_filter
from chpf.tracking.types import Box, Frame, TrackResult


def limit_library_threads(n: int) -> None:
    """Cap OpenCV's and the BLAS library's worker threads for this process.

    On a small CPU their idle workers compete with onnxruntime's threads: measured here, the
    encoder's 50 crops took ~59 ms per frame inside the tracker with default threading and
    ~30 ms with both capped at 1 (the crops and look-ups gain nothing from more threads).
    """
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(n)
    threadpool_limits(limits=n, user_api="blas")


def check_frame(rgb: np.ndarray, depth: np.ndarray | None, K: np.ndarray) -> np.ndarray:
    """Validate an input frame; returns K as (3,3) float64. ImageSizeError on a mismatch."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ImageSizeError(f"rgb image must be (H,W,3) uint8, got {rgb.shape} {rgb.dtype}")
    h, w = rgb.shape[:2]
    if K is None:
        raise ImageSizeError("camera intrinsics K are required")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ImageSizeError(f"K must be a finite (3,3) matrix with positive focals, got {K}")
    cx, cy = K[0, 2], K[1, 2]
    if not (0 <= cx < w and 0 <= cy < h):
        raise ImageSizeError(
            f"principal point ({cx:g}, {cy:g}) of K lies outside the {w}x{h} image "
            "(image size and K disagree)"
        )
    if depth is not None:
        d = np.asarray(depth)
        if d.shape != (h, w):
            raise ImageSizeError(f"depth image is {d.shape[::-1]} but the rgb image is {w}x{h}")
    return K


def depth_in_metres(depth: np.ndarray) -> np.ndarray:
    """Depth (H,W) as float32 metres with every non-finite or negative value made 0 (missing):
    the one place where a sensor's NaN / inf markers become the toolkit's holes."""
    d = np.asarray(depth, dtype=np.float32)
    return np.where(np.isfinite(d) & (d > 0), d, np.float32(0.0))


class Tracker:
    """Tracks one object with one method; see the module docstring.

    method: one of config.METHODS. modality: "rgb" or "rgbd" (depth used when given).
    seed: the filter's random generator seed (same seed, same poses).
    """

    def __init__(
        self,
        bundle: Bundle,
        method: str = "chpf",
        modality: str = "rgb",
        seed: int = 0,
        config: TrackConfig | None = None,
    ) -> None:
        cfg = config or TrackConfig()
        if method not in METHODS:
            raise ConfigError(f"unknown method {method!r} (choose from {', '.join(METHODS)})")
        if modality not in MODALITIES:
            raise ConfigError(f"unknown modality {modality!r} (rgb or rgbd)")
        if cfg.crop_size is not None and cfg.crop_size != bundle.spec.size:
            raise BundleError(
                f"{bundle.path}: bundle crop size {bundle.spec.size} differs from the "
                f"configured crop_size {cfg.crop_size}"
            )
        rgbd = modality == "rgbd"
        c_mode = cfg.c_mode if method == "chpf" else "none"  # only CH-PF uses C
        if c_mode in ("depth", "both") and not rgbd:
            raise ConfigError(f"c_mode {c_mode!r} needs --modality rgbd")
        limit_library_threads(cfg.library_threads)
        self.bundle = bundle
        self.method = method
        self.modality = modality
        self.config = cfg
        self.seed: int | Sequence[int] = seed
        self.likelihood = BundleLikelihood(
            bundle,
            sigma=cfg.sigma,
            l_from_cos=cfg.l_from_cos,
            c_mode=c_mode,
            use_depth=rgbd,
            depth_margin=cfg.depth_margin,
            c_depth_margin=cfg.c_depth_margin,
            depth_no_data=cfg.depth_no_data,
        )
        diameter = float(bundle.obj_info.diameter)
        self.candidates = CandidateSampler(
            z_range=tuple(cfg.z_range),  # type: ignore[arg-type]
            box_extent=self.likelihood.box_extent if cfg.z_from_box else None,
            z_box_factors=tuple(cfg.z_box_factors),  # type: ignore[arg-type]
            depth_offset=tuple(cfg.depth_offset or (0.0, 0.5 * diameter)),  # type: ignore[arg-type]
            depth_window=cfg.depth_window,
            use_depth=rgbd,
            uv_fraction=cfg.box_uv_fraction,
            rotations=None
            if cfg.candidate_rotations == "uniform"
            else CodebookRotations(
                self.likelihood, cfg.candidate_temperature, cfg.candidate_uniform_share
            ),
        )
        self.filter: Filter = make_filter(
            method, self.likelihood, cfg, self.candidates, np.random.default_rng(self.seed)
        )

    @classmethod
    def from_bundle(
        cls,
        path: str | Path | Bundle,
        method: str = "chpf",
        n_particles: int = 50,
        modality: str = "rgb",
        seed: int = 0,
        config: str | Path | dict[str, Any] | TrackConfig | None = None,
        **options: Any,
    ) -> Tracker:
        """Load the bundle folder ``path`` (or use a loaded Bundle) and build a Tracker.

        ``config``: a YAML file / dict / TrackConfig; ``options`` override single TrackConfig
        fields (e.g. sigma_t=0.02, srl_beta=0.5). Raises BundleError / ConfigError.
        """
        cfg = make_config(config, n_particles=n_particles, **options)
        if isinstance(path, Bundle):
            bundle = path
        else:
            bundle = Bundle.load(path, threads=cfg.threads, spin=cfg.spin)
        return cls(bundle, method=method, modality=modality, seed=seed, config=cfg)

    def reset(self, seed: int | Sequence[int] | None = None) -> None:
        """Start a new sequence (optionally with a new seed: an int or a tuple of ints)."""
        if seed is not None:
            self.seed = seed
        self.filter.reset()
        self.filter.rng = np.random.default_rng(self.seed)  # type: ignore[attr-defined]

    def step(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        K: np.ndarray | None = None,
        box: Box | None = None,
    ) -> TrackResult:
        """One frame: rgb (H,W,3) uint8, depth (H,W) float32 m or None (non-finite or negative
        values are missing, as 0 is), K (3,3), box (x,y,w,h) pixels or None (predict only).
        Returns a TrackResult (pose R, t metres, alpha, ...)."""
        K_arr = check_frame(rgb, depth, K)  # type: ignore[arg-type]
        if self.modality == "rgb":
            depth = None
        elif depth is not None:
            depth = depth_in_metres(depth)
        return self.filter.step(Frame(rgb=rgb, depth=depth, K=K_arr, box=box))
