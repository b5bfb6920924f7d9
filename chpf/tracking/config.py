"""Tracking options: nested sections loadable from YAML (configs/track_*.yaml) and ``--set``.

``TrackConfig`` has the core sections (filter, motion, candidates, likelihood, runtime, search:
chpf.tracking.search_region) and one
section per registered method with options (chpf.tracking.methods), e.g. ``srl: {beta: 0.6}``.
Unknown keys and out-of-range values raise ConfigError naming the key and the file; a key of
the former flat form names its new place.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from chpf.config_schema import Invalid, Section, load, read_yaml, setting
from chpf.errors import ConfigError
from chpf.tracking.methods import METHODS
from chpf.tracking.search_region import SearchConfig
from chpf.tracking.strategies import BOX_SHAPES, BOX_SIDES, C_MODES

__all__ = [
    "BOX_SHAPES",
    "BOX_SIDES",
    "C_MODES",
    "L_FROM_COS",
    "MODALITIES",
    "TrackConfig",
    "make_config",
]

MODALITIES = ("rgb", "rgbd")
LFromCos = Literal["clip", "affine"]
L_FROM_COS: tuple[str, ...] = typing.get_args(LFromCos)
"""How the cosine c in [-1, 1] becomes the unnormalised likelihood L in [0, 1] that SRL, Aug.
MCL and CH-PF sum: "clip" L = max(c, 0); "affine" L = (1 + c) / 2. With the trained encoders,
whose embeddings of unrelated views are near orthogonal (c ~ 0), "clip" gives the candidates
drawn blindly from phi_cand L ~ 0 next to C ~ 1, which holds CH-PF's alpha near 1 even on a
correct belief; "affine" keeps the baseline that an Augmented Autoencoder's cosine has."""


@dataclass
class FilterConfig(Section):
    """n_particles: particles of every method."""

    n_particles: int = setting(50, ge=1)


@dataclass
class MotionConfig(Section):
    """Random walk per frame: translation std sigma_t (m), rotation std sigma_r (rad)."""

    sigma_t: float = setting(0.01, ge=0.0)
    sigma_r: float = setting(0.08, ge=0.0)


@dataclass
class CandidatesConfig(Section):
    """The candidate distribution phi_cand (see configs/track_default.yaml for each key)."""

    z_range: tuple[float, float] = (0.3, 2.0)  # RGB z range when the box scale is not used
    z_from_box: bool = True  # RGB: z range from the box size and the object's extent
    z_box_factors: tuple[float, float] = (0.8, 1.25)
    box_uv_fraction: float = setting(0.3, gt=0.0, le=1.0)  # (u, v) in this central fraction
    rotations: Literal["uniform", "codebook"] = "codebook"  # codebook: entries matching the box
    temperature: float = setting(0.05, gt=0.0)  # codebook: p(entry) ~ exp((cos - max) / this)
    uniform_share: float = setting(0.25, ge=0.0, le=1.0)  # codebook: share drawn uniformly
    rerank: int = setting(1024, ge=0)  # codebook: the classifier ranks the best cosines' entries
    c_temperature: float = setting(0.05, gt=0.0)  # rerank: p(entry) ~ exp(-(C - min C) / this)
    depth_offset: tuple[float, float] | None = None  # RGB-D: z = measured + U(a, b); None =
    # (0, diameter / 2)
    depth_window: int = 3
    occluded_box: bool = True  # RGB: a detection of the visible part: draw at the belief's scale
    occluded_rule: Literal["inside", "around"] = "around"  # which detections are such a part

    def check(self) -> None:
        lo, hi = self.z_range
        if not 0 < lo < hi:
            raise Invalid("z_range", f"must be 0 < min < max, got {list(self.z_range)}")
        if not 0 < self.z_box_factors[0] <= self.z_box_factors[1]:
            raise Invalid("z_box_factors", f"must be 0 < min <= max, got {self.z_box_factors}")


@dataclass
class LikelihoodConfig(Section):
    """Likelihoods: sigma (AE cosine -> importance weight width), l_from_cos (L_FROM_COS),
    depth margins (m), the scores of a hypothesis without depth data and refine_neighbours,
    the grid entries of each weighing's orientation search (0 = off; see
    chpf.tracking.bundle_likelihood)."""

    sigma: float = setting(0.1, gt=0.0)
    l_from_cos: LFromCos = "clip"
    depth_margin: float = setting(0.03, ge=0.0)
    c_depth_margin: float = setting(0.02, ge=0.0)
    depth_no_data: float = setting(0.5, ge=0.0, le=1.0)
    refine_neighbours: int = setting(12, ge=0)


@dataclass
class RuntimeConfig(Section):
    """threads: onnxruntime intra-op threads; spin: its idle threads busy-wait (starves the
    filter's numpy); library_threads: OpenCV and BLAS threads; crop_size: expected bundle
    crop size (None = any); precision: the encoders' (chpf.bundle.PRECISIONS; int8 needs a
    bundle made by chpf-quantize); device: where the networks run (chpf.providers.DEVICES)."""

    threads: int = setting(2, ge=1)
    spin: bool = False
    library_threads: int = setting(1, ge=1)
    crop_size: int | None = None
    precision: Literal["float32", "int8"] = "float32"
    device: Literal["auto", "cpu", "cuda"] = "auto"


@dataclass
class TrackCore(Section):
    """The sections every method uses."""

    filter: FilterConfig = field(default_factory=FilterConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    candidates: CandidatesConfig = field(default_factory=CandidatesConfig)
    likelihood: LikelihoodConfig = field(default_factory=LikelihoodConfig)
    runtime: RuntimeConfig = field(default_factory=RuntimeConfig)
    search: SearchConfig = field(default_factory=SearchConfig)


def _method_sections() -> list[tuple[str, type, Any]]:
    """One (section, options class, field) per registered method with options."""
    seen: dict[str, type] = {}
    for m in METHODS.values():
        if m.options is not None:
            seen.setdefault(m.section, m.options)
    return [(name, cls, field(default_factory=cls)) for name, cls in seen.items()]


TrackConfig = dataclasses.make_dataclass(
    "TrackConfig",
    _method_sections(),
    bases=(TrackCore,),
    namespace={"__doc__": "All tracking options: core sections + one per method with options."},
)
TrackConfig.__module__ = __name__


def _flat_keys() -> dict[str, str]:
    """Keys of the former flat TrackConfig (e.g. srl_beta) -> their new dotted names."""
    prefixes = {"candidates": "candidate_", "annealing": "anneal_", "poserbpf": "rbpf_"}
    flat: dict[str, str] = {}
    for name, options in typing.get_type_hints(TrackConfig).items():
        core = name in TrackCore.__annotations__ or name == "chpf"
        prefix = prefixes.get(name, "" if core else f"{name}_")
        for g in dataclasses.fields(options):
            flat.setdefault(prefix + g.name, f"{name}.{g.name}")
            if name == "candidates":
                flat.setdefault(g.name, f"{name}.{g.name}")
    return flat


_FLAT_KEYS = _flat_keys()


def _refuse_flat_keys(data: Any, where: str) -> None:
    """ConfigError with the new name when ``data`` holds a key of the former flat form."""
    if not isinstance(data, Mapping):
        return
    for key, value in data.items():
        if not isinstance(value, Mapping) and key in _FLAT_KEYS:
            new = _FLAT_KEYS[key]
            raise ConfigError(f"{where}: {key} is now {new} (a key of section {new.split('.')[0]})")


def make_config(
    source: str | Path | Mapping[str, Any] | Any | None = None,
    sets: Iterable[str] = (),
    **sections: Mapping[str, Any],
) -> Any:
    """TrackConfig from a YAML file, a nested dict or a TrackConfig, then ``sections``
    (``srl={"beta": 0.5}``) and ``sets`` (``"srl.beta=0.5"``); checked (ConfigError)."""
    base, data, where = None, None, "tracking config"
    if isinstance(source, TrackConfig):
        base = source
    elif isinstance(source, (str, Path)):
        data, where = read_yaml(source), str(source)
    elif isinstance(source, Mapping):
        data = source
    elif source is not None:
        raise ConfigError(
            "tracking config: expected a TrackConfig, a dict of sections or a YAML file, got "
            f"{type(source).__name__}"
        )
    _refuse_flat_keys(data, where)
    _refuse_flat_keys(sections, "options")
    cfg = load(TrackConfig, data=data, base=base, where=where)
    return load(TrackConfig, data=sections, sets=sets, base=cfg, where="options")
