"""The frame loop both filters run (FilterLoop): collapse handling, predict-only frames,
the resampling scheme option."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from chpf.geometry import RotationGrid
from chpf.tracking import (
    SRL,
    CandidateSampler,
    Frame,
    ParticleFilter,
    RandomWalk,
    RaoBlackwellisedFilter,
    Scores,
    WeightCollapseWarning,
)
from chpf.tracking.filter_loop import FilterLoop
from chpf.tracking.strategies import SRLConfig
from chpf.tracking.types import CodebookScores

GRID = RotationGrid.uniform(256)


class _NanLikelihood:
    """Scores every hypothesis NaN: both filters' weights collapse on every frame."""

    grid = GRID

    def score(self, frame, R, t):
        n = R.shape[0]
        return Scores(L=np.full(n, np.nan), w=np.full(n, np.nan), C=None)

    def codebook_scores(self, frame, t):
        return CodebookScores(cos=np.full((t.shape[0], len(GRID)), np.nan))

    def depth_weight(self, frame, k, t):
        return None


def _filters(resampling="systematic"):
    common = dict(
        n_particles=20,
        motion=RandomWalk(sigma_t=0.01, sigma_r=0.1),
        candidates=CandidateSampler(z_range=(0.6, 1.0)),
        rng=np.random.default_rng(0),
        resampling=resampling,
    )
    lik = _NanLikelihood()
    return [
        ParticleFilter(lik, SRL(SRLConfig(beta=0.6)), **common),
        RaoBlackwellisedFilter(lik, reset_threshold=-2.0, **common),
    ]


@pytest.mark.parametrize("filt", _filters(), ids=["6d", "rbpf"])
def test_both_filters_share_the_loop(sequence, filt):
    assert isinstance(filt, FilterLoop)
    no_box = Frame(sequence.rgb, None, sequence.K, None)
    assert not filt.step(no_box).ok and not filt.initialised  # nothing until a box
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = [filt.step(Frame(sequence.rgb, None, sequence.K, sequence.box(i))) for i in range(3)]
    # a collapse: one warning per filter, full reinvigoration, the uniform-weight estimate
    assert [w.category for w in caught] == [WeightCollapseWarning] and filt.warner.count == 3
    assert all(r.alpha == 1.0 and r.ess == 0.0 and r.ok and r.weighed for r in res)
    t_est = res[-1].t
    assert np.all(np.isfinite(t_est)) and np.array_equal(t_est, res[0].t)
    # a frame without a box: predict only, the estimate is kept, nothing recorded
    r = filt.step(no_box)
    assert r.ok and not r.weighed and np.isnan(r.alpha) and np.isnan(r.ess)
    assert np.array_equal(r.t, t_est) and "predict" in r.stage_ms
    filt.reset()
    assert not filt.initialised and filt.estimate is None


@pytest.mark.parametrize("scheme", ["systematic", "multinomial"])
def test_the_resampling_scheme_is_an_option(scheme):
    assert all(f.resample_indices.__name__ == f"{scheme}_resample" for f in _filters(scheme))
