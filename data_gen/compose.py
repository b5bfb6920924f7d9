"""Online composition of pairs / autoencoder samples from the cached pools (numpy/cv2 only).

Observed crop of one sample (entry e of the observation pool, window of side P):

1. background patch (procedural texture / user image / plain colour), P x P;
2. clutter: 0..clutter_max other-object crops pasted behind the object;
3. the object's window render (one of its lights) pasted through its mask;
4. with probability ``occlusion.prob``: one occluder (another object's crop or a random shape)
   slid over the object to cover a fraction drawn from ``occlusion.fraction_range``;
   ``visib_fract`` = visible / all object pixels of the window, counted exactly on the masks;
5. crop jitter: the translation estimate t' = t + noise (xy: ``crop_jitter.xy_sigma`` x
   diameter, z: ``crop_jitter.z_sigma`` x z); the S x S crop the tracker would cut at t' is
   warped out of the window (``chpf.crops.extract_crops`` with the composed affine);
6. colour jitter, blur, noise on the crop.

Autoencoder targets are the clean canonical renders of the entries' orientations; with
``crop_jitter.ae_target: follow`` they are re-cut by the same jitter (shifted and scaled as the
input), so that the embedding, and with it the likelihood L, tells a misplaced crop apart.

Empty crops (``empty_crops``): a share of ae samples and of pair negatives skip step 3 (and the
occluder), i.e. the crop a particle far off the object would see; their ae target is empty
(black, no mask) and their pair label misaligned.

Candidates (pairs) come from the codebook pool: the grid entry nearest to the hypothesis.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from chpf.crops import CropSpec, crop_affines, extract_crops
from chpf.geometry import RotationGrid
from data_gen import augment
from data_gen.pool import (
    ObsPool,
    OccluderPool,
    TaskRunner,
    codebook_pool,
    crop_to_window_affines,
    load_codebook_pool,
    load_obs_pool,
    load_occluder_pool,
    obs_pool,
    occluder_objects,
    occluder_pool,
)
from data_gen.pool_store import release
from data_gen.rotations import draw_candidates, symmetry_set


def aligned_depth_bound(pairs_cfg: dict) -> float:
    """|ln(z_crop / z)| below which a crop counts as cut at the right depth when scale
    negatives are on: half the low end of ``pairs.scale_negative_range``."""
    return 0.5 * float(pairs_cfg["scale_negative_range"][0])


def scale_error(depth_ratio: np.ndarray) -> np.ndarray:
    """A crop's scale error |ln(z_crop / z)| (N,) float64 from its ``depth_ratio`` (N,)."""
    return np.abs(np.log(np.maximum(np.asarray(depth_ratio, dtype=np.float64), 1e-6)))


def depth_off(depth_ratio: np.ndarray, pairs_cfg: dict) -> np.ndarray:
    """Which observed crops (N,) bool were cut at a wrong depth (scale negatives: every
    hypothesis misaligned), from their ``depth_ratio`` (N,) and the data's ``pairs`` config;
    none when it made no scale negatives."""
    off = scale_error(depth_ratio)
    if float(pairs_cfg.get("scale_negative_share", 0.0)) <= 0:
        return np.zeros(off.shape, bool)
    return off >= aligned_depth_bound(pairs_cfg)


@dataclass
class ComposerContext:
    """A generation job: the object, crop spec, config, pool cache and sample kind."""

    obj: object  # chpf.objects.ObjectModel
    spec: CropSpec
    cfg: dict
    cache_dir: str | None
    kind: str  # "pairs" | "ae"


@dataclass
class ComposerSetup:
    """What a Composer needs (small, picklable, no mesh: worker processes never import trimesh):
    the pool folders and the object's diameter and symmetries."""

    kind: str
    spec: CropSpec
    cfg: dict
    diameter: float
    symmetries_discrete: list
    symmetries_continuous: list
    obs_dir: str
    occluder_dir: str | None
    codebook_dir: str | None


def build_pools(ctx: ComposerContext, workers: int = 1, progress: bool = True) -> ComposerSetup:
    """Make sure every pool ``ctx`` needs exists (renders the missing ones with ``workers``
    processes shared by all pools) and return the Composer setup pointing at them."""
    from chpf.objects import object_fingerprint
    from data_gen.pool import codebook_pool_path, occluder_pool_path

    cfg = ctx.cfg
    occ = occluder_objects(cfg["occluder_pool"]["objects"], object_fingerprint(ctx.obj))
    with TaskRunner(workers) as runner:
        kw = {"progress": progress, "runner": runner}
        cb_dir = None
        if ctx.kind == "pairs":
            k = cfg["codebook"]["size"]
            codebook_pool(ctx.obj, ctx.spec, k, ctx.cache_dir, mmap=True, **kw)
            cb_dir = str(codebook_pool_path(ctx.obj, ctx.spec, k, ctx.cache_dir))
        op = obs_pool(ctx.obj, ctx.spec, cfg["obs_pool"], ctx.cache_dir, **kw)
        occluder_pool(occ, ctx.spec.size, cfg["occluder_pool"], ctx.cache_dir, **kw)
    occ_dir = occluder_pool_path(occ, ctx.spec.size, cfg["occluder_pool"], ctx.cache_dir)
    return ComposerSetup(
        kind=ctx.kind,
        spec=ctx.spec,
        cfg=cfg,
        diameter=float(ctx.obj.diameter),
        symmetries_discrete=[np.asarray(T) for T in ctx.obj.symmetries_discrete],
        symmetries_continuous=[dict(s) for s in ctx.obj.symmetries_continuous],
        obs_dir=str(op.path),
        occluder_dir=None if occ_dir is None else str(occ_dir),
        codebook_dir=cb_dir,
    )


class Composer:
    """Composes pairs / ae samples from the cached pools of one object."""

    def __init__(self, setup: ComposerSetup) -> None:
        self.setup = setup
        self.kind = setup.kind
        self.cfg = setup.cfg
        self.spec = setup.spec
        self.S = setup.spec.size
        self.obs: ObsPool = load_obs_pool(setup.obs_dir)
        self.P = self.obs.mask.shape[1]
        self.occ: OccluderPool = load_occluder_pool(setup.occluder_dir, self.S)
        self.bg = augment.Backgrounds.from_config(
            self.cfg["background"], Path(setup.obs_dir).parent
        )
        self.diameter = setup.diameter
        self.sym_rots, self.sym_axes = symmetry_set(
            setup.symmetries_discrete, setup.symmetries_continuous
        )
        self.grid = None
        self.cb = None
        if setup.kind == "pairs":
            self.grid = RotationGrid.uniform(self.cfg["codebook"]["size"])
            self.cb = load_codebook_pool(setup.codebook_dir)

    # ------------------------------------------------------------------------- observed crops

    def _occluder(self, rng: np.random.Generator, side: int) -> tuple[np.ndarray, np.ndarray]:
        """An occluder (rgb, mask) of about ``side`` pixels: another object or a random shape."""
        use_obj = len(self.occ) and rng.random() < self.cfg["occlusion"]["object_share"]
        if use_obj:
            i = int(rng.integers(0, len(self.occ)))
            rgb, m = self.occ.rgb[i], self.occ.mask[i]
            if side != self.S:
                rgb = cv2.resize(rgb, (side, side), interpolation=cv2.INTER_LINEAR)
                m = cv2.resize(
                    m.view(np.uint8), (side, side), interpolation=cv2.INTER_NEAREST
                ).view(bool)
            if rng.random() < 0.5:
                rgb, m = rgb[:, ::-1], m[:, ::-1]
            return np.ascontiguousarray(rgb), np.ascontiguousarray(m)
        return augment.random_shape(rng, side, self.bg.textures)

    def compose_window(
        self, e: int, rng: np.random.Generator, with_object: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Window image (P,P,3) u8 of pool entry ``e`` with background, clutter, occluder;
        ``with_object=False`` gives background and clutter only (an empty crop).

        Returns (window, object mask (P,P), visible object mask (P,P), visib_fract).
        """
        P, S = self.P, self.S
        cfg = self.cfg
        if not with_object and rng.random() < cfg["empty_crops"]["plain_share"]:
            # plain (half of them dark: the unlit background of a rendered scene)
            win = augment.plain_patch(rng, P, 40 if rng.random() < 0.5 else 256)
        else:
            win = self.bg.sample(rng, P)
        # clutter behind the object
        n_clutter = (
            int(rng.integers(0, cfg["background"]["clutter_max"] + 1)) if len(self.occ) else 0
        )
        for _ in range(n_clutter):
            side = int(S * rng.uniform(0.5, 1.2))
            rgb, m = self._occluder_object(rng, side)
            y0, x0 = (int(v) for v in rng.integers(-side // 2, P - side // 2, 2))
            augment.paste(win, rgb, m, y0, x0)
        if not with_object:
            empty = np.zeros((P, P), bool)
            return win, empty, empty, 0.0
        obj_mask = np.asarray(self.obs.mask[e])
        L = self.obs.rgb.shape[1]
        light = int(rng.integers(0, L)) if L > 1 else 0
        a = self.obs.alpha[e]
        inv = (255 - a).astype(np.uint16)[..., None]
        win = np.minimum(self.obs.rgb[e, light] + (win * inv + 127) // 255, 255).astype(np.uint8)
        covered = np.zeros((P, P), bool)
        occ_cfg = cfg["occlusion"]
        if rng.random() < occ_cfg["prob"]:
            target = float(rng.uniform(*occ_cfg["fraction_range"]))
            area = int(obj_mask.sum())
            side = int(S * rng.uniform(*occ_cfg["scale_range"]))
            rgb, m = self._occluder(rng, max(side, 4))
            m_area = int(m.sum())
            if m_area < 0.1 * m.size:  # a sliver (e.g. an object seen edge-on): use a shape
                rgb, m = augment.random_shape(rng, max(side, 4), self.bg.textures)
                m_area = int(m.sum())
            if m_area < 1.3 * target * area and m_area > 0:  # too small to reach the target
                side = int(np.ceil(side * np.sqrt(1.3 * target * area / m_area)))
                rgb = cv2.resize(rgb, (side, side), interpolation=cv2.INTER_LINEAR)
                m = cv2.resize(
                    m.view(np.uint8), (side, side), interpolation=cv2.INTER_NEAREST
                ).view(bool)
            y0, x0 = augment.place_occluder(obj_mask, m, target, rng)
            augment.paste(win, rgb, m, y0, x0, covered)
        visible = obj_mask & ~covered
        n_all = int(obj_mask.sum())
        visib = float(visible.sum()) / n_all if n_all else 0.0
        return win, obj_mask, visible, visib

    def _occluder_object(self, rng: np.random.Generator, side: int):
        i = int(rng.integers(0, len(self.occ)))
        rgb = cv2.resize(np.asarray(self.occ.rgb[i]), (side, side), interpolation=cv2.INTER_LINEAR)
        m = cv2.resize(
            np.asarray(self.occ.mask[i]).view(np.uint8),
            (side, side),
            interpolation=cv2.INTER_NEAREST,
        ).view(bool)
        return rgb, m

    def jittered_translations(
        self, e: np.ndarray, rng: np.random.Generator, depth_factor: np.ndarray | None = None
    ) -> np.ndarray:
        """Translation estimates t' (N,3) around the true t of entries e (crop jitter); where
        ``depth_factor`` (N,) is finite, z' is z times it (scale negatives), and with scale
        negatives on, every other z' / z stays within exp(+-lo / 2) of 1 (lo: the low end of
        ``pairs.scale_negative_range``), so that no aligned crop is as far off in depth."""
        t = np.asarray(self.obs.t)[e]
        j = self.cfg["crop_jitter"]
        n = len(e)
        noise = np.empty((n, 3))
        noise[:, :2] = rng.normal(0.0, j["xy_sigma"] * self.diameter, (n, 2))
        noise[:, 2] = rng.normal(0.0, j["z_sigma"], n) * t[:, 2]
        t_est = t + noise
        t_est[:, 2] = np.maximum(t_est[:, 2], 0.5 * t[:, 2])
        if depth_factor is not None:
            half = aligned_depth_bound(self.cfg["pairs"])
            ratio = np.clip(t_est[:, 2] / t[:, 2], np.exp(-half), np.exp(half))
            t_est[:, 2] = t[:, 2] * np.where(np.isfinite(depth_factor), depth_factor, ratio)
        return t_est

    def observed(
        self,
        rng: np.random.Generator,
        n: int,
        debug: bool = False,
        empty: np.ndarray | None = None,
        depth_factor: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """n augmented observed crops: rgb (n,S,S,3) u8, entry (n,), visib_fract (n,) f32,
        t_est (n,3); with ``debug`` also mask / visible_mask (n,S,S) bool crops (un-augmented
        geometry, nearest-neighbour warps). ``empty`` (n,) bool: crops without the object.
        ``depth_factor`` (n,): see ``jittered_translations``."""
        S = self.S
        e = rng.integers(0, len(self.obs), n)
        t_est = self.jittered_translations(e, rng, depth_factor)
        M = crop_to_window_affines(
            t_est, np.asarray(self.obs.K)[e], np.asarray(self.obs.win_affine)[e], self.spec
        )
        rgb = np.empty((n, S, S, 3), np.uint8)
        visib = np.empty(n, np.float32)
        masks = np.empty((n, S, S), bool) if debug else None
        vmasks = np.empty((n, S, S), bool) if debug else None
        for i in range(n):
            with_object = empty is None or not empty[i]
            win, obj_mask, visible, visib[i] = self.compose_window(int(e[i]), rng, with_object)
            crop = extract_crops(win, M[i : i + 1], S)[0]
            rgb[i] = augment.augment_crop(crop, rng, self.cfg)
            if debug:
                mm = np.stack([obj_mask, visible], -1).astype(np.uint8)
                w = cv2.warpAffine(
                    mm, M[i], (S, S), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0
                )
                masks[i], vmasks[i] = w[..., 0] > 0, w[..., 1] > 0
        out = {"rgb": rgb, "entry": e, "visib_fract": visib, "t_est": t_est}
        if debug:
            out["mask"], out["visible_mask"] = masks, vmasks
        return out

    # ------------------------------------------------------------------------- samples

    def candidates(
        self, R_true: np.ndarray, aligned: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Codebook indices (N,) and symmetry-aware angles (N,) rad of candidates for true
        allocentric rotations R_true (N,3,3) (``data_gen.rotations.draw_candidates``)."""
        return draw_candidates(
            self.grid, R_true, aligned, self.cfg["pairs"], self.sym_rots, self.sym_axes, rng
        )

    def scale_negatives(
        self, aligned: np.ndarray, empty: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Which pairs (n,) bool are scale negatives (``pairs.scale_negative_share`` of the
        negatives with the object: the orientation drawn as a positive's, the crop at a wrong
        depth) and the depth factors (n,) of their crops (nan elsewhere); None for the factors
        when the share is 0 (no random numbers drawn: the data stay as before)."""
        p = self.cfg["pairs"]
        n = len(aligned)
        if p["scale_negative_share"] <= 0:
            return np.zeros(n, bool), None
        scaled = (aligned == 0) & ~empty & (rng.random(n) < p["scale_negative_share"])
        lo, hi = p["scale_negative_range"]
        log_f = rng.uniform(lo, hi, n) * np.where(rng.random(n) < 0.5, -1.0, 1.0)
        return scaled, np.where(scaled, np.exp(log_f), np.nan)

    def pairs(self, rng: np.random.Generator, n: int, debug: bool = False) -> dict:
        """n pair samples (spec fields; with ``debug`` also obs/cand masks, entry, t_est)."""
        n_pos = round(self.cfg["pairs"]["positive_share"] * n)
        aligned = np.zeros(n, np.uint8)
        aligned[:n_pos] = 1
        aligned = rng.permutation(aligned)
        empty = (aligned == 0) & (rng.random(n) < self.cfg["empty_crops"]["pairs_negative_share"])
        scaled, factor = self.scale_negatives(aligned, empty, rng)
        obs = self.observed(rng, n, debug, empty, factor)
        R_true = np.asarray(self.obs.R_allo)[obs["entry"]]
        idx, ang = self.candidates(R_true, aligned | scaled, rng)
        true_z = np.asarray(self.obs.t)[obs["entry"], 2]
        order = np.argsort(idx, kind="stable")  # sorted reads from the memory-mapped pool
        cand_rgb = np.empty((n, self.S, self.S, 3), np.uint8)
        cand_depth = np.empty((n, self.S, self.S), np.float16)
        cand_rgb[order] = self.cb.rgb[idx[order]]
        cand_depth[order] = self.cb.depth[idx[order]].astype(np.float16)
        out = {
            "obs_rgb": obs["rgb"],
            "cand_rgb": cand_rgb,
            "cand_depth": cand_depth,
            "aligned": aligned,
            "obs_R_allo": R_true.astype(np.float32),
            "cand_R_allo": self.grid.rotations[idx].astype(np.float32),
            "angle_deg": np.degrees(ang).astype(np.float32),
            "visib_fract": obs["visib_fract"],
            "depth_ratio": (obs["t_est"][:, 2] / true_z).astype(np.float32),
        }
        if debug:
            out.update(
                obs_mask=obs["mask"],
                obs_visible_mask=obs["visible_mask"],
                cand_mask=np.asarray(self.cb.mask)[idx],
                entry=obs["entry"],
                t_est=obs["t_est"],
                cand_idx=idx,
            )
        return out

    def follow_jitter(
        self, target: np.ndarray, mask: np.ndarray, e: np.ndarray, t_est: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Centred clean targets (N,S,S,3) and masks (N,S,S) of entries e re-cut as the crops
        at the jittered translations t_est (N,3) see them: crop(t_est) pixel -> image pixel ->
        crop(t) pixel, the similarity that shifts and scales the object like the input."""
        t = np.asarray(self.obs.t)[e]
        K = np.asarray(self.obs.K)[e]
        true_crops = np.stack([crop_affines(t[i], K[i], self.spec)[0] for i in range(len(e))])
        M = crop_to_window_affines(t_est, K, true_crops, self.spec)  # "window" = crop at t
        size, inv = (self.S, self.S), cv2.WARP_INVERSE_MAP
        out_rgb, out_mask = np.empty_like(target), np.empty_like(mask)
        for i in range(len(e)):
            out_rgb[i] = cv2.warpAffine(target[i], M[i], size, flags=cv2.INTER_LINEAR | inv)
            m = mask[i].view(np.uint8)
            out_mask[i] = cv2.warpAffine(m, M[i], size, flags=cv2.INTER_NEAREST | inv).view(bool)
        return out_rgb, out_mask

    def ae(self, rng: np.random.Generator, n: int, debug: bool = False) -> dict:
        """n autoencoder samples (spec fields; with ``debug`` also input masks, entry, t_est)."""
        empty = rng.random(n) < self.cfg["empty_crops"]["ae_share"]
        obs = self.observed(rng, n, debug, empty)
        e = obs["entry"]
        order = np.argsort(e, kind="stable")
        target = np.empty((n, self.S, self.S, 3), np.uint8)
        tmask = np.empty((n, self.S, self.S), bool)
        target[order] = self.obs.clean_rgb[e[order]]
        tmask[order] = self.obs.clean_mask[e[order]]
        if self.cfg["crop_jitter"]["ae_target"] == "follow":
            target, tmask = self.follow_jitter(target, tmask, e, obs["t_est"])
        target[empty], tmask[empty] = 0, False
        out = {
            "input_rgb": obs["rgb"],
            "target_rgb": target,
            "target_mask": tmask,
            "R_allo": np.asarray(self.obs.R_allo)[e].astype(np.float32),
            "visib_fract": obs["visib_fract"],
        }
        if debug:
            out.update(
                input_mask=obs["mask"],
                input_visible_mask=obs["visible_mask"],
                entry=e,
                t_est=obs["t_est"],
            )
        return out

    def release_pages(self) -> None:
        """Unmap the pool pages read so far (``pool_store.release``); call between shards."""
        arrays = [getattr(self.obs, f) for f in ObsPool.FIELDS] + [self.occ.rgb, self.occ.mask]
        if self.cb is not None:
            arrays += [self.cb.rgb, self.cb.depth, self.cb.mask]
        release(arrays)

    def generate(self, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
        """n samples of the context's kind (spec fields only)."""
        return self.pairs(rng, n) if self.kind == "pairs" else self.ae(rng, n)
