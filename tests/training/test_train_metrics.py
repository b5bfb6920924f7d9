"""ROC AUC, bootstrapped L2 and symmetry-aware angles against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from training.evaluate import (
    by_visibility,
    far_negatives,
    hard_auc_by_scale_off,
    hard_auc_by_visibility,
)
from training.lit import bootstrapped_l2, classifier_metrics
from training.metrics import cosine_retrieval, roc_auc, roc_auc_interval, symmetry_aware_angle


def test_roc_auc_hand_case() -> None:
    # positives (label 1): 0.9, 0.4 ; negatives: 0.8, 0.3, 0.1
    # pairs pos > neg: 0.9 beats all 3; 0.4 beats 0.3, 0.1 -> 5 of 6
    assert roc_auc(np.array([0.9, 0.4, 0.8, 0.3, 0.1]), np.array([1, 1, 0, 0, 0])) == pytest.approx(
        5 / 6
    )


def test_roc_auc_ties_count_half_and_extremes() -> None:
    assert roc_auc(np.array([0.5, 0.5]), np.array([1, 0])) == pytest.approx(0.5)
    # pos {0.7, 0.5}, neg {0.5, 0.2}: 0.7>both (2), 0.5=0.5 (0.5), 0.5>0.2 (1) -> 3.5/4
    assert roc_auc(np.array([0.7, 0.5, 0.5, 0.2]), np.array([1, 1, 0, 0])) == pytest.approx(3.5 / 4)
    assert roc_auc(np.array([1.0, 2.0]), np.array([0, 1])) == 1.0
    assert roc_auc(np.array([1.0, 2.0]), np.array([1, 0])) == 0.0
    assert math.isnan(roc_auc(np.array([1.0, 2.0]), np.array([1, 1])))


def test_roc_auc_matches_pairwise_definition() -> None:
    rng = np.random.default_rng(0)
    s = np.round(rng.normal(size=300), 1)  # many ties
    y = rng.integers(0, 2, 300)
    p, n = s[y == 1], s[y == 0]
    ref = ((p[:, None] > n[None]).sum() + 0.5 * (p[:, None] == n[None]).sum()) / (p.size * n.size)
    assert roc_auc(s, y) == pytest.approx(ref, abs=1e-12)


def test_roc_auc_interval_holds_the_auc_and_narrows_with_more_pairs() -> None:
    """The stratified bootstrap's 95 % interval holds the AUC, is reproducible from its seed,
    narrows about as 1 / sqrt(n) with four times the pairs, covers the true AUC of the draw's
    distributions (0.76 for unit normals 1 apart) and is nan without negatives."""
    rng = np.random.default_rng(3)

    def draw(n: int) -> tuple[np.ndarray, np.ndarray]:
        y = np.r_[np.ones(n), np.zeros(n)]
        return np.r_[rng.normal(1.0, 1.0, n), rng.normal(0.0, 1.0, n)], y

    s, y = draw(250)
    lo, hi = roc_auc_interval(s, y, seed=1)
    assert lo < roc_auc(s, y) < hi and lo < 0.760 < hi
    assert roc_auc_interval(s, y, seed=1) == (lo, hi)
    s4, y4 = draw(1000)
    lo4, hi4 = roc_auc_interval(s4, y4, seed=1)
    assert 0.35 < (hi4 - lo4) / (hi - lo) < 0.7
    assert all(np.isnan(roc_auc_interval(s[:250], y[:250])))


def test_bootstrapped_l2_is_mean_of_worst_pixels() -> None:
    target = torch.zeros(1, 3, 2, 2)
    recon = torch.zeros(1, 3, 2, 2)
    # pixel errors (mean over channels of squared diff): 4, 1, 0, 0.25 (for the 4 pixels)
    recon[0, :, 0, 0] = 2.0
    recon[0, :, 0, 1] = 1.0
    recon[0, 0, 1, 1] = math.sqrt(0.75)
    # ratio 0.5 -> top 2 pixels (4, 1) -> 2.5 ; ratio 1 -> (4+1+0+0.25)/4
    assert bootstrapped_l2(recon, target, 0.5).item() == pytest.approx(2.5)
    assert bootstrapped_l2(recon, target, 0.25).item() == pytest.approx(4.0)
    assert bootstrapped_l2(recon, target, 1.0).item() == pytest.approx(5.25 / 4)
    # two images: each keeps its own worst pixels
    two = bootstrapped_l2(torch.cat([recon, target]), torch.cat([target, target]), 0.25)
    assert two.item() == pytest.approx(2.0)


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_symmetry_aware_angle() -> None:
    R_gt = np.eye(3)[None]
    R_est = _rz(math.radians(170))[None]
    assert np.degrees(symmetry_aware_angle(R_est, R_gt))[0] == pytest.approx(170)
    flip = np.eye(4)
    flip[:3, :3] = _rz(math.pi)
    assert np.degrees(symmetry_aware_angle(R_est, R_gt, [flip]))[0] == pytest.approx(10)
    # continuous symmetry about z: spin costs nothing, tilt costs its angle
    cont = [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]
    tilt = (_rx(math.radians(25)) @ _rz(1.3))[None]
    assert np.degrees(symmetry_aware_angle(tilt, R_gt, None, cont))[0] == pytest.approx(25)
    # continuous + discrete flip of the axis (a can): upside-down costs nothing
    upside = np.eye(4)
    upside[:3, :3] = _rx(math.pi)
    down = (_rx(math.radians(175)))[None]
    assert np.degrees(symmetry_aware_angle(down, R_gt, [upside], cont))[0] == pytest.approx(5)


def test_cosine_retrieval_and_classifier_metrics() -> None:
    cb = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    idx, cos = cosine_retrieval(np.array([[0.1, 2.0, 0.0], [0, 0, -1.0]]), cb)
    assert idx.tolist() == [1, 0]
    assert cos[0] == pytest.approx(2.0 / math.hypot(0.1, 2.0), rel=1e-6)
    logit = np.array([-2.0, -1.0, 1.0, 3.0, 0.5, -0.5])
    y = np.array([0, 0, 0, 1, 1, 1])
    angle = np.array([2.0, 3.0, 1.0, 120.0, 30.0, 40.0])
    visib = np.array([0.4, 0.9, 0.5, 1.0, 1.0, 1.0])
    m = classifier_metrics(logit, y, angle, visib)
    assert m["acc"] == pytest.approx(4 / 6)
    assert m["aligned_rate_pos"] == pytest.approx(2 / 3)
    assert m["aligned_rate_occluded"] == pytest.approx(0.5)  # visib 0.4 ok, 0.5 called mis
    # hard: negatives at 30 and 40 deg (logits 0.5, -0.5) vs positives (-2, -1, 1): 4/6
    assert m["auc_hard"] == pytest.approx(4 / 6)
    # empty crops (visib 0, negatives): out of the AUC, counted as rejected when p >= 0.5
    logit_e = np.append(logit, [-4.0, 2.0])
    m_e = classifier_metrics(logit_e, np.append(y, [1, 1]), np.append(angle, [90.0, 90.0]),
                             np.append(visib, [0.0, 0.0]))  # fmt: skip
    assert m_e["auc"] == pytest.approx(m["auc"]) and m_e["auc_hard"] == pytest.approx(4 / 6)
    assert m_e["empty_rejected"] == pytest.approx(0.5)
    assert math.isnan(m["empty_rejected"])


def test_empty_separation_pushes_empty_crops_away_from_views() -> None:
    import torch

    from training.lit import empty_separation

    views = torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    empty = torch.tensor([False, False, True])
    near = torch.cat([views, torch.tensor([[0.05, 0.0, 0.0]])])  # tiny norm, same direction
    far = torch.cat([views, torch.tensor([[0.0, 0.0, -3.0]])])
    # cosine 1 with view 0 and 0 with view 1: relu(1 - 0.3) and relu(0 - 0.3), averaged
    assert float(empty_separation(near, empty, 0.3)) == pytest.approx(0.35)
    assert float(empty_separation(far, empty, 0.3)) == 0.0
    assert float(empty_separation(near, torch.zeros(3, dtype=torch.bool), 0.3)) == 0.0
    # extra views (clean targets) count like the batch's views: here a third, orthogonal one
    extra = torch.tensor([[0.0, 0.0, 1.0]])
    assert float(empty_separation(near, empty, 0.3, extra)) == pytest.approx(0.7 / 3)
    tilted = torch.cat([views, torch.tensor([[0.05, 0.01, 0.0]])])
    z = tilted.clone().requires_grad_(True)
    sep = empty_separation(z, empty, 0.3)
    assert float(sep) == pytest.approx((0.05 / math.hypot(0.05, 0.01) - 0.3) / 2, rel=1e-5)
    sep.backward()
    assert float(z.grad[2].norm()) > 0  # the gradient moves the empty crop's embedding


def test_far_pairs_respect_angle_keep_and_symmetry() -> None:
    from chpf.geometry import axis_angle_to_matrix
    from training.lit import far_pairs

    z_axis = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, 0.0, np.pi]])
    R = axis_angle_to_matrix(z_axis)  # 0, ~29 and 180 degrees about z
    keep = np.array([True, True, True])
    far = far_pairs(R, keep, 90.0, [], [])
    assert far.tolist() == [[False, False, True], [False, False, True], [True, True, False]]
    # the third crop shows no object: none of its pairs count
    assert not far_pairs(R, np.array([True, True, False]), 90.0, [], [])[:, 2].any()
    # a 180-degree symmetry about z makes the half turn the same view
    half_turn = np.diag([-1.0, -1.0, 1.0, 1.0])
    assert not far_pairs(R, keep, 90.0, [half_turn], []).any()


def test_view_separation_pushes_the_hardest_far_view_away() -> None:
    import torch

    from training.lit import view_separation

    views = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.6, 0.8]])
    z = torch.tensor([[1.0, 0.0], [0.0, 3.0]], requires_grad=True)
    far = torch.tensor([[False, True, True], [True, False, False]])
    # crop 0: far views 1 (cos 0) and 2 (cos 0.6) -> hardest 0.6; crop 1: view 0, cos 0
    sep = view_separation(z, views, far, 0.5)
    assert float(sep.detach()) == pytest.approx((0.6 - 0.5) / 2)
    sep.backward()
    assert float(z.grad[0].norm()) > 0 and float(z.grad[1].norm()) == 0.0
    none = torch.zeros(2, 3, dtype=torch.bool)
    assert float(view_separation(z, views, none, 0.5)) == 0.0
    assert float(view_separation(z, views, far, 0.7)) == 0.0


def test_retrieval_by_visibility_bands() -> None:
    err = np.array([5.0, 40.0, 170.0, 10.0, 20.0, 160.0, 1.0])
    visib = np.array([1.0, 0.95, 0.5, 0.3, 0.59, 0.2, 0.0])  # 0.0: empty, in no band
    rows = {tuple(r["visib"]): r for r in by_visibility(err, visib)}
    assert rows[(0.9, 1.0)]["n"] == 2 and rows[(0.9, 1.0)]["median_deg"] == 22.5
    assert rows[(0.6, 0.9)]["n"] == 0 and np.isnan(rows[(0.6, 0.9)]["median_deg"])
    occl = rows[(0.3, 0.6)]
    assert occl["n"] == 3 and occl["median_deg"] == 20.0
    assert occl["pct_below"] == pytest.approx(200 / 3) and occl["pct_above150"] == pytest.approx(
        100 / 3
    )
    assert rows[(0.0, 0.3)]["n"] == 1 and rows[(0.0, 0.3)]["pct_above150"] == 100.0


def test_view_matching_is_the_codebook_lookup_as_a_loss() -> None:
    """InfoNCE over the batch's views: low when every crop is nearest its own view, high when
    it points at another's; excluded alternatives (near orientations) do not count."""
    import torch

    from training.lit import view_matching

    views = torch.eye(3)
    all_neg = ~torch.eye(3, dtype=torch.bool)
    right = view_matching(views.clone(), views, all_neg, 0.1)
    swapped = view_matching(views[[1, 0, 2]], views, all_neg, 0.1)
    # exact: -log(e^10 / (e^10 + 2 e^0)) per row
    assert float(right) == pytest.approx(-math.log(math.exp(10) / (math.exp(10) + 2)), rel=1e-3)
    assert float(swapped) > 6.0  # rows 0 and 1 match the wrong view
    # with crops 0 and 1 of nearly the same orientation, neither is the other's negative
    near = all_neg.clone()
    near[0, 1] = near[1, 0] = False
    relaxed = view_matching(views[[1, 0, 2]], views, near, 0.1)
    assert float(relaxed) < float(swapped)
    # no negatives at all: nothing to learn
    assert float(view_matching(views, views, torch.zeros(3, 3, dtype=torch.bool), 0.1)) == 0.0
    z = views[[1, 0, 2]].clone().requires_grad_(True)
    view_matching(z, views, all_neg, 0.1).backward()
    assert float(z.grad[0, 0]) < 0  # moves crop 0 toward its own view 0


def test_hard_auc_by_visibility_bands() -> None:
    """Each band ranks its own positives against its own hard negatives."""
    visib = np.array([1.0, 1.0, 0.95, 0.7, 0.7, 0.7, 0.4, 0.4])
    pos = np.array([1, 1, 0, 1, 0, 0, 1, 0], bool)
    hard = ~pos
    logit = np.array([0.1, 0.5, 0.9, 0.2, 0.1, 0.3, 0.5, 0.4])
    rows = {tuple(r["visib"]): r for r in hard_auc_by_visibility(logit, pos, hard, visib)}
    assert set(rows) == {(0.9, 1.0), (0.6, 0.9), (0.3, 0.6)}
    assert rows[(0.9, 1.0)]["auc"] == 1.0 and rows[(0.9, 1.0)]["n_pos"] == 2
    assert rows[(0.6, 0.9)]["auc"] == 0.5 and rows[(0.6, 0.9)]["n_hard"] == 2
    assert rows[(0.3, 0.6)]["auc"] == 0.0


def test_hard_auc_by_scale_off_bands() -> None:
    """A pair counts in the band of its crop's |ln depth_ratio|, nearer and farther alike; the
    last band is open."""
    ratio = np.array([1.0, 1.01, 1.03, 1 / 1.03, 1.07, 1 / 1.07, 1.3, 2.0])
    pos = np.array([1, 0, 1, 0, 0, 1, 1, 0], bool)
    hard = ~pos
    logit = np.array([0.1, 0.5, 0.9, 0.2, 0.9, 0.2, 0.5, 0.4])
    rows = {tuple(r["scale_off"]): r for r in hard_auc_by_scale_off(logit, pos, hard, ratio)}
    assert list(rows) == [(0.0, 0.02), (0.02, 0.05), (0.05, 0.08), (0.08, None)]
    assert rows[(0.0, 0.02)]["auc"] == 1.0 and rows[(0.0, 0.02)]["n_pos"] == 1
    assert rows[(0.02, 0.05)]["auc"] == 0.0 and rows[(0.02, 0.05)]["n_hard"] == 1
    assert rows[(0.05, 0.08)]["auc"] == 1.0
    assert rows[(0.08, None)]["auc"] == 0.0 and rows[(0.08, None)]["n_hard"] == 1


def test_far_negatives_are_the_random_ones_that_show_the_object() -> None:
    """Negatives 45-150 deg off with the object in the crop: not positives, hard negatives,
    flips or empty crops."""
    y = np.array([0, 1, 1, 1, 1, 1, 1, 1])
    angle = np.array([60.0, 30.0, 45.0, 100.0, 150.0, 175.0, 90.0, 151.0])
    visib = np.array([1.0, 1.0, 0.5, 0.2, 1.0, 1.0, 0.0, 1.0])
    assert far_negatives(y, angle, visib).tolist() == [0, 0, 1, 1, 1, 0, 0, 0]


def test_embed_of_no_crops_is_an_empty_matrix() -> None:
    """An empty crop array gives (0, E) embeddings, not an error."""
    from training.lit import AELitModule
    from training.model_config import EncoderConfig

    m = AELitModule(EncoderConfig(channels=(8, 16), size=16, embedding_dim=16))
    assert m.embed(np.zeros((0, 16, 16, 3), np.uint8)).shape == (0, 16)
