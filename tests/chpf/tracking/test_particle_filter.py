"""The 6D particle-filter core with the OracleLikelihood (no networks)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from chpf.geometry import axis_angle_to_matrix, geodesic_angle, perturb_rotations
from chpf.tracking import (
    CHPF,
    E2E,
    SRL,
    Annealing,
    AugMCL,
    CandidateSampler,
    Frame,
    NoReinvigoration,
    OracleLikelihood,
    ParticleFilter,
    RandomWalk,
    Scores,
    WeightCollapseWarning,
)
from chpf.tracking.strategies import (
    CHPF_SUMS,
    AnnealingConfig,
    CHPFConfig,
    FixedConfig,
    FixedRate,
    SRLConfig,
)


def make_filter(strategy, likelihood, seed=0, n=50):
    return ParticleFilter(
        likelihood,
        strategy,
        n_particles=n,
        motion=RandomWalk(sigma_t=0.01, sigma_r=0.1),
        candidates=CandidateSampler(z_range=(0.6, 1.0)),
        rng=np.random.default_rng(seed),
    )


def run(filt, oracle, seq, frames=None, box=True):
    """Track frames of seq; returns (T,2) errors (m, deg) and the results."""
    errs, results = [], []
    for i in frames if frames is not None else range(len(seq)):
        oracle.set_pose(seq.R[i], seq.t[i])
        r = filt.step(Frame(seq.rgb, None, seq.K, seq.box(i) if box else None))
        results.append(r)
        if r.ok:
            errs.append([np.linalg.norm(r.t - seq.t[i]), np.degrees(geodesic_angle(r.R, seq.R[i]))])
        else:
            errs.append([np.inf, np.inf])
    return np.array(errs), results


# The oracle's L = 0.2 + 0.8 s is linear in its score with a floor, unlike the networks' cosine
# that chpf.l_power (default 4) spreads out: CH-PF runs here with L as it is (l_power 1).
CHPF_ORACLE = CHPFConfig(l_power=1.0)


@pytest.mark.parametrize(
    "strategy",
    [
        CHPF(CHPFConfig(sums="paper", l_power=1.0, c_weight=0.0, keep_belief=False, temper=0.0)),
        SRL(SRLConfig(beta=0.6)),
        E2E(),
    ],
)
def test_reinvigorating_filters_converge_from_the_candidate_distribution(sequence, strategy):
    oracle = OracleLikelihood()
    errs, results = run(make_filter(strategy, oracle), oracle, sequence)
    assert errs[0, 1] > 20.0  # starts from the uninformed candidate distribution
    final = errs[-15:].mean(axis=0)
    assert final[0] < 0.02 and final[1] < 20.0, (strategy.name, final)
    r = results[-1]
    assert r.R.shape == (3, 3) and r.t.shape == (3,) and r.ok and r.weighed
    assert 1.0 <= r.ess <= 50.0
    rule = {  # each strategy's alpha from the frame's recorded sums (N = 50)
        "chpf": r.sum_C / (r.sum_C + r.sum_L),
        "srl": float(np.clip(1.0 - r.sum_L / 50 / 0.6, 0.0, 1.0)),
        "e2e": 0.2,
    }
    assert r.alpha == pytest.approx(rule[strategy.name], abs=1e-12)
    assert np.isfinite(r.sum_L) and np.isfinite(r.sum_C)
    assert {"likelihood", "estimate", "resample", "total"} <= set(r.stage_ms)


@pytest.mark.parametrize(
    "strategy", [CHPF(), SRL(SRLConfig(beta=0.6)), AugMCL(), Annealing(), E2E(), NoReinvigoration()]
)
def test_every_strategy_tracks_a_moving_pose_from_a_good_start(sequence, strategy):
    oracle = OracleLikelihood()
    filt = make_filter(strategy, oracle)
    run(filt, oracle, sequence, range(1))
    rng = np.random.default_rng(1)
    R0 = perturb_rotations(np.broadcast_to(sequence.R[0], (50, 3, 3)), 0.05, rng)
    filt.set_particles(R0, sequence.t[0] + rng.normal(0.0, 0.005, (50, 3)))
    errs, _ = run(filt, oracle, sequence, range(1, len(sequence)))
    assert errs[:, 0].max() < 0.03 and errs[-15:, 1].mean() < 15.0, (strategy.name, errs[-15:])


def test_annealing_weighs_once_per_layer(sequence):
    oracle = OracleLikelihood()
    filt = make_filter(Annealing(AnnealingConfig(betas=(0.3, 0.6, 1.0))), oracle)
    run(filt, oracle, sequence, frames=range(5))
    assert oracle.calls == 15
    assert "anneal" in filt.step(Frame(sequence.rgb, None, sequence.K, sequence.box(5))).stage_ms


def test_same_seed_same_poses(sequence):
    outs = []
    for seed in (3, 3, 4):
        oracle = OracleLikelihood(rng=np.random.default_rng(seed))
        _, res = run(make_filter(E2E(), oracle, seed=seed), oracle, sequence, range(10))
        outs.append(np.concatenate([np.concatenate([r.R.ravel(), r.t]) for r in res]))
    np.testing.assert_array_equal(outs[0], outs[1])
    assert not np.allclose(outs[0], outs[2])


@pytest.mark.parametrize("sums", CHPF_SUMS)
def test_chpf_recovers_after_a_forced_collapse_onto_a_wrong_pose(sequence, sums):
    oracle = OracleLikelihood()
    filt = make_filter(CHPF(CHPFConfig(sums=sums, l_power=1.0)), oracle)
    errs, res = run(filt, oracle, sequence, range(30))
    alpha_tracking = np.mean([r.alpha for r in res[-10:]])
    assert errs[-5:, 0].mean() < 0.02
    # collapse: every particle on one wrong pose (90 deg off, 8 cm away)
    wrong_R = axis_angle_to_matrix(np.array([0.0, np.pi / 2, 0.0])) @ sequence.R[30]
    wrong_t = sequence.t[30] + np.array([0.08, 0.0, 0.0])
    filt.set_particles(np.broadcast_to(wrong_R, (50, 3, 3)), np.broadcast_to(wrong_t, (50, 3)))
    errs2, res2 = run(filt, oracle, sequence, range(30, 60))
    assert res2[0].alpha > 0.8 > alpha_tracking
    assert errs2[0, 1] > 45.0  # the estimate is wrong right after the collapse
    assert errs2[-10:, 0].mean() < 0.02 and errs2[-10:, 1].mean() < 20.0


def test_the_filter_marks_the_particles_it_just_reinvigorated(sequence):
    oracle = OracleLikelihood()
    filt = make_filter(FixedRate(FixedConfig(rate=0.2)), oracle)
    run(filt, oracle, sequence, range(1))
    assert filt.fresh.sum() == 10 and filt.fresh[-10:].all()  # the proposal's share, at the end
    filt.set_particles(filt.R, filt.t)
    assert not filt.fresh.any()


@pytest.mark.parametrize("keep", [True, False])
def test_chpf_drawn_particles_join_the_whole_belief_or_replace_part_of_it(sequence, keep):
    oracle = OracleLikelihood()
    filt = make_filter(CHPF(CHPFConfig(l_power=1.0, keep_belief=keep)), oracle)
    _, res = run(filt, oracle, sequence, range(3))
    for frame in range(3, 6):
        n_drawn = round(res[-1].alpha * 50)
        assert filt.fresh.sum() == n_drawn and filt.fresh[len(filt.fresh) - n_drawn :].all()
        assert len(filt.R) == len(filt.t) == len(filt.fresh) == (50 + n_drawn if keep else 50)
        calls = oracle.calls
        _, more = run(filt, oracle, sequence, range(frame, frame + 1))
        assert oracle.calls == calls + 1 and more[0].ok  # all of them weighed in one call
        res = more


def test_chpf_weights_follow_c_when_l_says_nothing(sequence):
    """Occluded (L and w flat, C informative): half the particles at the truth, half 10 cm off
    (oracle C = 1 - exp(-0.5 (0.1 / 0.06)^2) = 0.75 there, 0 at the truth). The paper's weights
    average the two halves (5 cm off); w (1 - C) keeps the estimate at 0.25 / 1.25 x 10 cm."""
    err = {}
    for c_weight in (0.0, 1.0):
        oracle = OracleLikelihood(occluded_L=0.5)
        filt = make_filter(CHPF(CHPFConfig(l_power=1.0, c_weight=c_weight)), oracle)
        run(filt, oracle, sequence, range(1))
        t0 = np.concatenate([np.broadcast_to(sequence.t[1], (25, 3)),
                             np.broadcast_to(sequence.t[1] + [0.1, 0, 0], (25, 3))])  # fmt: skip
        filt.set_particles(np.broadcast_to(sequence.R[1], (50, 3, 3)), t0)
        filt.motion = RandomWalk(sigma_t=0.0, sigma_r=0.0)
        oracle.occluded = True
        errs, _ = run(filt, oracle, sequence, range(1, 2))
        err[c_weight] = errs[0, 0]
    assert err[0.0] == pytest.approx(0.05, abs=0.002)
    assert err[1.0] == pytest.approx(0.1 * 0.25 / 1.25, abs=0.003)


def test_no_reinvigoration_does_not_recover_from_the_same_collapse(sequence):
    oracle = OracleLikelihood()
    filt = make_filter(NoReinvigoration(), oracle)
    run(filt, oracle, sequence, range(30))
    wrong_R = axis_angle_to_matrix(np.array([0.0, np.pi, 0.0])) @ sequence.R[30]
    wrong_t = sequence.t[30] + np.array([0.15, 0.0, 0.0])
    filt.set_particles(np.broadcast_to(wrong_R, (50, 3, 3)), np.broadcast_to(wrong_t, (50, 3)))
    errs2, _ = run(filt, oracle, sequence, range(30, 60))
    assert errs2[-10:, 1].mean() > 30.0


def test_occlusion_is_no_evidence_against_a_correct_belief_for_chpf(sequence):
    """Particles at the truth, L uninformative (occluded), C informative: SRL reinvigorates
    most particles, CH-PF few; on a wrong belief CH-PF reinvigorates most."""
    alphas = {}
    for strategy in (CHPF(CHPF_ORACLE), SRL(SRLConfig(beta=0.6))):
        for where in ("right", "wrong"):
            oracle = OracleLikelihood(occluded_L=0.1)
            oracle.occluded = True
            filt = make_filter(strategy, oracle)
            run(filt, oracle, sequence, range(1))
            t0 = sequence.t[1] + (0.0 if where == "right" else 0.1)
            R0 = np.broadcast_to(sequence.R[1], (50, 3, 3))
            filt.set_particles(R0, np.broadcast_to(t0, (50, 3)))
            _, res = run(filt, oracle, sequence, range(1, 2))
            alphas[strategy.name, where] = res[0].alpha
    assert alphas["srl", "right"] > 0.8 and alphas["chpf", "right"] < 0.5
    assert alphas["chpf", "wrong"] > 0.85


class _BrokenLikelihood:
    def __init__(self, value):
        self.value = value

    def score(self, frame, R, t):
        n = R.shape[0]
        return Scores(L=np.full(n, self.value), w=np.full(n, self.value), C=np.full(n, 0.5))


@pytest.mark.parametrize("value", [0.0, np.nan])
def test_all_zero_or_nan_weights_reinvigorate_fully_with_one_warning(sequence, value):
    filt = make_filter(SRL(SRLConfig(beta=0.6)), _BrokenLikelihood(value))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = [Frame(sequence.rgb, None, sequence.K, sequence.box(i)) for i in range(4)]
        results = [filt.step(f) for f in frames]
    assert [w.category for w in caught] == [WeightCollapseWarning]
    assert all(r.alpha == 1.0 and r.ok and r.ess == 0.0 for r in results)
    assert np.all(np.isfinite(results[-1].t)) and filt.warner.count == 4


def test_frames_without_a_box(sequence):
    oracle = OracleLikelihood()
    filt = make_filter(CHPF(), oracle)
    # no detection yet: no estimate, nothing scored
    r0 = filt.step(Frame(sequence.rgb, None, sequence.K, None))
    assert not r0.ok and r0.R is None and not filt.initialised and oracle.calls == 0
    _, res = run(filt, oracle, sequence, range(20))
    calls = oracle.calls
    t_before = filt.t.copy()
    # a frame without a box: predict only, the estimate is kept
    r = filt.step(Frame(sequence.rgb, None, sequence.K, None))
    assert oracle.calls == calls and r.ok and not r.weighed and np.isnan(r.alpha)
    np.testing.assert_array_equal(r.t, res[-1].t)
    assert not np.array_equal(filt.t, t_before)  # particles were diffused
    # degenerate boxes count as no box
    r = filt.step(Frame(sequence.rgb, None, sequence.K, (10.0, 10.0, 0.0, 5.0)))
    assert not r.weighed
    filt.reset()
    assert not filt.initialised and filt.estimate is None
