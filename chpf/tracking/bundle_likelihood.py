"""Likelihoods from a model bundle, batched over the particles.

For N hypotheses (egocentric R (N,3,3), t (N,3) metres) of one frame:

1. crop: the scale-normalised crop of each particle (chpf.crops: square centred on the
   projection of t, side S * (D_r / z) * (f / f_r)), resized to S x S;
2. encode: one autoencoder pass over the N crops (the classifier's observed branch reuses it
   when the bundle's CH shares the AE encoder, else one more pass with the CH encoder);
3. lookup: nearest codebook entry of each particle's allocentric rotation R_ray(t)^T R;
   cosine c with that entry's AE embedding; w = exp(-(1 - c)^2 / (2 sigma^2)) and the
   unnormalised likelihood L in [0, 1] by ``l_from_cos``: "clip" L = max(c, 0) or "affine"
   L = (1 + c) / 2 (see L_FROM_COS);
4. head: C = p_misaligned(observed CH embedding, codebook CH embedding of the entry);
5. depth (RGB-D): L_depth and C_depth from the codebook depth crops (chpf.tracking.depth_scores);
   the importance weight w is multiplied by L_depth; C is the learned C, C_depth or their mean
   (``c_mode``). L stays the appearance's, as PoseRBPF's similarity that decides its resets:
   the strategies compare it with a fixed scale (SRL's beta) or with C, and L_depth, a fraction
   that falls to 0 a few centimetres off the measured surface, would shrink it for every
   particle of a good belief and hold their alpha near 1 (a random search: ADD-S AUC 0 on
   a partly occluded box sequence). Depth's counter-evidence reaches CH-PF's alpha through
   C_depth (``c_mode`` depth or both);
6. box scale (``c_box``, a scale, None = off; ``c_box_shape``): a hypothesis whose object
   would project smaller than the detection box, by the ratio rho = box side / projected side
   (the larger side of the box of the model's outline points, chpf.tracking.model_outline,
   projected at the particle's pose), is impossible up to the detector's size noise (the box
   shows at most the whole object; a larger hypothesis is explained by occlusion): C_box =
   ``box_counter_evidence(rho, c_box, c_box_shape)``, and C becomes 1 - (1 - C)(1 - C_box).
   On a frame without a detection, a search region's box fitted to the image (``Region.fitted``,
   chpf.tracking.search_region) measures the size instead (``Frame.scale_box``).
   Per side (``c_box_sides`` "each"; "larger": the larger sides only): rho_x, rho_y = box
   width / projected width, box height / projected height, and C_box = 1 - (1 - C_box(rho_x))
   (1 - C_box(rho_y)): an occluder shortens a side, never lengthens one, so the side it left
   whole still measures the depth. With ``box_whole`` q (None = off) a side shorter than the
   projection's weighs w (not C, not alpha) by 1 - q C_box(1 / rho), the too-near side of a
   box that is whole with probability q: a box whole on both sides holds the depth from both
   ends, and on a side an occluder cut, every depth gets about 1 - q there, so the cut side
   pushes no hypothesis away (the larger side alone could not tell a cut side from a whole one).
   Neither network sees a wrong depth well (the crops are scale-normalised): at the true pose
   of the development suite's unoccluded frames the mean L is 0.747 at the true depth, 0.742
   at 1.03 x and 0.708 at 1.1 x it, C 0.021, 0.024, 0.040.

   Edge (``c_edge``, a margin m, None = off): the visible part of an object lies inside its
   projection, so a hypothesis whose projected outline box leaves an edge of the detection box
   outside it, by o (the largest overshoot, as a fraction of the projected side), is
   contradicted whatever the occlusion: C_edge = ``edge_counter_evidence(o, m)`` = clip((o -
   m) / m, 0, 1), none within the detector's noise. It is ``Scores.C_edge``, which CH-PF's
   alpha counts and its weights do not: a containment test favours hypotheses that project
   larger (too near), which neither network nor C_box contradicts, so in the weights it
   pulled the set's depth nearer (docs/chpf-ablations.md).

   Near (``c_near``, a margin m, None = off): a hypothesis whose projected box extends past the
   detection box on all four sides, by o (the least of the four, a fraction of the projected
   side), is too near: an occluder shrinks the box from one or two sides, not from all four.
   C_near = ``edge_counter_evidence(o, m)`` joins C_edge (1 - (1 - C_edge)(1 - C_near)).

7. orientation search (``refine_neighbours`` k > 1, 0 = off): before steps 3-4, each particle's
   nearest entry and its k - 1 nearest grid neighbours are compared with its crop's embedding
   (the crop depends on t only, so no more encoder passes), and the particle's orientation moves
   by the rotation from its entry to the best of them (R_allo <- G_best G_entry^T R_allo): one
   step of a local search per weighing that keeps each particle's offset from the grid. The
   moved orientations come back in ``Scores.R``; the filter adopts them.

8. reference (``reference``, for CH-PF and CH-RBPF; CHPF_REFERENCES): on a frame with the
   box it names (the detection; with "box" also, on a frame without one, the search region's
   box around the estimate while it is not widened: ``Frame.cue_box``), the crop at the box's
   centre (encoded in the particles' batch) against the whole codebook: the best entry's L and
   its C (learned, without the box scale: its depth would come from the box) are
   ``Scores.reference`` (L_ref, C_ref), what a pose can score on this frame's view of the
   object. Under occlusion they fall with the visible part as the true pose's do. One crop's
   best entry is a poor yardstick for C, and a detection of the visible part is read as a
   whole object farther away, the same misreading as a set that lost the object there. So on
   a frame with a detection and with ``reference_anchors`` (sides a), C_ref is the least C over
   that crop and the crops of the squares of side a times the detection's longer side flush
   with its sides, corners or centred (``anchored_boxes``: where the whole object would be,
   were the detection its visible part), each at its best-cosine entry. A search region's box
   is the model's projection at the estimate, never a visible part: there the box crop alone.
   With a can passing in front of the shipped box bundle's object the box crop's C_ref was
   0.94-0.99 on frames where C at the true pose was 0.00, and within 0.06 of it with them.

9. silhouette (``c_silhouette``, a power p, None = off; CH-PF's C; ``silhouette_cue``): how
   well each hypothesis's projected outline fits the image, a (chpf.tracking.silhouette: the
   colour contrast across it, "region", or its edges, "edges"), and C becomes 1 - (1 - C)(1 -
   C_sil) with C_sil = 1 - (a / max a)^p, the max over the hypotheses weighed together and,
   with a reference, the box's single-frame estimate, whose own C_sil joins C_ref. Unlike the
   crops, the outline sees a depth error: at the true orientation of the development suite's
   unoccluded frames the region contrast peaks at the true depth (not 5 % off) on 136 of
   137 frames, and falls to 0.65 of its peak 5 % too far. Scored with the set, the estimate
   is the yardstick: a set whose outlines all fit worse than the box's own guess is in doubt
   (a set all at a wrong depth has none of its own to compare), and one that fits better than
   that guess is not doubted for the spread the motion model gives it.

Particles with z below ``z_min`` (behind or at the camera) get c = -1 (L = 0) and C = 1.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from chpf.bundle import Bundle
from chpf.crops import CropSpec, crop_affines, extract_crops
from chpf.errors import ConfigError
from chpf.geometry import allocentric_to_egocentric, ray_rotation
from chpf.tracking.candidates import box_translations, corners, inner_margins, valid_box
from chpf.tracking.config import BOX_SHAPES, BOX_SIDES, C_MODES, L_FROM_COS
from chpf.tracking.depth_scores import depth_scores
from chpf.tracking.model_outline import outline_points, project_outline
from chpf.tracking.rotation_diffusion import neighbour_table
from chpf.tracking.silhouette import (
    SilhouetteEdges,
    SilhouetteRegion,
    outline_scale,
    silhouette_counter_evidence,
)
from chpf.tracking.strategies import CHPF_REFERENCES, SILHOUETTE_CUES, either
from chpf.tracking.timing import ms_since
from chpf.tracking.types import Box, CodebookScores, Frame, Reference, Scores


def box_counter_evidence(rho: np.ndarray, scale: float, shape: str) -> np.ndarray:
    """C_box (N,) in [0, 1] of box / projected side ratios rho (N,) > 0 (module docstring,
    item 6; BOX_SHAPES): "gauss" 1 - exp(-ln(rho)^2 / (2 scale^2)) for rho > 1, "ramp"
    clip((rho - 1 - scale) / scale, 0, 1); 0 where rho <= 1."""
    if shape == "ramp":
        return np.clip((rho - 1.0 - scale) / scale, 0.0, 1.0)
    excess = np.maximum(np.log(rho), 0.0) / scale
    return 1.0 - np.exp(-0.5 * excess**2)


def edge_counter_evidence(overshoot: np.ndarray, margin: float) -> np.ndarray:
    """C_edge (N,) in [0, 1] of overshoots (N,) (the largest distance by which an edge of the
    detection box lies outside a hypothesis's projected box, over the projected side; module
    docstring, item 6): clip((overshoot - margin) / margin, 0, 1)."""
    return np.clip((overshoot - margin) / margin, 0.0, 1.0)


def likelihood_from_cosine(c: np.ndarray, mode: str) -> np.ndarray:
    """Unnormalised likelihood L (N,) in [0, 1] of cosine similarities c (N,) (L_FROM_COS)."""
    if mode == "clip":
        return np.maximum(c, 0.0)
    if mode == "affine":
        return np.clip(0.5 * (1.0 + c), 0.0, 1.0)
    raise ConfigError(f"l_from_cos must be one of {L_FROM_COS}, got {mode!r}")


def _codebook_extent(depth: np.ndarray, scale: float) -> np.ndarray:
    """Largest side (K,) of each codebook entry's object box, in crop pixels (S)."""
    mask = depth > 0
    sd = depth.shape[1]

    def span(occupied: np.ndarray) -> np.ndarray:  # (K, Sd) bool -> (K,) occupied extent
        first = np.argmax(occupied, axis=1)
        last = sd - 1 - np.argmax(occupied[:, ::-1], axis=1)
        return np.where(occupied.any(axis=1), last - first + 1, 0)

    return np.maximum(span(mask.any(axis=2)), span(mask.any(axis=1))).astype(np.float64) * scale


def anchored_boxes(box: Box, scales: tuple[float, ...]) -> np.ndarray:
    """The object's whole box, were ``box`` (x, y, w, h) pixels only its visible part: squares
    (M,4) (x, y, w, h) of side a max(w, h) for each a in ``scales``, flush with the box's left
    side, its right side or centred across it, and likewise with its top, its bottom or centred
    (9 per scale), repeats dropped and so is the centred square of side max(w, h), whose crop is
    the box's own (box_translations: its centre, its longer side)."""
    x, y, w, h = box
    out = []
    for a in scales:
        side = a * max(w, h)
        for x0 in (x, x + w - side, x + 0.5 * (w - side)):
            for y0 in (y, y + h - side, y + 0.5 * (h - side)):
                out.append((x0, y0, side, side))
    side = max(w, h)
    own = np.round([x + 0.5 * (w - side), y + 0.5 * (h - side), side, side], 3)
    boxes = np.unique(np.round(np.array(out), 3), axis=0)
    return boxes[~np.all(boxes == own, axis=1)]


class BundleLikelihood:
    """AE likelihood L, learned C, depth L_depth / C_depth from a Bundle (see module docstring).

    sigma: width of w = exp(-(1 - c)^2 / (2 sigma^2)). l_from_cos: "clip" | "affine" (L from
    c, see L_FROM_COS). c_mode: "learned" | "depth" | "both" | "none" (C = None). use_depth:
    use frame.depth when given (RGB-D). depth_margin / c_depth_margin: metres. depth_no_data:
    L_depth and C_depth without valid depth pixels. refine_neighbours: grid entries compared
    by the orientation search (module docstring, item 7; 0 = off). reference: attach the
    frame's reference scores (item 8) to Scores and CodebookScores.
    """

    def __init__(
        self,
        bundle: Bundle,
        sigma: float = 0.3,
        c_mode: str = "learned",
        l_from_cos: str = "clip",
        use_depth: bool = False,
        depth_margin: float = 0.03,
        c_depth_margin: float = 0.02,
        depth_no_data: float = 0.5,
        z_min: float = 0.05,
        c_box: float | None = None,
        c_box_shape: str = "gauss",
        c_box_sides: str = "larger",
        box_whole: float | None = None,
        c_edge: float | None = None,
        c_near: float | None = None,
        c_silhouette: float | None = None,
        silhouette_cue: str = "region",
        refine_neighbours: int = 0,
        reference: str = "none",
        reference_anchors: tuple[float, ...] = (),
    ) -> None:
        if c_mode not in C_MODES:
            raise ConfigError(f"c_mode must be one of {C_MODES}, got {c_mode!r}")
        if c_mode in ("depth", "both") and not use_depth:
            raise ConfigError(f"c_mode {c_mode!r} needs depth (modality rgbd)")
        if l_from_cos not in L_FROM_COS:
            raise ConfigError(f"l_from_cos must be one of {L_FROM_COS}, got {l_from_cos!r}")
        if reference not in CHPF_REFERENCES:
            raise ConfigError(f"reference must be one of {CHPF_REFERENCES}, got {reference!r}")
        if c_box_shape not in BOX_SHAPES:
            raise ConfigError(f"c_box_shape must be one of {BOX_SHAPES}, got {c_box_shape!r}")
        if c_box_sides not in BOX_SIDES:
            raise ConfigError(f"c_box_sides must be one of {BOX_SIDES}, got {c_box_sides!r}")
        if box_whole is not None and not 0 < box_whole <= 1:
            raise ConfigError(f"box_whole must be in (0, 1], got {box_whole}")
        if sigma <= 0:
            raise ConfigError(f"likelihood sigma must be > 0, got {sigma}")
        self.bundle = bundle
        self.spec: CropSpec = bundle.spec
        self.grid = bundle.grid
        self.sigma = float(sigma)
        self.c_mode = c_mode
        self.l_from_cos = l_from_cos
        self.use_depth = bool(use_depth)
        self.depth_margin = float(depth_margin)
        self.c_depth_margin = float(c_depth_margin)
        self.depth_no_data = float(depth_no_data)
        self.z_min = float(z_min)
        self.c_box = c_box
        self.c_box_shape = c_box_shape
        self.c_box_sides = c_box_sides
        self.box_whole = box_whole
        self.c_edge = c_edge
        self.c_near = c_near
        self.c_silhouette = c_silhouette
        self._outline: np.ndarray | None = None  # ``outline``, made on first use
        if silhouette_cue not in SILHOUETTE_CUES:
            raise ConfigError(
                f"silhouette_cue must be one of {SILHOUETTE_CUES}, got {silhouette_cue!r}"
            )
        self.silhouette: SilhouetteEdges | SilhouetteRegion | None = None
        if c_silhouette is not None:
            cue = SilhouetteEdges if silhouette_cue == "edges" else SilhouetteRegion
            self.silhouette = cue(self.outline * outline_scale(bundle, self.outline))
        self.reference = reference
        self.reference_anchors = tuple(float(a) for a in reference_anchors)
        # the cue box's crop rides along in the particles' encoder pass once it has been asked
        # for (_cue_embedding): (crop (S,S,3), its AE embedding (1,E)) of the last, or None
        self._cue_in_batch = reference != "none"
        self._cue: tuple[np.ndarray, np.ndarray] | None = None
        self._cue_ch: tuple[np.ndarray, np.ndarray] | None = None  # (that crop, its CH embedding)
        self.neighbours = (
            neighbour_table(self.grid, refine_neighbours) if refine_neighbours > 1 else None
        )
        self._codebook_t = np.ascontiguousarray(bundle.ae_codebook.T)  # (E,K): fast matmul
        sd = bundle.depth_size
        self.depth_spec = CropSpec(
            size=sd, render_distance=self.spec.render_distance, focal=float(bundle.depth_K[0, 0])
        )
        # object box side per codebook entry (crop pixels), for box-scale depth estimates
        all_depth = bundle.codebook_depth(np.arange(bundle.codebook_size))
        self.extent_px = _codebook_extent(all_depth, self.spec.size / sd)
        good = self.extent_px[self.extent_px > 0]
        self.median_extent_px = float(np.median(good)) if good.size else 0.9 * self.spec.size

    @property
    def box_extent(self) -> float:
        """Typical projected object extent in metres (box side = fx * box_extent / z)."""
        return self.median_extent_px * self.spec.render_distance / self.spec.focal

    # ------------------------------------------------------------------ pieces
    def _affines(self, frame: Frame, t: np.ndarray, spec: CropSpec) -> np.ndarray:
        """Crop affines (N,2,3) of ``spec`` at t (N,3), z clamped to at least ``z_min``."""
        t_safe = t.copy()
        t_safe[:, 2] = np.maximum(t_safe[:, 2], self.z_min)
        return crop_affines(t_safe, np.asarray(frame.K, dtype=np.float64), spec)

    def _crops_and_embed(
        self, frame: Frame, t: np.ndarray, ms: dict[str, float]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Crops (N,S,S,3) at t (N,3) and their AE embeddings (N,E); times into ``ms``. Once
        asked for (_cue_embedding), the cue box's crop rides along in the same encoder pass."""
        t_cue = self._cue_translation(frame) if self._cue_in_batch else None
        t_all = t if t_cue is None else np.vstack([t, t_cue])
        t0 = time.perf_counter()
        crops = extract_crops(frame.rgb, self._affines(frame, t_all, self.spec), self.spec.size)
        ms["crop"] = ms_since(t0)
        t0 = time.perf_counter()
        emb = self.bundle.embed(crops)
        ms["encode"] = ms_since(t0)
        if t_cue is None:
            return crops, emb
        self._cue = (crops[-1].copy(), emb[-1:].copy())
        return crops[:-1], emb[:-1]

    def _depth_crops(self, frame: Frame, t: np.ndarray) -> np.ndarray:
        aff = self._affines(frame, t, self.depth_spec)
        depth = np.asarray(frame.depth, dtype=np.float32)
        return extract_crops(depth, aff, self.depth_spec.size, interpolation=cv2.INTER_NEAREST)

    def _depth(self, frame: Frame, idx: np.ndarray, t: np.ndarray):
        meas = self._depth_crops(frame, t)
        return depth_scores(
            meas,
            self.bundle.codebook_depth(idx),
            t[:, 2],
            self.spec.render_distance,
            self.depth_margin,
            self.c_depth_margin,
            self.depth_no_data,
        )

    # ------------------------------------------------------------------ Likelihood
    def score(self, frame: Frame, R: np.ndarray, t: np.ndarray) -> Scores:
        """Scores of N hypotheses R (N,3,3), t (N,3) metres (see module docstring)."""
        ms: dict[str, float] = {}
        t = np.asarray(t, dtype=np.float64)
        crops, emb = self._crops_and_embed(frame, t, ms)
        need_c = self.c_mode in ("learned", "both")
        if need_c and not self.bundle.shares_encoder:
            t0 = time.perf_counter()
            ch_emb = self.bundle.ch_embed(crops)
            ms["ch_encode"] = ms_since(t0)
        else:
            ch_emb = emb

        t0 = time.perf_counter()
        R_ray = ray_rotation(t)  # once for both directions (egocentric_to_allocentric's)
        R_allo = np.swapaxes(R_ray, -1, -2) @ np.asarray(R, dtype=np.float64)
        idx = self.bundle.nearest(R_allo)
        R_moved = None
        if self.neighbours is None:
            c = self.bundle.cosine(emb, idx).astype(np.float64)
        else:
            idx, c, R_moved = self._search(emb, idx, R_allo, R_ray)
        behind = t[:, 2] < self.z_min
        c[behind] = -1.0
        L = likelihood_from_cosine(c, self.l_from_cos)
        w = np.exp(-((1.0 - c) ** 2) / (2.0 * self.sigma**2))
        ms["lookup"] = ms_since(t0)

        C = None
        if need_c:
            t0 = time.perf_counter()
            C = self.bundle.p_misaligned(ch_emb, idx).astype(np.float64)
            ms["head"] = ms_since(t0)

        if self.use_depth and frame.depth is not None:
            t0 = time.perf_counter()
            d = self._depth(frame, idx, t)
            w = w * d.L
            if self.c_mode == "depth":
                C = d.C
            elif self.c_mode == "both":
                C = 0.5 * (C + d.C)
            ms["depth"] = ms_since(t0)
        elif self.c_mode == "depth":
            C = np.full(t.shape[0], self.depth_no_data)  # an RGB-D run's frame without depth
        elif self.c_mode == "both" and C is not None:
            C = 0.5 * (C + self.depth_no_data)
        C_edge = None
        ref = self.frame_reference(frame)
        if C is not None:
            R_scored = R if R_moved is None else R_moved
            C_box, C_edge, whole = self._box_evidence(frame, R_scored, t)
            if whole is not None:
                w = w * whole
            C_sil, C_sil_ref = self._silhouette(frame, R_scored, t, ref is not None)
            C = np.where(behind, 1.0, either(either(C, C_sil), C_box))
            if ref is not None and C_sil_ref is not None:
                ref = (ref[0], float(either(np.array([ref[1]]), np.array([C_sil_ref]))[0]))
        return Scores(L=L, w=w, C=C, stage_ms=ms, R=R_moved, reference=ref, C_edge=C_edge)

    def _search(
        self, emb: np.ndarray, idx: np.ndarray, R_allo: np.ndarray, R_ray: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The orientation search (module docstring, item 7) for embeddings emb (N,E) of
        particles at entries idx (N,), allocentric R_allo (N,3,3), ray rotations R_ray (N,3,3)
        of their t (chpf.geometry.ray_rotation): the best entries (N,), their cosines (N,) and
        the moved egocentric orientations (N,3,3)."""
        assert self.neighbours is not None
        nb = self.neighbours[idx]  # (N,k), the entry itself first
        cos = np.einsum("ne,nke->nk", emb, self.bundle.ae_codebook[nb]).astype(np.float64)
        j = np.argmax(cos, axis=1)  # ties keep the particle's own entry
        rows = np.arange(idx.shape[0])
        best = nb[rows, j]
        G = self.grid.rotations
        moved = G[best] @ np.swapaxes(G[idx], -1, -2) @ R_allo
        return best, cos[rows, j], R_ray @ moved  # allocentric_to_egocentric(moved, t)

    def _silhouette(
        self, frame: Frame, R: np.ndarray, t: np.ndarray, with_reference: bool
    ) -> tuple[np.ndarray | None, float | None]:
        """C_sil (N,) of poses R (N,3,3), t (N,3) (chpf.tracking.silhouette; 1 behind the
        camera) and, when ``with_reference`` and the frame has a cue box, that of the box's
        single-frame estimate, scored in the same comparison (the best alignment is over the
        poses and it): the reference's share of the frame's counter-evidence (module
        docstring, item 9). (None, None) when off."""
        if self.silhouette is None or self.c_silhouette is None:
            return None, None
        est = self.single_frame_estimate(frame) if with_reference else None
        if est is not None:
            R = np.concatenate([R, est[0][None]])
            t = np.concatenate([t, est[1][None]])
        a = self.outline_contrast(frame, R, t)
        assert a is not None
        C_sil = np.where(
            t[:, 2] >= self.z_min, silhouette_counter_evidence(a, self.c_silhouette), 1.0
        )
        return (C_sil[:-1], float(C_sil[-1])) if est is not None else (C_sil, None)

    def outline_contrast(self, frame: Frame, R: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """The silhouette's alignment a (N,) of poses R (N,3,3), t (N,3) metres on the frame
        (item 9's, with its cue; 0 behind the camera); None when the silhouette is off."""
        if self.silhouette is None:
            return None
        ok = t[:, 2] >= self.z_min
        a = np.zeros(t.shape[0])
        if ok.any():
            a[ok] = self.silhouette.alignment(frame.rgb, frame.K, R[ok], t[ok], self.z_min)
        return a

    @property
    def outline(self) -> np.ndarray:
        """(M,3) metres, object frame: the model's outline points (chpf.tracking.model_outline),
        computed once."""
        if self._outline is None:
            self._outline = outline_points(self.bundle)
        return self._outline

    def _projected_boxes(self, R: np.ndarray, t: np.ndarray, K: np.ndarray) -> np.ndarray:
        """Boxes (N,4) pixels (x0, y0, x1, y1) of the model's outline points projected at
        poses R (N,3,3), t (N,3) metres (depths clamped to z_min)."""
        uv = project_outline(self.outline, R, t, K, self.z_min)  # (N,M,2)
        return np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)

    def outline_box(self, R: np.ndarray, t: np.ndarray, K: np.ndarray) -> Box:
        """The box (x, y, w, h) pixels of the model's outline projected at R (3,3), t (3,)
        metres with intrinsics K (3,3) (chpf.tracking.candidates.OutlineBox)."""
        x0, y0, x1, y1 = self._projected_boxes(R[None], t[None], K)[0]
        return (float(x0), float(y0), float(x1 - x0), float(y1 - y0))

    def _box_evidence(
        self, frame: Frame, R: np.ndarray, t: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """C_box, C_edge and the whole-box factor (N,) of poses R (N,3,3), t (N,3) (module
        docstring, item 6): C_box against the box that measures the object's size (the
        detection, else a fitted search region's: ``Frame.scale_box``), C_edge against the
        detection; each None when off or without its box."""
        box, sized = valid_box(frame.box), valid_box(frame.scale_box())
        c_box = c_edge = whole = None
        edges = box is not None and (self.c_edge is not None or self.c_near is not None)
        if sized is None or (self.c_box is None and not edges):
            return None, None, None
        proj = self._projected_boxes(R, t, np.asarray(frame.K))
        sides = np.maximum(proj[:, 2:] - proj[:, :2], 1e-6)  # (N,2) projected width, height
        side = sides.max(axis=1)
        if self.c_box is not None:
            # box / projected side ratios (N,k): width and height (k = 2) or the larger sides
            if self.c_box_sides == "each":
                rho = np.asarray(sized[2:4], dtype=np.float64) / sides
            else:
                rho = (max(sized[2], sized[3]) / side)[:, None]
            far = box_counter_evidence(rho, self.c_box, self.c_box_shape)
            c_box = 1.0 - np.prod(1.0 - far, axis=1)
            if self.box_whole is not None:
                near = box_counter_evidence(1.0 / rho, self.c_box, self.c_box_shape)
                whole = np.prod(1.0 - self.box_whole * near, axis=1)
        if box is not None and edges:
            edges_out = inner_margins(proj, corners(box))
            out = edges_out.max(axis=1) / side  # the box's edge farthest outside; < 0: inside
            c_edge = np.zeros(t.shape[0])
            if self.c_edge is not None:
                c_edge = edge_counter_evidence(out, self.c_edge)
            if self.c_near is not None:
                c_edge = either(c_edge, edge_counter_evidence(-out, self.c_near))
        return c_box, c_edge, whole

    # ------------------------------------------------------------------ Rao-Blackwellised
    def codebook_scores(self, frame: Frame, t: np.ndarray) -> CodebookScores:
        """Cosine similarities (N,K) of the crops at t (N,3) with the whole AE codebook."""
        ms: dict[str, float] = {}
        t = np.asarray(t, dtype=np.float64)
        crops, emb = self._crops_and_embed(frame, t, ms)
        t0 = time.perf_counter()
        cos = self._all_cosines(emb, t)
        behind = t[:, 2] < self.z_min
        ms["lookup"] = ms_since(t0)

        def misaligned(idx: np.ndarray) -> np.ndarray:
            """Learned C (N,) of entries idx (N,) for these crops (1 behind the camera)."""
            idx = np.asarray(idx)
            ch_emb = emb if self.bundle.shares_encoder else self.bundle.ch_embed(crops)
            C = self.bundle.p_misaligned(ch_emb, idx).astype(np.float64)
            C_box = self._box_evidence(frame, self._entry_poses(idx, t), t)[0]
            return np.where(behind, 1.0, either(C, C_box))

        def edge(idx: np.ndarray) -> np.ndarray | None:
            """C_edge (N,) of entries idx (N,) at these translations, None when off."""
            return self._box_evidence(frame, self._entry_poses(idx, t), t)[1]

        ref = self.frame_reference(frame)
        return CodebookScores(cos=cos, stage_ms=ms, misaligned=misaligned, reference=ref, edge=edge)

    def _entry_poses(self, idx: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Egocentric orientations (N,3,3) of codebook entries idx (N,) seen at t (N,3)."""
        return allocentric_to_egocentric(self.grid.rotations[np.asarray(idx)], t)

    def depth_weight(self, frame: Frame, idx: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """L_depth (N,) of codebook entries idx (N,) at t (N,3), or None without depth."""
        if not self.use_depth or frame.depth is None:
            return None
        return self._depth(frame, np.asarray(idx), np.asarray(t, dtype=np.float64)).L

    # ------------------------------------------------------------------ box-centre look-up
    def box_centre_cosines(self, frame: Frame) -> tuple[np.ndarray, np.ndarray] | None:
        """Cosines (K,) of the crop at the detection box's centre with the whole codebook and
        that crop's translation (3,) metres (depth guessed from the box size and the codebook's
        median object extent); the box is ``frame.cue_box()``; None without one."""
        t0 = self._cue_translation(frame)
        if t0 is None:
            return None
        _, emb = self._cue_embedding(frame, t0)
        return self._all_cosines(emb, t0[None])[0], t0

    def frame_reference(self, frame: Frame) -> Reference | None:
        """(L_ref, C_ref) of the frame (module docstring, item 8); None when ``reference`` is
        "none" or the frame has no box it names."""
        if self.reference == "none" or (
            self.reference == "detection" and valid_box(frame.box) is None
        ):
            return None
        found = self.box_centre_cosines(frame)
        if found is None:
            return None
        cos, t0 = found
        k = int(np.argmax(cos))
        L_ref = likelihood_from_cosine(cos[k : k + 1].astype(np.float64), self.l_from_cos)
        C_ref = float(self.box_centre_misalignment(frame, t0, np.array([k]))[0])
        box = valid_box(frame.box)  # a detection may be the visible part; a region's box is not
        if self.reference_anchors and box is not None:
            C_ref = min(C_ref, self._anchored_misalignment(frame, box))
        return float(L_ref[0]), C_ref

    def _anchored_misalignment(self, frame: Frame, box: Box) -> float:
        """The least learned C over the crops of the object's whole box, were ``box`` (x, y, w,
        h) pixels only its visible part (anchored_boxes of ``reference_anchors``); each crop's
        C is that of its best-cosine entry."""
        boxes = anchored_boxes(box, self.reference_anchors)
        if boxes.shape[0] == 0:
            return 1.0
        t = box_translations(boxes, frame.K, self.box_extent)
        crops = extract_crops(frame.rgb, self._affines(frame, t, self.spec), self.spec.size)
        emb = self.bundle.embed(crops)
        best = np.argmax(self._all_cosines(emb, t), axis=1)
        ch_emb = emb if self.bundle.shares_encoder else self.bundle.ch_embed(crops)
        return float(np.min(self.bundle.p_misaligned(ch_emb, best)))

    def box_centre_misalignment(self, frame: Frame, t0: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """The learned C (M,) of codebook entries idx (M,) for the crop at the cue translation
        t0 (3,) (box_centre_cosines'); the crop's classifier embedding is computed once."""
        crop, emb = self._cue_embedding(frame, t0)
        if self.bundle.shares_encoder:
            ch_emb = emb
        else:
            if self._cue_ch is None or self._cue_ch[0] is not crop:
                self._cue_ch = (crop, self.bundle.ch_embed(crop[None]))
            ch_emb = self._cue_ch[1]
        return self.bundle.p_misaligned(np.repeat(ch_emb, len(idx), axis=0), np.asarray(idx))

    def _cue_embedding(self, frame: Frame, t0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The crop (S,S,3) at the cue translation t0 (3,) and its AE embedding (1,E): the one
        encoded with the particles' crops when it is this crop, else one encoder pass (from
        then on the crop rides along in the particles' pass, _crops_and_embed)."""
        self._cue_in_batch = True
        crop = extract_crops(frame.rgb, self._affines(frame, t0[None], self.spec), self.spec.size)
        if self._cue is None or not np.array_equal(crop[0], self._cue[0]):
            self._cue = (crop[0], self.bundle.embed(crop))
        return self._cue

    def _all_cosines(self, emb: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Cosines (N,K) of embeddings emb (N,E) of the crops at t (N,3) with the whole AE
        codebook; -1 for a crop behind the camera (z below ``z_min``)."""
        cos = emb @ self._codebook_t
        cos[t[:, 2] < self.z_min] = -1.0
        return cos

    def _cue_translation(self, frame: Frame) -> np.ndarray | None:
        """Translation (3,) metres of the crop at ``frame.cue_box()``'s centre (depth guessed
        from the box size and the codebook's median object extent), None without a box."""
        box = valid_box(frame.cue_box())
        if box is None:
            return None
        return box_translations(np.array([box]), frame.K, self.box_extent)[0]

    # ------------------------------------------------------------------ MCL + E2E
    def single_frame_estimate(self, frame: Frame) -> tuple[np.ndarray, np.ndarray] | None:
        """Pose from the detection box (``frame.cue_box()``) alone: the codebook entry with the
        best cosine for the crop at the box centre (box_centre_cosines) gives R_allo, that
        entry's own extent vs the box gives z; then egocentric through the ray of the box
        centre. None without a box."""
        found = self.box_centre_cosines(frame)
        if found is None:
            return None
        cos, t0 = found
        k = int(np.argmax(cos))
        ext = self.extent_px[k] if self.extent_px[k] > 0 else self.median_extent_px
        t = t0 * (ext / self.median_extent_px)  # same ray; the box depth is linear in the extent
        R = allocentric_to_egocentric(self.grid.rotations[k], t)
        return R, t
