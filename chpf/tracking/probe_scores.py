"""How much the object seems to be in each probe box of a widened search window.

A probe box (x, y, w, h) pixels stands for the object at the box's centre, at the depth where
the codebook's median object extent spans the box (``Probed.box_extent``). Its crop (the
likelihood's scale-normalised crop at that translation) is compared with the whole codebook
(one autoencoder pass) and scored by ``PROBE_SCORES``:

- ``classifier``: 1 - C, C the counter-hypothetical classifier's p(misaligned) of the crop
  against its best-cosine entry (one more encoder pass when the bundle's classifier has its
  own encoder);
- ``cosine``: that best cosine.

Both peak on the object only within about 0.1 of its side and 15 % of its size; a background
patch or a distractor can score about as well as the object's own box (docs/own-recording.md:
the classifier re-acquired a little more often after a forced jump).

chpf.tracking.search_region moves phi_cand's box to the best probe.
"""

from __future__ import annotations

import typing
from dataclasses import replace
from typing import Literal, Protocol

import numpy as np

from chpf.tracking.candidates import box_translations
from chpf.tracking.types import CodebookScores, Frame

ProbeScoreName = Literal["classifier", "cosine"]
PROBE_SCORES: tuple[str, ...] = typing.get_args(ProbeScoreName)
"""How probe boxes are scored (module docstring)."""


class Probed(Protocol):
    """What probe scoring needs from a likelihood (BundleLikelihood has it)."""

    @property
    def box_extent(self) -> float: ...

    def codebook_scores(self, frame: Frame, t: np.ndarray) -> CodebookScores: ...


def probe_scores(
    likelihood: Probed, frame: Frame, boxes: np.ndarray, kind: ProbeScoreName
) -> np.ndarray:
    """Scores (M,) in [-1, 1] of probe boxes (M,4) (x, y, w, h) pixels in ``frame`` by ``kind``
    (module docstring); higher: the object more likely there. The frame's box and region are
    ignored (the classifier's box-scale term reads a detection box)."""
    frame = replace(frame, box=None, region=None)
    t = box_translations(boxes, frame.K, likelihood.box_extent)
    scores = likelihood.codebook_scores(frame, t)
    if kind == "cosine":
        return scores.cos.max(axis=1)
    if scores.misaligned is None:
        raise ValueError("probe score 'classifier' needs a likelihood with a classifier")
    return 1.0 - scores.misaligned(np.argmax(scores.cos, axis=1))
