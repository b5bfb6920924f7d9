"""Tracking options: one flat dataclass, loadable from YAML (configs/track_*.yaml).

Unknown keys and out-of-range values raise ConfigError naming the key (and the file).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from chpf.errors import ConfigError

METHODS = ("chpf", "srl", "augmcl", "annealing", "e2e", "poserbpf", "poserbpf++", "fixed", "none")
"""Tracking methods: the 6D filters (one reinvigoration strategy each) and the RBPFs."""
PAPER_METHODS = ("chpf", "srl", "augmcl", "annealing", "e2e", "poserbpf", "poserbpf++")
"""The methods compared in the paper (``--method all``)."""
MODALITIES = ("rgb", "rgbd")
C_MODES = ("learned", "depth", "both", "none")
"""Where C comes from: the learned classifier, C_depth, their mean, or nowhere (C = None)."""
L_FROM_COS = ("clip", "affine")
"""How the cosine c in [-1, 1] becomes the unnormalised likelihood L in [0, 1] that SRL, Aug.
MCL and CH-PF sum: "clip" L = max(c, 0); "affine" L = (1 + c) / 2. With the trained encoders,
whose embeddings of unrelated views are near orthogonal (c ~ 0), "clip" gives the candidates
drawn blindly from phi_cand L ~ 0 next to C ~ 1, which holds CH-PF's alpha near 1 even on a
correct belief; "affine" keeps the baseline that an Augmented Autoencoder's cosine has."""


@dataclass
class TrackConfig:
    """All tracking options (lengths in metres, angles in radians)."""

    n_particles: int = 50
    # motion model: random walk per frame
    sigma_t: float = 0.01
    sigma_r: float = 0.08
    # candidate distribution phi_cand
    z_range: tuple[float, float] = (0.3, 2.0)  # RGB z range when the box scale is not used
    z_from_box: bool = True  # RGB: z range from the box size and the object's extent
    z_box_factors: tuple[float, float] = (0.8, 1.25)
    box_uv_fraction: float = 1.0  # (u, v) uniform in this central fraction of the box's sides
    candidate_rotations: str = "uniform"  # uniform | codebook (matching the box's crop)
    candidate_temperature: float = 0.05  # codebook: p(entry) ~ exp((cos - max cos) / this)
    candidate_uniform_share: float = 0.25  # codebook: share still drawn uniformly
    depth_offset: tuple[float, float] | None = None  # RGB-D: z = measured + U(a, b); None =
    # (0, diameter / 2)
    depth_window: int = 3
    # likelihoods
    sigma: float = 0.3  # AE cosine -> importance weight width
    l_from_cos: str = "clip"  # unnormalised likelihood L from the cosine: clip | affine
    c_mode: str = "learned"  # learned | depth | both | none
    depth_margin: float = 0.03
    c_depth_margin: float = 0.02
    depth_no_data: float = 0.5
    # strategies
    srl_beta: float = 0.6
    augmcl_a_slow: float = 0.001
    augmcl_a_fast: float = 0.1
    anneal_betas: tuple[float, ...] = (0.2, 0.5, 1.0)
    anneal_decay: float = 0.5
    e2e_rate: float = 0.2
    e2e_sigma_t: tuple[float, float, float] = (0.01, 0.01, 0.03)
    e2e_sigma_r: float = 0.15
    fixed_rate: float = 0.1
    # Rao-Blackwellised filters
    rbpf_sigma: float = 0.1
    rbpf_neighbours: int = 12
    rbpf_rotation_sigma: float | None = None  # None = the codebook grid spacing
    rbpf_reset_threshold: float = 0.4
    rbpf_plus_fraction: float = 0.5
    rbpf_rotation_estimate: str = "argmax"
    # runtime
    threads: int = 2  # onnxruntime intra-op threads
    spin: bool = False  # onnxruntime idle threads busy-wait (True starves the filter's numpy)
    library_threads: int = 1  # OpenCV and BLAS threads (their idle workers slow onnxruntime)
    crop_size: int | None = None  # expected bundle crop size (None = any)

    def check(self, where: str = "tracking config") -> TrackConfig:
        """Validate ranges; returns self. ConfigError names the key."""

        def bad(key: str, why: str) -> ConfigError:
            return ConfigError(f"{where}: {key} {why} (got {getattr(self, key)!r})")

        lengths = {"z_range": 2, "z_box_factors": 2, "depth_offset": 2, "e2e_sigma_t": 3}
        for key, n in lengths.items():
            value = getattr(self, key)
            if value is not None and len(value) != n:
                raise bad(key, f"must have {n} values")
        if not self.anneal_betas:
            raise bad("anneal_betas", "must not be empty")
        if self.n_particles < 1:
            raise bad("n_particles", "must be >= 1")
        for key in ("sigma_t", "sigma_r", "depth_margin", "c_depth_margin", "e2e_sigma_r"):
            if getattr(self, key) < 0:
                raise bad(key, "must be >= 0")
        for key in ("sigma", "rbpf_sigma", "srl_beta", "candidate_temperature"):
            if getattr(self, key) <= 0:
                raise bad(key, "must be > 0")
        lo, hi = self.z_range
        if not 0 < lo < hi:
            raise bad("z_range", "must be 0 < min < max")
        if not 0 < self.z_box_factors[0] <= self.z_box_factors[1]:
            raise bad("z_box_factors", "must be 0 < min <= max")
        if not 0.0 < self.box_uv_fraction <= 1.0:
            raise bad("box_uv_fraction", "must be in (0, 1]")
        if self.candidate_rotations not in ("uniform", "codebook"):
            raise bad("candidate_rotations", "must be uniform or codebook")
        for key in (
            "e2e_rate",
            "fixed_rate",
            "rbpf_plus_fraction",
            "depth_no_data",
            "candidate_uniform_share",
        ):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise bad(key, "must be in [0, 1]")
        if self.c_mode not in C_MODES:
            raise bad("c_mode", f"must be one of {', '.join(C_MODES)}")
        if self.l_from_cos not in L_FROM_COS:
            raise bad("l_from_cos", f"must be one of {', '.join(L_FROM_COS)}")
        if self.rbpf_rotation_estimate not in ("argmax", "mean"):
            raise bad("rbpf_rotation_estimate", "must be argmax or mean")
        if self.threads < 1:
            raise bad("threads", "must be >= 1")
        if self.library_threads < 1:
            raise bad("library_threads", "must be >= 1")
        return self


_FIELDS = {f.name: f for f in dataclasses.fields(TrackConfig)}


def _coerce(key: str, value: Any, where: str) -> Any:
    """Value of option ``key`` converted to its annotated type; ConfigError if impossible."""
    ann = str(_FIELDS[key].type)
    try:
        if value is None:
            if "None" not in ann:
                raise ValueError
            return None
        if ann.startswith("tuple"):
            return tuple(float(v) for v in value)
        if ann == "bool" or isinstance(value, bool):
            if ann != "bool" or not isinstance(value, bool):
                raise ValueError
            return value
        if ann.startswith("int"):
            if int(value) != value:
                raise ValueError
            return int(value)
        if ann.startswith("float"):
            return float(value)
        if not isinstance(value, str):
            raise ValueError
        return value
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: {key} has an invalid value {value!r}") from None


def make_config(
    source: str | Path | dict[str, Any] | TrackConfig | None = None, **overrides: Any
) -> TrackConfig:
    """TrackConfig from a YAML file, a dict or a TrackConfig, then keyword overrides; checked."""
    where = "tracking config"
    values: dict[str, Any] = {}
    if isinstance(source, TrackConfig):
        values = {k: getattr(source, k) for k in _FIELDS}
    elif isinstance(source, (str, Path)):
        path = Path(source)
        where = str(path)
        try:
            loaded = yaml.safe_load(path.read_text(encoding="utf-8"))
        except OSError as err:
            raise ConfigError(f"{path}: cannot read config ({err.strerror})") from None
        except yaml.YAMLError as err:
            raise ConfigError(f"{path}: invalid YAML ({str(err).splitlines()[0]})") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"{path}: expected a mapping of options")
        values = dict(loaded)
    elif isinstance(source, dict):
        values = dict(source)
    elif source is not None:
        raise ConfigError(f"tracking config: unsupported source {type(source).__name__}")
    values.update({k: v for k, v in overrides.items() if v is not None})
    unknown = sorted(set(values) - set(_FIELDS))
    if unknown:
        raise ConfigError(f"{where}: unknown option(s) {unknown}")
    cfg = TrackConfig(**{k: _coerce(k, v, where) for k, v in values.items()})
    return cfg.check(where)
