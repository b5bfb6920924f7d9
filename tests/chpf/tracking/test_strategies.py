"""Each reinvigoration strategy's alpha against its formula on fixed inputs."""

from __future__ import annotations

import numpy as np
import pytest

from chpf.errors import ConfigError
from chpf.tracking import CHPF, E2E, SRL, Annealing, AugMCL, FixedRate, NoReinvigoration, Scores
from chpf.tracking.oracle import OracleLikelihood
from chpf.tracking.strategies import (
    CHPF_REFERENCES,
    CHPF_SUMS,
    AnnealingConfig,
    AugMCLConfig,
    CHPFConfig,
    E2EConfig,
    FixedConfig,
    SRLConfig,
    relative_scores,
)
from chpf.tracking.types import Frame

L_FIXED = np.array([0.9, 0.5, 0.1, 0.0, 0.3])
C_FIXED = np.array([0.1, 0.4, 0.9, 1.0, 0.6])


def scores(L=L_FIXED, C=C_FIXED) -> Scores:
    L = np.asarray(L, dtype=float)
    return Scores(L=L, w=L.copy(), C=None if C is None else np.asarray(C, float))


W_FIXED = np.array([0.4, 0.3, 0.1, 0.0, 0.2])  # normalised importance weights
FRESH = np.array([False, False, True, True, False])  # just drawn from phi_cand


def chpf(sums: str, l_power: float = 1.0, edge_discounts_l: bool = False) -> CHPF:
    return CHPF(CHPFConfig(sums=sums, l_power=l_power, edge_discounts_l=edge_discounts_l))


def test_chpf_paper_alpha_is_sum_c_over_sum_c_plus_sum_l():
    paper = chpf("paper")
    assert paper.alpha(scores()) == pytest.approx(3.0 / (3.0 + 1.8))
    assert paper.alpha(scores(L=[1, 1], C=[0, 0])) == 0.0
    assert paper.alpha(scores(L=[0, 0], C=[1, 0])) == 1.0
    assert paper.alpha(scores(L=[0, 0], C=[0, 0])) == 1.0  # no evidence at all
    # NaN entries count as 0
    assert paper.alpha(scores(L=[0.5, np.nan], C=[0.5, np.nan])) == pytest.approx(0.5)


def test_chpf_paper_sums_ignore_weights_and_freshness():
    assert CHPF_SUMS == ("paper", "belief", "weighted")
    assert chpf("paper").alpha(scores(), W_FIXED, FRESH) == pytest.approx(3.0 / (3.0 + 1.8))


def test_chpf_default_is_weighted_sums_with_l_cubed_and_the_box_scale_c_of_the_larger_side():
    config = CHPFConfig()
    assert (
        config.sums,
        config.l_power,
        config.c_box,
        config.c_box_shape,
        config.c_box_sides,
        config.box_whole,
    ) == ("weighted", 3.0, 0.1, "gauss", "larger", None)
    e_c = W_FIXED @ C_FIXED
    e_l3 = W_FIXED @ L_FIXED**3
    assert CHPF().alpha(scores(), W_FIXED, FRESH) == pytest.approx(e_c / (e_c + e_l3))


def test_chpf_weighs_each_particle_by_the_evidence_against_it():
    assert (CHPFConfig().c_weight, CHPFConfig().keep_belief) == (1.0, True)
    w = L_FIXED.copy()
    paper = CHPF(CHPFConfig(c_weight=0.0, keep_belief=False))
    np.testing.assert_array_equal(paper.importance(scores()), w)
    weighed = CHPF(CHPFConfig(c_weight=1.0))
    np.testing.assert_allclose(weighed.importance(scores()), w * (1.0 - C_FIXED))
    squared = CHPF(CHPFConfig(c_weight=2.0)).importance(scores())
    np.testing.assert_allclose(squared, w * (1.0 - C_FIXED) ** 2)
    # C = 1 (certainly wrong, e.g. behind the camera) leaves a tiny weight, NaN C counts as 0
    out = weighed.importance(scores(L=[0.5, 0.5], C=[1.0, np.nan]))
    assert 0.0 < out[0] < 1e-5 and out[1] == pytest.approx(0.5)
    # the other strategies weigh by the likelihood alone
    np.testing.assert_array_equal(SRL().importance(scores()), w)
    assert CHPF().keeps_belief and not paper.keeps_belief
    assert not SRL().keeps_belief


def test_chpf_doubt_tempers_the_next_frames_weights():
    """temper t: the weights of the frame after an alpha a are w^(1 - t a) (1 - C)^k; the first
    frame of a sequence (and after reset) has no doubt yet."""
    rule = CHPF(CHPFConfig(temper=1.0, c_weight=1.0))
    w = L_FIXED.copy()
    np.testing.assert_allclose(rule.importance(scores()), w * (1.0 - C_FIXED))
    a = rule.alpha(scores(), W_FIXED, FRESH)
    assert 0.2 < a < 0.9
    np.testing.assert_allclose(rule.importance(scores()), w ** (1.0 - a) * (1.0 - C_FIXED))
    half = CHPF(CHPFConfig(temper=0.5, c_weight=0.0))
    half.alpha(scores(), W_FIXED, FRESH)
    np.testing.assert_allclose(half.importance(scores()), w ** (1.0 - 0.5 * a))
    rule.reset()
    np.testing.assert_allclose(rule.importance(scores()), w * (1.0 - C_FIXED))
    off = CHPF(CHPFConfig(temper=0.0, c_weight=0.0))
    off.alpha(scores(), W_FIXED, FRESH)
    np.testing.assert_array_equal(off.importance(scores()), w)


@pytest.mark.parametrize("sums", CHPF_SUMS)
def test_chpf_l_power_raises_each_l_in_the_sums(sums):
    # paper: sum C = 3.0, sum L^2 = 0.81 + 0.25 + 0.01 + 0 + 0.09 = 1.16
    # belief (particles 0, 1, 4): sum C = 1.1, sum L^2 = 0.81 + 0.25 + 0.09 = 1.15
    # weighted: E_w[C] = 0.37, E_w[L^2] = 0.4 * 0.81 + 0.3 * 0.25 + 0.1 * 0.01 + 0.2 * 0.09
    expected = {
        "paper": 3.0 / (3.0 + 1.16),
        "belief": 1.1 / (1.1 + 1.15),
        "weighted": 0.37 / (0.37 + 0.324 + 0.075 + 0.001 + 0.018),
    }
    assert chpf(sums, 2.0).alpha(scores(), W_FIXED, FRESH) == pytest.approx(expected[sums])
    # a wrong pose (L 0.5) loses more to the power than a right one (L 0.8): with equal C the
    # set of wrong poses gets the higher alpha, more so at a higher power
    right, wrong = scores(L=[0.8], C=[0.3]), scores(L=[0.5], C=[0.3])
    gap = [chpf(sums, p).alpha(wrong) - chpf(sums, p).alpha(right) for p in (1.0, 4.0)]
    assert 0.0 < gap[0] < gap[1]


def test_chpf_belief_sums_run_over_the_particles_resampled_from_the_belief():
    # particles 0, 1, 4: sum C = 0.1 + 0.4 + 0.6, sum L = 0.9 + 0.5 + 0.3
    assert chpf("belief").alpha(scores(), W_FIXED, FRESH) == pytest.approx(1.1 / (1.1 + 1.7))
    # a set that is all fresh (first frame, full reset) sums over every particle
    all_fresh = np.ones(5, dtype=bool)
    assert chpf("belief").alpha(scores(), W_FIXED, all_fresh) == pytest.approx(3.0 / 4.8)
    assert chpf("belief").alpha(scores(), W_FIXED, None) == pytest.approx(3.0 / 4.8)


def test_chpf_weighted_sums_are_expectations_under_the_importance_weights():
    e_c = 0.4 * 0.1 + 0.3 * 0.4 + 0.1 * 0.9 + 0.0 * 1.0 + 0.2 * 0.6
    e_l = 0.4 * 0.9 + 0.3 * 0.5 + 0.1 * 0.1 + 0.0 * 0.0 + 0.2 * 0.3
    assert chpf("weighted").alpha(scores(), W_FIXED, FRESH) == pytest.approx(e_c / (e_c + e_l))
    # collapsed weights (None): every particle counts alike
    assert chpf("weighted").alpha(scores(), None, FRESH) == pytest.approx(3.0 / 4.8)


def test_chpf_alpha_measures_the_set_against_the_frames_reference():
    """reference "box" (the default; "detection" alike, the likelihood picks the box): alpha is
    the ratio of L' = min(L / L_ref, 1) and C' = clip((C - C_ref) / (1 - C_ref), 0, 1); temper
    reads the ratio of L and C as they are; a frame without a reference and reference "none"
    use those values."""
    assert CHPFConfig().reference == "box"
    assert CHPF_REFERENCES == ("none", "detection", "box")
    L_rel, C_rel = relative_scores(L_FIXED, C_FIXED, (0.5, 0.2))
    np.testing.assert_allclose(L_rel, [1.0, 1.0, 0.2, 0.0, 0.6])
    np.testing.assert_allclose(C_rel, [0.0, 0.25, 0.875, 1.0, 0.5])
    framed = Scores(L=L_FIXED, w=L_FIXED.copy(), C=C_FIXED, reference=(0.5, 0.2))
    rule = chpf("paper")
    assert rule.alpha(framed) == pytest.approx(2.625 / (2.625 + 2.8))
    doubt = 3.0 / 4.8  # the values as they are
    assert rule.last_doubt == pytest.approx(doubt)
    np.testing.assert_allclose(rule.importance(framed), L_FIXED ** (1.0 - doubt) * (1.0 - C_FIXED))
    assert rule.alpha(scores()) == pytest.approx(doubt)  # a frame without a detection
    as_they_are = CHPF(CHPFConfig(sums="paper", l_power=1.0, reference="none"))
    assert as_they_are.alpha(framed) == pytest.approx(doubt)
    # occluded: a set that explains the frame as well as its own best hypothesis has no doubt,
    # however low its L and high its C; lost: the box's crop is explained, the set is not
    weights = np.full(3, 1.0 / 3.0)
    occluded = Scores(L=np.full(3, 0.3), w=np.ones(3), C=np.full(3, 0.6), reference=(0.3, 0.6))
    lost = Scores(L=np.full(3, 0.3), w=np.ones(3), C=np.full(3, 0.6), reference=(0.8, 0.05))
    assert CHPF().alpha(occluded, weights) == 0.0
    assert CHPF().alpha(lost, weights) > 0.9
    assert CHPF(CHPFConfig(reference="none")).alpha(occluded, weights) > 0.9


def test_chpf_alpha_counts_the_box_edge_evidence_and_the_weights_do_not():
    """C_edge joins C in alpha's sums (1 - (1 - C)(1 - C_edge)), in the reference's C' too, and
    stays out of the importance weights; the default margin is 0.2."""
    assert CHPFConfig().c_edge == 0.2
    edge = np.array([0.0, 0.5, 0.0, 0.0, 1.0])
    edged = Scores(L=L_FIXED, w=L_FIXED.copy(), C=C_FIXED, C_edge=edge)
    rule = chpf("paper")
    sum_c = C_FIXED.sum() + 0.6 * 0.5 + 0.4 * 1.0
    assert rule.alpha(edged) == pytest.approx(sum_c / (sum_c + L_FIXED.sum()))
    np.testing.assert_array_equal(CHPF().importance(edged), CHPF().importance(scores()))
    framed = Scores(L=L_FIXED, w=L_FIXED.copy(), C=C_FIXED, reference=(0.5, 0.2))
    framed_edged = Scores(L=L_FIXED, w=L_FIXED.copy(), C=C_FIXED, reference=(0.5, 0.2), C_edge=edge)
    assert chpf("paper").alpha(framed_edged) > chpf("paper").alpha(framed)


def test_edge_discounts_l_takes_the_support_the_box_contradicts_out_of_alpha():
    """edge_discounts_l (the default): alpha's L side sums L (1 - C_edge), after the
    reference; the doubt that ``temper`` reads keeps L as it is."""
    assert CHPFConfig().edge_discounts_l and CHPFConfig().c_near == 0.05
    edge = np.array([0.0, 0.5, 0.0, 0.0, 1.0])
    edged = Scores(L=L_FIXED, w=L_FIXED.copy(), C=C_FIXED, C_edge=edge)
    sum_c = C_FIXED.sum() + 0.6 * 0.5 + 0.4 * 1.0
    sum_l = 0.9 + 0.5 * 0.5 + 0.1
    rule = chpf("paper", edge_discounts_l=True)
    assert rule.alpha(edged) == pytest.approx(sum_c / (sum_c + sum_l))
    assert rule.last_doubt == pytest.approx(sum_c / (sum_c + L_FIXED.sum()))
    framed = Scores(L=L_FIXED, w=L_FIXED.copy(), C=C_FIXED, reference=(0.5, 0.2), C_edge=edge)
    L_rel = np.minimum(L_FIXED / 0.5, 1.0) * (1.0 - edge)
    C_rel = np.clip((1.0 - (1.0 - C_FIXED) * (1.0 - edge) - 0.2) / 0.8, 0.0, 1.0)
    assert rule.alpha(framed) == pytest.approx(C_rel.sum() / (C_rel.sum() + L_rel.sum()))
    assert rule.alpha(scores()) == chpf("paper").alpha(scores())  # no C_edge: as without


def test_chpf_without_c_is_a_config_error():
    with pytest.raises(ConfigError):
        CHPF().alpha(scores(C=None))


def test_srl_alpha_is_clipped_one_minus_mean_over_beta():
    assert SRL(SRLConfig(beta=0.6)).alpha(scores()) == pytest.approx(1.0 - 0.36 / 0.6)
    assert SRL(SRLConfig(beta=0.3)).alpha(scores()) == 0.0  # mean above beta -> clipped at 0
    assert SRL(SRLConfig(beta=0.5)).alpha(scores(L=[0, 0, 0])) == 1.0
    with pytest.raises(ConfigError):
        SRL(SRLConfig(beta=0.0))


def test_augmcl_follows_slow_and_fast_averages():
    s = AugMCL(AugMCLConfig(a_slow=0.01, a_fast=0.5))
    # first frame: both averages start at w_avg -> alpha 0
    assert s.alpha(scores(L=[0.8, 0.8])) == 0.0
    assert s.w_slow == pytest.approx(0.8) and s.w_fast == pytest.approx(0.8)
    # second frame w_avg = 0.2
    w_slow = 0.8 + 0.01 * (0.2 - 0.8)
    w_fast = 0.8 + 0.5 * (0.2 - 0.8)
    assert s.alpha(scores(L=[0.2, 0.2])) == pytest.approx(1.0 - w_fast / w_slow)
    # a good frame again: w_fast > w_slow -> alpha clipped to 0
    for _ in range(5):
        a = s.alpha(scores(L=[1.0, 1.0]))
    assert a == 0.0
    s.reset()
    assert s.w_slow is None and s.alpha(scores(L=[0.1])) == 0.0
    with pytest.raises(ConfigError):
        AugMCL(AugMCLConfig(a_slow=0.5, a_fast=0.1))


def test_fixed_rates_and_no_reinvigoration():
    assert FixedRate(FixedConfig(rate=0.25)).alpha(scores()) == 0.25
    assert NoReinvigoration().alpha(scores()) == 0.0
    assert Annealing().alpha(scores()) == 0.0
    assert E2E(E2EConfig(rate=0.3)).alpha(scores()) == 0.3
    with pytest.raises(ConfigError):
        FixedRate(FixedConfig(rate=1.5))


def test_annealing_schedule_is_validated():
    a = Annealing(AnnealingConfig(betas=(0.1, 0.4, 1.0), decay=0.5))
    assert a.betas == (0.1, 0.4, 1.0) and a.layer_decay == 0.5
    for bad in [(0.5, 0.2, 1.0), (0.2, 0.5), ()]:
        with pytest.raises(ConfigError):
            Annealing(AnnealingConfig(betas=bad))


def test_e2e_proposes_around_the_single_frame_estimate():
    oracle = OracleLikelihood(estimate_noise=(0.0, 0.0))
    R_gt, t_gt = np.eye(3), np.array([0.1, 0.0, 0.9])
    oracle.set_pose(R_gt, t_gt)
    frame = Frame(np.zeros((4, 4, 3), np.uint8), None, np.eye(3), (0, 0, 1, 1))
    rng = np.random.default_rng(0)
    e2e = E2E(E2EConfig(rate=0.5, sigma_t=(0.01, 0.01, 0.01), sigma_r=0.05))
    R, t = e2e.propose(frame, 200, rng, oracle)
    assert R.shape == (200, 3, 3) and t.shape == (200, 3)
    np.testing.assert_allclose(t.mean(0), t_gt, atol=0.003)
    np.testing.assert_allclose(t.std(0), 0.01, rtol=0.2)
    # no single-frame estimator -> fall back to phi_cand
    assert E2E().propose(frame, 5, rng, object()) is None
