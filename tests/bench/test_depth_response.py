"""bench.depth_response: L and C at the true pose moved along its ray."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.depth_response import responses, table
from bench.likelihoods import band_index
from chpf.tracking.types import Scores


class RayLikelihood:
    """L falls and C rises with the distance from the true depth z_true (a likelihood that
    sees depth); records the translations it was asked about."""

    def __init__(self, z_true: float) -> None:
        self.z_true = z_true
        self.asked: list[np.ndarray] = []

    def score(self, frame, R, t):
        self.asked.append(np.array(t))
        off = np.abs(np.log(t[:, 2] / self.z_true))
        return Scores(L=1.0 - off, w=1.0 - off, C=off, stage_ms={})


def scene(visib: list[float], z: float = 0.8):
    gt = SimpleNamespace(obj_id=3, R=np.eye(3), t=np.array([0.05, -0.02, z]))
    other = SimpleNamespace(obj_id=7, R=np.eye(3), t=np.array([0.0, 0.0, 1.0]))
    ids = list(range(len(visib)))
    info = [SimpleNamespace(visib_fract=v) for v in visib]
    return SimpleNamespace(
        image_ids=lambda: ids,
        gt={i: [other, gt] for i in ids},
        gt_info={i: [SimpleNamespace(visib_fract=1.0), info[i]] for i in ids},
        rgb=lambda i: np.zeros((8, 8, 3), np.uint8),
        camera=lambda i: SimpleNamespace(K=np.eye(3)),
    )


def test_the_true_pose_is_scored_along_its_own_ray_per_visibility_band():
    factors = np.array([0.9, 1.0, 1.2])
    lik = RayLikelihood(0.8)
    got = list(responses(lik, scene([1.0, 0.5, 0.2, 0.95]), 3, factors, every=1))
    assert [b for b, _, _ in got] == [0, 2, 3, 0]
    t = lik.asked[0]
    np.testing.assert_allclose(t / t[1], factors[:, None] * np.ones(3))  # along the ray
    np.testing.assert_allclose(t[1], [0.05, -0.02, 0.8])  # the target's, not the other object's
    for _, L, C in got:
        assert np.argmax(L) == 1 and np.argmin(C) == 1
    out = table({b: [(L, C)] for b, L, C in got}, factors)
    assert "| 0.9-1.0 | 1 | best L | 0 | 1 | 0 |" in out
    assert len(list(responses(lik, scene([1.0] * 6), 3, factors, every=4))) == 2


def test_bands_cover_every_visible_fraction():
    assert [band_index(v) for v in (1.0, 0.9, 0.89, 0.6, 0.3, 0.0)] == [0, 0, 1, 1, 2, 3]
