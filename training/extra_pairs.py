"""Extra classifier pairs per observed crop, against a codebook of candidate embeddings.

The embedding of every candidate view of a rotation grid is computed ahead of the step: once,
when the classifier's candidate branch is the autoencoder's frozen encoder
(``CHLitModule(freeze_candidate=True)``), or every ``candidate_refresh_steps`` steps when the
branch trains (shared weights with the observed branch). Each observed crop of a batch then
meets ``m`` more hypotheses besides its own pair, drawn exactly as ``chpf-gen-data pairs``
draws them (``data_gen.rotations.draw_candidates`` with the data's ``pairs`` config: positives
near the true orientation, hard negatives 20-45 deg away, flips, random ones), for the cost of
the head alone: the observed crop's encoder pass, the expensive part of a step, is shared by all
of them. Crops without the object get negatives only. With a frozen branch the batch's own
candidates are looked up too (no encoder pass for them).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from chpf.geometry import RotationGrid
from data_gen.rotations import draw_candidates, symmetry_set


class CandidateCodebook:
    """Candidate embeddings of a rotation grid and draws of extra hypotheses.

    Args:
        rotations: (K,3,3) allocentric orientations of the codebook views.
        embeddings: (K,E) normalised candidate-branch embeddings of those views.
        pairs_cfg: the ``pairs`` section of a chpf-gen-data config (how hypotheses are drawn).
        object_info: a data manifest's ``object_info`` (symmetries in metres).
    """

    def __init__(
        self,
        rotations: np.ndarray,
        embeddings: torch.Tensor,
        pairs_cfg: Mapping[str, Any],
        object_info: Mapping[str, Any] | None,
    ) -> None:
        self.grid = RotationGrid(np.asarray(rotations, np.float64))
        self.embeddings = embeddings
        self.pairs_cfg = dict(pairs_cfg)
        info = object_info or {}
        self.sym_rots, self.sym_axes = symmetry_set(
            info.get("symmetries_discrete", []), info.get("symmetries_continuous", [])
        )

    def embed(self, R_allo: np.ndarray) -> torch.Tensor:
        """Embeddings (N,E) of the views nearest to allocentric rotations R_allo (N,3,3): the
        exact ones for candidates drawn from the same grid (as chpf-gen-data's pairs are)."""
        return self.embeddings[torch.from_numpy(self.grid.nearest(R_allo))]

    def draw(
        self,
        R_obs: np.ndarray,
        shows_object: np.ndarray,
        m: int,
        rng: np.random.Generator,
        wrong_depth: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``m`` hypotheses for each of B observed crops.

        R_obs: (B,3,3) true allocentric orientations; shows_object: (B,) bool (False: an empty
        crop, all its hypotheses are misaligned); wrong_depth: (B,) bool, crops cut at a wrong
        depth (scale negatives, data_gen.compose.depth_off): their hypotheses are drawn as for
        any crop, near the true orientation as often, and all labelled misaligned. Returns
        codebook indices (B,m), labels (B,m) float (1 = misaligned) and symmetry-aware angles
        (B,m) in degrees.
        """
        b = R_obs.shape[0]
        R = np.repeat(np.asarray(R_obs, np.float64), m, axis=0)
        near = rng.random(b * m) < float(self.pairs_cfg["positive_share"])
        near &= np.repeat(shows_object, m)
        idx, ang = draw_candidates(
            self.grid, R, near, self.pairs_cfg, self.sym_rots, self.sym_axes, rng
        )
        shape = (b, m)
        aligned = near if wrong_depth is None else near & ~np.repeat(wrong_depth, m)
        label = (~aligned).astype(np.float32)
        return idx.reshape(shape), label.reshape(shape), np.degrees(ang).reshape(shape)
