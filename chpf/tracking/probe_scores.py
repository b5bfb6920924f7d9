"""How much the object seems to be in each probe box of a widened search window.

A probe box (x, y, w, h) pixels stands for the object at the box's centre, at the depth where
the codebook's median object extent spans the box (``Probed.box_extent``). Its crop (the
likelihood's scale-normalised crop at that translation) is compared with the whole codebook
(one autoencoder pass) and scored by ``PROBE_SCORES``:

- ``classifier``: 1 - C, C the counter-hypothetical classifier's p(misaligned) of the crop
  against its best-cosine entry (one more encoder pass when the bundle's classifier has its
  own encoder);
- ``cosine``: that best cosine;
- ``odds``: log10(L^3 / C) with L = max(that cosine, 0): the log-odds of "aligned" that
  CH-PF's rule gives one hypothesis (alpha_i = C / (C + L^3), its default ``l_power`` 3), so
  that a probe needs both a good cosine and a low C; in decades, which is how C varies (10^-3
  on the object, 10^-1 a tenth of a side away).

All peak on the object only within about 0.1 of its side and 15 % of its size; a background
patch or a distractor can score about as well as the object's own box, which is why
chpf.tracking.search_region lets a probe take over phi_cand's box only when it beats what was
seen at its place while the object was tracked elsewhere (docs/own-recording.md).
"""

from __future__ import annotations

import typing
from dataclasses import replace
from typing import Literal, Protocol

import numpy as np

from chpf.geometry import RotationGrid, allocentric_to_egocentric
from chpf.tracking.candidates import box_translations
from chpf.tracking.types import CodebookScores, Frame

ProbeScoreName = Literal["odds", "classifier", "cosine"]
PROBE_SCORES: tuple[str, ...] = typing.get_args(ProbeScoreName)
"""How probe boxes are scored (module docstring)."""


class Probed(Protocol):
    """What probe scoring needs from a likelihood (BundleLikelihood has it)."""

    @property
    def box_extent(self) -> float: ...

    @property
    def grid(self) -> RotationGrid: ...

    def codebook_scores(self, frame: Frame, t: np.ndarray) -> CodebookScores: ...


def probe_codebook(
    likelihood: Probed, frame: Frame, boxes: np.ndarray
) -> tuple[CodebookScores, np.ndarray]:
    """The codebook scores of probe boxes (M,4) (x, y, w, h) pixels in ``frame`` and the boxes'
    translations t (M,3) metres (the object at the box's centre, its extent spanning the box).
    The frame's box and region are ignored (the classifier's box-scale term reads a detection
    box)."""
    t = box_translations(boxes, frame.K, likelihood.box_extent)
    return likelihood.codebook_scores(replace(frame, box=None, region=None), t), t


def probe_evidence(
    likelihood: Probed, frame: Frame, boxes: np.ndarray, with_c: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """The evidence of probe boxes (M,4) (x, y, w, h) pixels in ``frame``: the best codebook
    cosine (M,) of each crop and the classifier's C (M,) of the crop against that best entry
    (None when ``with_c`` is false or the likelihood has no classifier; ``probe_codebook``)."""
    scores, _ = probe_codebook(likelihood, frame, boxes)
    cos = scores.cos.max(axis=1)
    if not with_c or scores.misaligned is None:
        return cos, None
    return cos, np.asarray(scores.misaligned(np.argmax(scores.cos, axis=1)), dtype=np.float64)


def probe_poses(
    likelihood: Probed, frame: Frame, boxes: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The object's poses in probe boxes (M,4) (x, y, w, h) pixels: the ``k`` codebook
    orientations R (M,k,3,3) whose cosines with each crop are highest, seen at the box's
    translation t (M,3) metres."""
    scores, t = probe_codebook(likelihood, frame, boxes)
    top = np.argsort(-scores.cos, axis=1)[:, :k]
    R = allocentric_to_egocentric(
        likelihood.grid.rotations[top.ravel()], np.repeat(t, top.shape[1], axis=0)
    )
    return R.reshape(len(boxes), -1, 3, 3), t


def probe_scores(
    likelihood: Probed, frame: Frame, boxes: np.ndarray, kind: ProbeScoreName
) -> np.ndarray:
    """Scores (M,) of probe boxes (M,4) (x, y, w, h) pixels in ``frame`` by ``kind`` (module
    docstring; in [-1, 1], ``odds`` in decades); higher: the object more likely there."""
    cos, C = probe_evidence(likelihood, frame, boxes, with_c=kind != "cosine")
    if kind == "cosine":
        return cos
    if C is None:
        raise ValueError(f"probe score {kind!r} needs a likelihood with a classifier")
    if kind == "odds":
        return odds(cos, C)
    return 1.0 - C


ODDS_FLOOR = 1e-6
"""``odds`` clips L and C to this from below (log10 of 0)."""


def odds(cos: np.ndarray, C: np.ndarray, l_power: float = 3.0) -> np.ndarray:
    """log10(L^l_power / C) (M,) of best cosines and C (M,) (module docstring)."""
    L = np.maximum(np.asarray(cos, dtype=np.float64), ODDS_FLOOR)
    return l_power * np.log10(L) - np.log10(np.maximum(np.asarray(C, dtype=np.float64), ODDS_FLOOR))
