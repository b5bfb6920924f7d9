"""The Python API for robot code: a Tracker around one filter and a bundle's likelihoods.

Example::

    from chpf.tracking import Tracker
    tracker = Tracker.from_bundle("chpf/assets/bundles/box", method="chpf", n_particles=50)
    for rgb, K, box in frames:                    # box = (x, y, w, h) pixels or None
        result = tracker.step(rgb, K=K, box=box)  # result.R (3,3), result.t (3,) metres

A box is needed to start (the first frame's); after it ``box=None`` means "search around the
estimate" (the ``search`` options, chpf.tracking.search_region) as long as no box has come
after the first; once one has (a detector runs), a frame without one is predict-only, as with
``box_source: detections``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from chpf.bundle import Bundle
from chpf.errors import BundleError, ConfigError, ImageSizeError
from chpf.geometry import check_image_size
from chpf.providers import execution_providers
from chpf.tracking.boxes import BoxChecker
from chpf.tracking.bundle_likelihood import BundleLikelihood
from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.codebook_candidates import CodebookRotations
from chpf.tracking.config import MODALITIES, TrackConfig, make_config
from chpf.tracking.methods import Filter, get_method, make_filter
from chpf.tracking.search_region import SearchRegion
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
    """Validate an input frame; returns K as (3,3) float64. ImageSizeError on a mismatch (also
    when the image's size is not about (2 cx + 1, 2 cy + 1): see ``check_image_size``)."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ImageSizeError(f"rgb image must be (H,W,3) uint8, got {rgb.shape} {rgb.dtype}")
    h, w = rgb.shape[:2]
    if K is None:
        raise ImageSizeError("camera intrinsics K are required")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ImageSizeError(f"K must be a finite (3,3) matrix with positive focals, got {K}")
    check_image_size(w, h, K)
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

    method: a registered method (chpf.tracking.methods.METHODS). modality: "rgb" or "rgbd"
    (depth used when given). seed: the filter's random generator seed (same seed, same poses).
    config: a TrackConfig, a nested dict of its sections or a YAML file (default: defaults).
    """

    def __init__(
        self,
        bundle: Bundle,
        method: str = "chpf",
        modality: str = "rgb",
        seed: int = 0,
        config: TrackConfig | dict[str, Any] | str | Path | None = None,
    ) -> None:
        cfg = config if isinstance(config, TrackConfig) else make_config(config)
        get_method(method)
        if modality not in MODALITIES:
            raise ConfigError(f"unknown modality {modality!r} (rgb or rgbd)")
        crop_size = cfg.runtime.crop_size
        if crop_size is not None and crop_size != bundle.spec.size:
            raise BundleError(
                f"{bundle.path}: bundle crop size {bundle.spec.size} differs from the "
                f"configured runtime.crop_size {crop_size}"
            )
        run = cfg.runtime
        if (bundle.precision, bundle.providers) != (
            run.precision,
            execution_providers(run.device),
        ):
            bundle = Bundle.load(
                bundle.path,
                threads=run.threads,
                spin=run.spin,
                precision=run.precision,
                device=run.device,
            )
        rgbd = modality == "rgbd"
        c_mode = cfg.chpf.c_mode if method == "chpf" else "none"  # only CH-PF uses C
        if c_mode in ("depth", "both") and not rgbd:
            raise ConfigError(f"chpf.c_mode {c_mode!r} needs --modality rgbd")
        limit_library_threads(cfg.runtime.library_threads)
        self.bundle = bundle
        self.method = method
        self.modality = modality
        self.config = cfg
        self.seed: int | Sequence[int] = seed
        lik = cfg.likelihood
        self.likelihood = BundleLikelihood(
            bundle,
            sigma=lik.sigma,
            l_from_cos=lik.l_from_cos,
            c_mode=c_mode,
            use_depth=rgbd,
            depth_margin=lik.depth_margin,
            c_depth_margin=lik.c_depth_margin,
            depth_no_data=lik.depth_no_data,
            c_box=cfg.chpf.c_box,
            c_box_shape=cfg.chpf.c_box_shape,
            # CH-PF's per-side box (CH-RBPF's C reads the larger side; measured on CH-PF only)
            c_box_sides=cfg.chpf.c_box_sides if method == "chpf" else "larger",
            box_whole=cfg.chpf.box_whole if method == "chpf" else None,
            c_edge=cfg.chpf.c_edge,
            c_near=cfg.chpf.c_near,
            c_silhouette=cfg.chpf.c_silhouette if method == "chpf" else None,
            silhouette_cue=cfg.chpf.silhouette_cue,
            refine_neighbours=lik.refine_neighbours,
            reference=cfg.chpf.reference if method in ("chpf", "chrbpf") else "none",
            reference_anchors=cfg.chpf.reference_anchors,
        )
        diameter = float(bundle.obj_info.diameter)
        cand = cfg.candidates
        self.candidates = CandidateSampler(
            z_range=cand.z_range,
            box_extent=self.likelihood.box_extent if cand.z_from_box else None,
            z_box_factors=cand.z_box_factors,
            depth_offset=cand.depth_offset or (0.0, 0.5 * diameter),
            depth_window=cand.depth_window,
            use_depth=rgbd,
            uv_fraction=cand.box_uv_fraction,
            occluded_box=cand.occluded_box,
            occluded_rule=cand.occluded_rule,
            outline_box=self.likelihood.outline_box,
            rotations=None
            if cand.rotations == "uniform"
            else CodebookRotations(
                self.likelihood,
                cand.temperature,
                cand.uniform_share,
                cand.rerank,
                cand.c_temperature,
            ),
        )
        self.filter: Filter = make_filter(
            method, self.likelihood, cfg, self.candidates, np.random.default_rng(self.seed)
        )
        self.boxes = BoxChecker("Tracker.step")  # warns once per tracker
        self.search = SearchRegion(
            cfg.search, lambda: self.likelihood.outline, self.likelihood, self.likelihood
        )
        self.frame = 0  # frames stepped since the last reset

    @classmethod
    def from_bundle(
        cls,
        path: str | Path | Bundle,
        method: str = "chpf",
        n_particles: int | None = 50,
        modality: str = "rgb",
        seed: int = 0,
        config: str | Path | dict[str, Any] | TrackConfig | None = None,
        device: str | None = None,
        **sections: dict[str, Any],
    ) -> Tracker:
        """Load the bundle folder ``path`` (or use a loaded Bundle) and build a Tracker.

        ``config``: a YAML file / nested dict / TrackConfig; ``sections`` override keys of
        its sections (e.g. motion={"sigma_t": 0.02}, srl={"beta": 0.5}); n_particles sets
        filter.n_particles (None: the config's); device sets runtime.device (auto | cpu |
        cuda; None: the config's). Raises BundleError / ConfigError.
        """
        if device is not None:
            sections = {**sections, "runtime": {**sections.get("runtime", {}), "device": device}}
        if n_particles is not None:
            sections = {
                **sections,
                "filter": {**sections.get("filter", {}), "n_particles": n_particles},
            }
        cfg = make_config(config, **sections)
        if isinstance(path, Bundle):
            bundle = path
        else:
            bundle = Bundle.load(
                path,
                threads=cfg.runtime.threads,
                spin=cfg.runtime.spin,
                precision=cfg.runtime.precision,
                device=cfg.runtime.device,
            )
        return cls(bundle, method=method, modality=modality, seed=seed, config=cfg)

    def reset(self, seed: int | Sequence[int] | None = None) -> None:
        """Start a new sequence (optionally with a new seed: an int or a tuple of ints)."""
        if seed is not None:
            self.seed = seed
        self.frame = 0
        self.filter.reset()
        self.search.reset()
        self.filter.rng = np.random.default_rng(self.seed)

    def step(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        K: np.ndarray | None = None,
        box: Box | None = None,
    ) -> TrackResult:
        """One frame: rgb (H,W,3) uint8, depth (H,W) float32 m or None (non-finite or negative
        values are missing, as 0 is), K (3,3), box (x,y,w,h) pixels or None: before the first
        box nothing is tracked; after it None means the search region around the estimate
        (``search.box_source``: auto, until a box comes after the first, or estimate; with
        ``detections``, or auto once a detector runs, it means predict only;
        ``estimate`` also ignores the boxes given; see chpf.tracking.search_region). An
        invalid box counts as None (warned once: see ``chpf.tracking.boxes.BoxChecker``; text
        is an InputError). Returns a TrackResult (pose R, t metres in the frame of the
        bundle's mesh file, alpha, ..., ``region``: the search region's area used)."""
        K_arr = check_frame(rgb, depth, K)  # type: ignore[arg-type]
        checked = self.boxes.check(box, f"frame {self.frame}")
        if self.modality == "rgb":
            depth = None
        elif depth is not None:
            depth = depth_in_metres(depth)
        self.frame += 1
        frame = self.search.frame(
            Frame(rgb=rgb, depth=depth, K=K_arr, box=checked), self.filter.estimate, self.filter.rng
        )
        result = self.filter.step(frame)
        self.search.update(result, self.config.filter.n_particles)
        result.region = None if frame.region is None else frame.region.window
        if result.R is not None and result.t is not None:  # the bundle's frame -> the mesh's
            result.t = self.bundle.obj_info.to_file_frame(result.R, result.t)
        return result
