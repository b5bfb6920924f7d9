"""The registry of tracking methods: one entry per method (name, class, options, description).

That entry is all there is to a method: ``chpf-track --method`` and ``all``,
``Tracker(method=...)``, the ``TrackConfig`` section of its options (``srl: {beta: 0.6}``) and
the README's table of methods all come from ``METHODS``. Adding a method = its class (a
Strategy of the 6D core, or a filter of its own) with its options dataclass + one ``register``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol

import numpy as np

from chpf.config_schema import Section, setting
from chpf.errors import ConfigError
from chpf.tracking.candidates import CandidateSampler
from chpf.tracking.chrbpf import CHRBPF
from chpf.tracking.motion import RandomWalk
from chpf.tracking.particle_filter import ParticleFilter
from chpf.tracking.rbpf import RaoBlackwellisedFilter
from chpf.tracking.strategies import (
    CHPF,
    E2E,
    SRL,
    Annealing,
    AnnealingConfig,
    AugMCL,
    AugMCLConfig,
    CHPFConfig,
    E2EConfig,
    FixedConfig,
    FixedRate,
    NoReinvigoration,
    SRLConfig,
    Strategy,
)
from chpf.tracking.types import Frame, TrackResult

if TYPE_CHECKING:
    from chpf.tracking.config import TrackConfig


class Filter(Protocol):
    """What every filter offers: one step per frame, reset between sequences, its current
    estimate (R (3,3), t (3,) metres; None before the first weighed frame) and its random
    generator."""

    estimate: tuple[np.ndarray, np.ndarray] | None
    rng: np.random.Generator

    def step(self, frame: Frame) -> TrackResult: ...

    def reset(self) -> None: ...


Build = Callable[..., Filter]
"""(likelihood, options, n_particles, motion, candidates, rng, *also) -> the method's filter;
``also``: the config sections named by ``Method.also``."""


@dataclass(frozen=True)
class Method:
    """One tracking method.

    cls: its Strategy (run by the 6D ParticleFilter) or its own filter class.
    options: its options dataclass (None: it has none), the TrackConfig section ``section``.
    build: how a filter class that is not a Strategy is made (None for strategies).
    paper: run by ``--method all`` (the methods compared in the paper, and CH-RBPF).
    also: other config sections that ``build`` reads (passed after rng, in this order).
    """

    name: str
    cls: type
    options: type[Section] | None
    description: str
    paper: bool = True
    section: str = ""
    build: Build | None = None
    also: tuple[str, ...] = ()

    def make(
        self,
        likelihood: object,
        options: Any,
        n_particles: int,
        motion: RandomWalk,
        candidates: CandidateSampler,
        rng: np.random.Generator,
        *also: Any,
    ) -> Filter:
        """This method's filter around ``likelihood`` with ``options`` (its config section)
        and the sections named by ``also``."""
        if self.build is not None:
            return self.build(likelihood, options, n_particles, motion, candidates, rng, *also)
        strategy: Strategy = self.cls(options) if self.options else self.cls()
        return ParticleFilter(
            likelihood,  # type: ignore[arg-type]
            strategy,
            n_particles=n_particles,
            motion=motion,
            candidates=candidates,
            rng=rng,
        )


METHODS: dict[str, Method] = {}
"""Every registered method by name, in registration order."""


def register(method: Method) -> Method:
    """Add ``method`` to METHODS (its section defaults to its name)."""
    if method.name in METHODS:
        raise ValueError(f"method {method.name!r} is registered twice")
    if method.options is not None and not method.section:
        object.__setattr__(method, "section", method.name)
    METHODS[method.name] = method
    return method


def method_names(paper_only: bool = False) -> tuple[str, ...]:
    """The registered method names (the paper's only, for ``--method all``)."""
    return tuple(name for name, m in METHODS.items() if m.paper or not paper_only)


def get_method(name: str) -> Method:
    """The registered method ``name``; ConfigError naming the choices otherwise."""
    if name not in METHODS:
        raise ConfigError(f"unknown method {name!r} (choose from {', '.join(METHODS)})")
    return METHODS[name]


@dataclass
class PoseRBPFConfig(Section):
    """PoseRBPF and PoseRBPF++ (their section is ``poserbpf``).

    sigma: cosine -> rotation likelihood width; neighbours: grid neighbours of the rotation
    prior's diffusion; rotation_sigma: its width in radians (None = the grid spacing);
    reset_threshold: best cosine below which all particles are redrawn; plus_fraction:
    PoseRBPF++'s share reinvigorated every frame; search_fraction: the least share drawn from
    phi_cand (joining the belief) on a frame whose search probe took over (chpf.tracking.rbpf;
    0: off); rotation_estimate: argmax | mean.
    """

    sigma: float = setting(0.1, gt=0.0)
    neighbours: int = 12
    rotation_sigma: float | None = None
    reset_threshold: float = 0.4
    plus_fraction: float = setting(0.5, ge=0.0, le=1.0)
    search_fraction: float = setting(0.5, ge=0.0, le=1.0)
    rotation_estimate: Literal["argmax", "mean"] = "argmax"


def _rotation_filter_options(options: PoseRBPFConfig) -> dict[str, Any]:
    """RaoBlackwellisedFilter's keywords for its rotation filter, shared by PoseRBPF(++) and
    CH-RBPF."""
    return {
        "sigma": options.sigma,
        "rotation_sigma": options.rotation_sigma,
        "n_neighbours": options.neighbours,
        "rotation_estimate": options.rotation_estimate,
        "search_fraction": options.search_fraction,
    }


def _poserbpf(plus: bool) -> Build:
    """Build PoseRBPF (plus: PoseRBPF++, reinvigorating plus_fraction every frame)."""

    def build(
        likelihood: object,
        options: PoseRBPFConfig,
        n_particles: int,
        motion: RandomWalk,
        candidates: CandidateSampler,
        rng: np.random.Generator,
    ) -> Filter:
        return RaoBlackwellisedFilter(
            likelihood,  # type: ignore[arg-type]
            n_particles=n_particles,
            motion=motion,
            candidates=candidates,
            rng=rng,
            reset_threshold=options.reset_threshold,
            reinvigorate=options.plus_fraction if plus else 0.0,
            name="poserbpf++" if plus else "poserbpf",
            **_rotation_filter_options(options),
        )

    return build


def _chrbpf(
    likelihood: object,
    options: PoseRBPFConfig,
    n_particles: int,
    motion: RandomWalk,
    candidates: CandidateSampler,
    rng: np.random.Generator,
    ch: CHPFConfig,
) -> Filter:
    """Build CH-RBPF: PoseRBPF's filter (``poserbpf`` options) with CH-PF's rule (``chpf``)."""
    return CHRBPF(
        likelihood,  # type: ignore[arg-type]
        CHPF(ch),
        n_particles=n_particles,
        motion=motion,
        candidates=candidates,
        rng=rng,
        **_rotation_filter_options(options),
    )


register(Method("chpf", CHPF, CHPFConfig, "Counter-Hypothetical PF: alpha = S_C / (S_C + S_L)"))
register(
    Method(
        "srl",
        SRL,
        SRLConfig,
        "Sensor Resetting Localisation: alpha = clip(1 - mean L / beta, 0, 1)",
    )
)
register(
    Method(
        "augmcl",
        AugMCL,
        AugMCLConfig,
        "Augmented MCL: alpha = max(0, 1 - w_fast / w_slow) from two averages of mean L",
    )
)
register(
    Method(
        "annealing",
        Annealing,
        AnnealingConfig,
        "annealed PF: M layers per frame weighing with w^beta_m, no reinvigoration",
    )
)
register(
    Method(
        "e2e",
        E2E,
        E2EConfig,
        "MCL + E2E: a fixed fraction drawn around the autoencoder's single-frame estimate",
    )
)
register(
    Method(
        "poserbpf",
        RaoBlackwellisedFilter,
        PoseRBPFConfig,
        "PoseRBPF: translation particles, each with a distribution over the codebook"
        " orientations; all redrawn on low similarity",
        build=_poserbpf(False),
    )
)
register(
    Method(
        "poserbpf++",
        RaoBlackwellisedFilter,
        PoseRBPFConfig,
        "PoseRBPF++: PoseRBPF with plus_fraction of the particles reinvigorated every frame",
        section="poserbpf",
        build=_poserbpf(True),
    )
)
register(
    Method(
        "chrbpf",
        CHRBPF,
        PoseRBPFConfig,
        "CH-RBPF: PoseRBPF's filter, alpha by CH-PF's rule over each particle's most probable"
        " orientation (no threshold reset)",
        section="poserbpf",
        build=_chrbpf,
        also=("chpf",),
    )
)
register(Method("fixed", FixedRate, FixedConfig, "6D PF with a constant alpha = rate", paper=False))
register(Method("none", NoReinvigoration, None, "plain SIR 6D PF (alpha = 0)", paper=False))


def make_filter(
    method: str,
    likelihood: object,
    cfg: TrackConfig,
    candidates: CandidateSampler,
    rng: np.random.Generator,
) -> Filter:
    """The filter of the registered ``method`` around ``likelihood``, with cfg's options."""
    spec = get_method(method)
    return spec.make(
        likelihood,
        getattr(cfg, spec.section) if spec.options else None,
        cfg.filter.n_particles,
        RandomWalk(cfg.motion.sigma_t, cfg.motion.sigma_r),
        candidates,
        rng,
        *(getattr(cfg, section) for section in spec.also),
    )
