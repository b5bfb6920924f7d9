"""Build the filter of a named method from a likelihood and a TrackConfig."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from chpf.errors import ConfigError
from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.config import METHODS, TrackConfig
from chpf.tracking.motion import RandomWalk
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
from chpf.tracking.types import Frame, TrackResult


class Filter(Protocol):
    """What every filter offers: one step per frame, reset between sequences."""

    def step(self, frame: Frame) -> TrackResult: ...

    def reset(self) -> None: ...


def make_strategy(method: str, cfg: TrackConfig) -> Strategy:
    """The reinvigoration strategy of a 6D-filter method."""
    if method == "chpf":
        return CHPF()
    if method == "srl":
        return SRL(cfg.srl_beta)
    if method == "augmcl":
        return AugMCL(cfg.augmcl_a_slow, cfg.augmcl_a_fast)
    if method == "annealing":
        return Annealing(tuple(cfg.anneal_betas), cfg.anneal_decay)
    if method == "e2e":
        s = cfg.e2e_sigma_t
        return E2E(cfg.e2e_rate, (s[0], s[1], s[2]), cfg.e2e_sigma_r)
    if method == "fixed":
        return FixedRate(cfg.fixed_rate)
    if method == "none":
        return NoReinvigoration()
    raise ConfigError(f"unknown method {method!r} (choose from {', '.join(METHODS)})")


def make_filter(
    method: str,
    likelihood: object,
    cfg: TrackConfig,
    candidates: CandidateSampler,
    rng: np.random.Generator,
) -> Filter:
    """The filter of ``method`` (see config.METHODS) around ``likelihood``."""
    motion = RandomWalk(cfg.sigma_t, cfg.sigma_r)
    if method in ("poserbpf", "poserbpf++"):
        return RaoBlackwellisedFilter(
            likelihood,  # type: ignore[arg-type]
            n_particles=cfg.n_particles,
            motion=motion,
            candidates=candidates,
            rng=rng,
            sigma=cfg.rbpf_sigma,
            rotation_sigma=cfg.rbpf_rotation_sigma,
            n_neighbours=cfg.rbpf_neighbours,
            reset_threshold=cfg.rbpf_reset_threshold,
            reinvigorate=cfg.rbpf_plus_fraction if method == "poserbpf++" else 0.0,
            rotation_estimate=cfg.rbpf_rotation_estimate,
            name=method,
        )
    strategy = make_strategy(method, cfg)
    return ParticleFilter(
        likelihood,  # type: ignore[arg-type]
        strategy,
        n_particles=cfg.n_particles,
        motion=motion,
        candidates=candidates,
        rng=rng,
    )
