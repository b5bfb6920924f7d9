"""Tracking runtime: particle filters over 6D pose, reinvigoration strategies, likelihoods.

The filters take a Likelihood (chpf.tracking.types) so they run with the learned likelihoods
of a model bundle (``Tracker.from_bundle``) or, in tests, with the OracleLikelihood.
``Tracker``, ``MultiTracker`` (several objects), ``TrackConfig`` and ``make_config`` are
imported on first use (they load onnxruntime).
"""

from typing import Any

from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.motion import RandomWalk
from chpf.tracking.oracle import OracleLikelihood
from chpf.tracking.particle_filter import ParticleFilter
from chpf.tracking.rbpf import RaoBlackwellisedFilter
from chpf.tracking.strategies import (
    CHPF,
    E2E,
    SRL,
    Annealing,
    AugMCL,
    FixedRate,
    NoReinvigoration,
    Strategy,
)
from chpf.tracking.types import Frame, Likelihood, Scores, TrackResult
from chpf.tracking.warn import WeightCollapseWarning

__all__ = [
    "CHPF",
    "E2E",
    "SRL",
    "Annealing",
    "AugMCL",
    "CandidateSampler",
    "FixedRate",
    "Frame",
    "Likelihood",
    "MultiTracker",
    "NoReinvigoration",
    "OracleLikelihood",
    "ParticleFilter",
    "RandomWalk",
    "RaoBlackwellisedFilter",
    "Scores",
    "Strategy",
    "TrackConfig",
    "TrackResult",
    "Tracker",
    "WeightCollapseWarning",
    "make_config",
]


def __getattr__(name: str) -> Any:
    if name == "Tracker":
        from chpf.tracking.tracker import Tracker

        return Tracker
    if name == "MultiTracker":
        from chpf.tracking.multi import MultiTracker

        return MultiTracker
    if name in ("TrackConfig", "make_config"):
        from chpf.tracking import config

        return getattr(config, name)
    raise AttributeError(f"module 'chpf.tracking' has no attribute {name!r}")
