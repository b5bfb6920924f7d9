"""PoseRBPF / PoseRBPF++ / CH-RBPF with the OracleLikelihood, and the rotation-prior diffusion
matrix."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from chpf.geometry import RotationGrid, geodesic_angle
from chpf.tracking import (
    CandidateSampler,
    Frame,
    OracleLikelihood,
    RandomWalk,
    RaoBlackwellisedFilter,
)
from chpf.tracking.chrbpf import CHRBPF
from chpf.tracking.rotation_diffusion import grid_spacing, neighbour_matrix, neighbour_table
from chpf.tracking.strategies import CHPF, CHPFConfig
from chpf.tracking.types import Region

GRID = RotationGrid.uniform(2048)


def make_rbpf(oracle, reinvigorate=0.0, seed=0, **kw):
    return RaoBlackwellisedFilter(
        oracle,
        n_particles=50,
        motion=RandomWalk(sigma_t=0.01, sigma_r=0.1),
        candidates=CandidateSampler(z_range=(0.6, 1.0)),
        rng=np.random.default_rng(seed),
        reinvigorate=reinvigorate,
        **kw,
    )


def track(filt, oracle, seq, frames):
    errs, res = [], []
    for i in frames:
        oracle.set_pose(seq.R[i], seq.t[i])
        r = filt.step(Frame(seq.rgb, None, seq.K, seq.box(i)))
        res.append(r)
        errs.append([np.linalg.norm(r.t - seq.t[i]), np.degrees(geodesic_angle(r.R, seq.R[i]))])
    return np.array(errs), res


def test_neighbour_matrix_is_row_stochastic_and_local():
    D = neighbour_matrix(GRID, k=8)
    assert D.shape == (2048, 2048)
    np.testing.assert_allclose(np.asarray(D.sum(axis=1)).ravel(), 1.0)
    assert np.all(np.diff(D.indptr) == 8)
    rows = np.repeat(np.arange(2048), 8)
    angles = geodesic_angle(GRID.rotations[rows], GRID.rotations[D.indices])
    assert angles.max() < 4 * grid_spacing(GRID)
    # each entry keeps the largest share of its own mass
    assert np.all(D.diagonal() >= D.max(axis=1).toarray().ravel() - 1e-12)
    # a point mass diffuses to its neighbours and stays a distribution
    p = np.zeros((1, 2048))
    p[0, 5] = 1.0
    q = p @ D
    assert q.sum() == pytest.approx(1.0) and np.count_nonzero(q) > 1


@pytest.mark.parametrize("estimate", ["argmax", "mean"])
def test_poserbpf_converges_on_a_synthetic_moving_pose(sequence, estimate):
    oracle = OracleLikelihood(grid=GRID)
    errs, res = track(make_rbpf(oracle, rotation_estimate=estimate), oracle, sequence, range(40))
    final = errs[-10:].mean(axis=0)
    assert final[0] < 0.02 and final[1] < 12.0, final
    assert all(r.alpha == 0.0 for r in res[-10:])  # no reinvigoration once tracking
    assert np.isnan(res[-1].sum_C) and res[-1].sum_L > 0


def test_poserbpf_plus_plus_reinvigorates_half(sequence):
    oracle = OracleLikelihood(grid=GRID)
    errs, res = track(make_rbpf(oracle, reinvigorate=0.5), oracle, sequence, range(40))
    assert errs[-10:, 0].mean() < 0.02 and errs[-10:, 1].mean() < 12.0
    assert all(r.alpha == 0.5 for r in res[-10:])


def test_poserbpf_resets_when_similarity_drops(sequence):
    oracle = OracleLikelihood(grid=GRID, occluded_L=0.1)
    filt = make_rbpf(oracle, reset_threshold=0.3)
    track(filt, oracle, sequence, range(20))
    resets = filt.n_resets
    oracle.occluded = True
    _, res = track(filt, oracle, sequence, range(20, 22))
    assert res[0].alpha == 1.0 and filt.n_resets == resets + 2
    np.testing.assert_allclose(filt.P, 1.0 / len(GRID))  # all particles redrawn, uniform


def _searched(seq, i, scale):
    """Frame i of ``seq`` without a detection, with a search region around the object whose
    window is widened ``scale`` times (its area: the object's box enlarged 3 times; widened:
    as when a probe took over there)."""
    box = seq.box(i)
    cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
    area = (cx - 1.5 * box[2], cy - 1.5 * box[3], 3 * box[2], 3 * box[3])
    region = Region(box, area, area, scale, cue=scale <= 1.0, probed=scale > 1.0)
    return Frame(seq.rgb, None, seq.K, None, region)


def test_a_lost_poserbpf_draws_from_a_widened_window_without_its_reset_and_finds_it(sequence):
    """PoseRBPF draws from phi_cand only on its reset, which a lost filter's similarity need
    not trigger (here never: reset_threshold -1): a widened search window (the likelihood said
    lost for ``patience`` frames) makes it draw search_fraction of N, joining the belief."""
    oracle = OracleLikelihood(grid=GRID)
    filt = make_rbpf(oracle, reset_threshold=-1.0)
    track(filt, oracle, sequence, range(10))
    filt.set_particles(filt.t + np.array([0.15, 0.0, 0.0]))  # lost: 15 cm off, ~60 px
    oracle.set_pose(sequence.R[10], sequence.t[10])
    calm = filt.step(_searched(sequence, 10, 1.0))  # not widened: nothing drawn
    assert calm.alpha == 0.0 and len(filt.t) == 50
    errs = []
    for i in range(11, 19):
        oracle.set_pose(sequence.R[i], sequence.t[i])
        frame = _searched(sequence, i, 3.0)
        r = filt.step(frame)
        assert r.alpha == 0.5
        if i == 11:  # drawn in the window, joining the whole belief
            assert len(filt.t) == 75 and filt.fresh[50:].all() and not filt.fresh[:50].any()
            uv = filt.t[50:, :2] / filt.t[50:, 2:] * sequence.K[0, 0] + sequence.K[:2, 2]
            x, y, w, h = frame.region.area
            assert np.all((uv >= (x, y)) & (uv <= (x + w, y + h)))
        errs.append(np.linalg.norm(r.t - sequence.t[i]))
    assert errs[0] > 0.1 and max(errs[-3:]) < 0.02, errs
    off = make_rbpf(OracleLikelihood(grid=GRID), reset_threshold=-1.0, search_fraction=0.0)
    track(off, oracle, sequence, range(10, 12))
    assert off.step(_searched(sequence, 12, 3.0)).alpha == 0.0  # 0: PoseRBPF's own rule


def test_chrbpf_draws_at_least_search_fraction_from_a_widened_window(sequence):
    oracle = OracleLikelihood(grid=GRID)
    filt = make_chrbpf(oracle, keep_belief=False)
    _, res = track(filt, oracle, sequence, range(15))
    assert res[-1].alpha < 0.3  # tracking: its rule draws few
    oracle.set_pose(sequence.R[15], sequence.t[15])
    r = filt.step(_searched(sequence, 15, 3.0))
    assert r.alpha == 0.5 and len(filt.t) == 75  # raised, and the draws join the belief


def test_poserbpf_same_seed_same_poses(sequence):
    outs = []
    for seed in (1, 1, 2):
        oracle = OracleLikelihood(grid=GRID)
        _, res = track(make_rbpf(oracle, seed=seed), oracle, sequence, range(8))
        outs.append(np.concatenate([np.concatenate([r.R.ravel(), r.t]) for r in res]))
    np.testing.assert_array_equal(outs[0], outs[1])
    assert not np.allclose(outs[0], outs[2])


class CountingRotations:
    """A RotationSource that counts its calls (uniform rotations)."""

    def __init__(self) -> None:
        self.calls = 0

    def sample(self, n, frame, t, rng):
        from chpf.geometry import random_rotations

        self.calls += 1
        return random_rotations(n, rng)


def test_poserbpf_draws_only_translations_from_phi_cand(sequence):
    """PoseRBPF's particles are translations: reinvigoration never asks phi_cand's rotation
    source (an informed source costs an encoder pass), and the translations it draws are the
    ones phi_cand's full poses would have."""
    source = CountingRotations()
    oracle = OracleLikelihood(grid=GRID)
    filt = make_rbpf(oracle, reinvigorate=0.5)
    filt.candidates.rotations = source
    track(filt, oracle, sequence, range(5))
    assert source.calls == 0
    frame = Frame(sequence.rgb, None, sequence.K, sequence.box(0))
    sampler = CandidateSampler(z_range=(0.6, 1.0), rotations=CountingRotations())
    t = sampler.translations(20, frame, np.random.default_rng(3))
    np.testing.assert_array_equal(t, sampler.sample(20, frame, np.random.default_rng(3))[1])


def make_chrbpf(oracle, seed=0, **ch):
    return CHRBPF(
        oracle,
        CHPF(CHPFConfig(**ch)),
        n_particles=50,
        motion=RandomWalk(sigma_t=0.01, sigma_r=0.1),
        candidates=CandidateSampler(z_range=(0.6, 1.0)),
        rng=np.random.default_rng(seed),
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_chrbpf_converges_and_its_alpha_is_chpfs_rule_over_its_particles(sequence, seed):
    """CH-RBPF tracks an unoccluded pose from the boxes alone; once it tracks, alpha is low
    and equals CH-PF's weighted rule over the particles' most probable orientations."""
    oracle = OracleLikelihood(grid=GRID)
    filt = make_chrbpf(oracle, seed=seed)
    errs, res = track(filt, oracle, sequence, range(40))
    final = errs[-10:].mean(axis=0)
    assert final[0] < 0.02 and final[1] < 12.0, final
    assert np.mean([r.alpha for r in res[-10:]]) < 0.2
    assert np.isfinite(res[-1].sum_C) and res[-1].sum_L > 0
    # the rule on the next frame's own numbers
    i = 40
    oracle.set_pose(sequence.R[i], sequence.t[i])
    filt._predict()
    frame = Frame(sequence.rgb, None, sequence.K, sequence.box(i))
    weighed = filt._weigh(frame, {})
    k = np.argmax(filt.P, axis=1)
    cos = oracle.codebook_scores(frame, filt.t).cos[np.arange(len(k)), k]
    C = oracle.codebook_scores(frame, filt.t).misaligned(k)
    W = weighed.weights.W
    e_c, e_l = W @ C, W @ np.clip(cos, 0, None) ** CHPFConfig().l_power
    assert weighed.alpha == pytest.approx(e_c / (e_c + e_l))
    assert weighed.sum_C == pytest.approx(C.sum())


def test_chrbpf_reinvigorates_all_after_a_forced_collapse_and_recovers(sequence):
    oracle = OracleLikelihood(grid=GRID)
    filt = make_chrbpf(oracle)
    track(filt, oracle, sequence, range(30))
    filt.set_particles(filt.t + np.array([0.08, 0.0, 0.0]))  # 8 cm aside, orientations unknown
    errs, res = track(filt, oracle, sequence, range(30, 60))
    assert res[0].alpha > 0.8 and errs[0, 0] > 0.05
    assert errs[-10:, 0].mean() < 0.02 and errs[-10:, 1].mean() < 12.0


@pytest.mark.parametrize("keep", [True, False])
def test_chrbpf_drawn_particles_join_the_whole_belief_or_replace_part_of_it(sequence, keep):
    oracle = OracleLikelihood(grid=GRID)
    filt = make_chrbpf(oracle, keep_belief=keep)
    track(filt, oracle, sequence, range(10))
    filt.set_particles(filt.t + np.array([0.08, 0.0, 0.0]))  # lost: alpha near 1
    _, res = track(filt, oracle, sequence, range(10, 11))
    n_drawn = round(res[0].alpha * 50)
    assert n_drawn > 25
    assert filt.fresh.sum() == n_drawn and filt.fresh[-n_drawn:].all()
    assert len(filt.t) == len(filt.P) == (50 + n_drawn if keep else 50)
    _, more = track(filt, oracle, sequence, range(11, 12))
    assert more[0].ok and len(filt.weights) == len(filt.t)
    assert filt.rule.last_doubt == more[0].alpha > 0.0
    filt.reset()  # a new sequence: no doubt carried over (chpf.temper)
    assert filt.rule.last_doubt == 0.0 and not filt.initialised


def test_chrbpf_weighs_each_particle_down_by_its_c(sequence):
    """c_weight 1: the weights are PoseRBPF's times (1 - C_i), normalised."""
    oracle = OracleLikelihood(grid=GRID)
    filt = make_chrbpf(oracle, c_weight=0.0, temper=0.0)
    track(filt, oracle, sequence, range(10))
    spread = np.random.default_rng(5).normal(0.0, 0.03, filt.t.shape)
    filt.set_particles(filt.t + spread)
    oracle.set_pose(sequence.R[10], sequence.t[10])
    twin = copy.deepcopy(filt)  # its own copy of the oracle too
    twin.rule = CHPF(CHPFConfig(c_weight=1.0, temper=0.0))
    frame = Frame(sequence.rgb, None, sequence.K, sequence.box(10))
    plain, weighed = filt._weigh(frame, {}), twin._weigh(frame, {})
    C = oracle.codebook_scores(frame, twin.t).misaligned(np.argmax(twin.P, axis=1))
    assert C.std() > 0.05
    expected = plain.weights.W * (1.0 - C)
    np.testing.assert_allclose(weighed.weights.W, expected / expected.sum(), rtol=1e-6)


def test_neighbour_table_lists_each_entry_first_then_its_nearest():
    table = neighbour_table(GRID, 6)
    assert table.shape == (len(GRID), 6)
    np.testing.assert_array_equal(table[:, 0], np.arange(len(GRID)))
    assert all(len(set(row)) == 6 for row in table)
    angles = geodesic_angle(GRID.rotations[table[:, 1:]], GRID.rotations[:, None])
    assert angles.max() < 4 * grid_spacing(GRID)


def test_rbpf_draws_in_the_belief_box_when_the_detection_is_its_visible_part():
    """candidates.occluded_box acts on the Rao-Blackwellised filters too (PoseRBPF's resets,
    PoseRBPF++'s share, CH-RBPF's draws): a detection inside the belief's projected box and
    smaller by more than 10 % gives translations at the belief's place and scale (they came
    from the detection's box, whose smaller size put them too far away)."""
    K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
    frame = Frame(np.zeros((240, 320, 3), np.uint8), None, K, (130.0, 100.0, 40.0, 50.0))
    filt = RaoBlackwellisedFilter(
        OracleLikelihood(grid=GRID),
        n_particles=50,
        candidates=CandidateSampler(box_extent=0.2, occluded_box=True),
        rng=np.random.default_rng(0),
    )
    filt.estimate = (np.eye(3), np.array([0.0, 0.0, 1.0]))  # belief box: 60 px, centre (160, 120)
    t, P = filt._draw(frame, 400)
    assert P.shape == (400, len(GRID.rotations))
    # z uniform in z_box_factors (0.75, 1.35) x z_box: the belief's 60 px give z_box 1.0 m
    assert t[:, 2].mean() == pytest.approx(1.05, abs=0.04)
    u = K[0, 0] * t[:, 0] / t[:, 2] + K[0, 2]
    assert u.min() > 130.0 and u.max() < 190.0
    detection = CandidateSampler(box_extent=0.2).translations(400, frame, np.random.default_rng(0))
    assert detection[:, 2].mean() == pytest.approx(1.26, abs=0.05)  # 50 px: z_box 1.2 m
