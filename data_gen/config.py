"""Generator configuration: typed sections with their defaults, YAML loading and validation.

``GenConfig`` holds one dataclass per section (the defaults live there and nowhere else;
``configs/gen_default.yaml`` documents every key, a test checks they agree). The generator
reads a config as a two-level dict ``{section: {key: value}}`` (``load_config``). Unknown
sections/keys, wrong types and out-of-range values raise ``ConfigError`` with one line naming
the file and the key (chpf.config_schema).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from chpf.config_schema import Invalid, Section, load, setting, to_dict
from chpf.detections import SIMULATED_DETECTOR_DEFAULTS as _DET

SEED_MAX = 2**31 - 1


@dataclass
class Crop(Section):
    size: int = setting(64, ge=16, le=512)


@dataclass
class Codebook(Section):
    size: int = setting(4096, ge=8, le=200000)


@dataclass
class ObsPool(Section):
    num_entries: int = setting(2000, ge=1, le=1000000)
    margin: float = setting(1.5, ge=1.0, le=3.0)
    image_width: int = setting(640, ge=32, le=8192)
    image_height: int = setting(480, ge=32, le=8192)
    focal_range: tuple[float, float] = setting((500.0, 1100.0), ge=10.0, le=20000.0, ordered=True)
    z_range: tuple[float, float] = setting((0.4, 1.5), ge=0.01, le=100.0, ordered=True)
    min_z_diameters: float = setting(2.0, ge=0.8, le=100.0)
    lights_per_entry: int = setting(1, ge=1, le=8)
    light_intensity_range: tuple[float, float] = setting((1.5, 6.0), ge=0.0, le=100.0, ordered=True)
    ambient_range: tuple[float, float] = setting((0.15, 0.6), ge=0.0, le=1.0, ordered=True)
    seed: int = setting(0, ge=0, le=SEED_MAX)


@dataclass
class OccluderPool(Section):
    objects: list[str] = field(default_factory=lambda: ["mug", "box", "can", "drill"])
    num_entries: int = setting(300, ge=1, le=100000)
    seed: int = setting(0, ge=0, le=SEED_MAX)


@dataclass
class Background(Section):
    image_dir: str | None = None
    image_share: float = setting(0.5, ge=0.0, le=1.0)
    max_images: int = setting(500, ge=1, le=100000)
    num_textures: int = setting(64, ge=1, le=10000)
    texture_size: int = setting(256, ge=32, le=2048)
    plain_share: float = setting(0.05, ge=0.0, le=1.0)
    clutter_max: int = setting(2, ge=0, le=10)
    seed: int = setting(0, ge=0, le=SEED_MAX)


@dataclass
class Occlusion(Section):
    prob: float = setting(0.5, ge=0.0, le=1.0)
    fraction_range: tuple[float, float] = setting((0.05, 0.7), ge=0.0, le=0.95, ordered=True)
    object_share: float = setting(0.5, ge=0.0, le=1.0)
    scale_range: tuple[float, float] = setting((0.5, 1.2), ge=0.1, le=5.0, ordered=True)


@dataclass
class Color(Section):
    prob: float = setting(0.8, ge=0.0, le=1.0)
    brightness: float = setting(0.25, ge=0.0, le=1.0)
    contrast: float = setting(0.3, ge=0.0, le=1.0)
    saturation: float = setting(0.3, ge=0.0, le=1.0)
    channel_gain: float = setting(0.1, ge=0.0, le=1.0)


@dataclass
class Noise(Section):
    prob: float = setting(0.5, ge=0.0, le=1.0)
    sigma_max: float = setting(8.0, ge=0.0, le=64.0)


@dataclass
class Blur(Section):
    prob: float = setting(0.3, ge=0.0, le=1.0)
    sigma_max: float = setting(1.2, ge=0.0, le=10.0)


@dataclass
class CropJitter(Section):
    xy_sigma: float = setting(0.04, ge=0.0, le=1.0)
    z_sigma: float = setting(0.05, ge=0.0, le=0.5)
    ae_target: Literal["follow", "centred"] = "follow"


def shifts_ae_targets(config: Mapping[str, Any]) -> bool:
    """Whether ae samples made with the generator ``config`` (a manifest's ``config``) show the
    object off the crop centre in their targets too: crop jitter with ``ae_target: follow``.
    An autoencoder trained so encodes the shift (a few pixels move its nearest centred view by
    tens of degrees), so such crops cannot measure its orientation retrieval."""
    jit = {**asdict(CropJitter()), **(config.get("crop_jitter") or {})}
    return jit["ae_target"] == "follow" and (jit["xy_sigma"] > 0 or jit["z_sigma"] > 0)


@dataclass
class EmptyCrops(Section):
    ae_share: float = setting(0.08, ge=0.0, le=1.0)
    pairs_negative_share: float = setting(0.15, ge=0.0, le=1.0)
    plain_share: float = setting(0.5, ge=0.0, le=1.0)


CROP_KEYS = ("scale_negative_share", "scale_negative_range")
"""``pairs`` keys that say how the observed crops are cut, not how hypotheses are drawn (a
classifier's extra pairs share the observed crop, so they cannot draw these differently)."""


@dataclass
class Pairs(Section):
    positive_share: float = setting(0.5, ge=0.0, le=1.0)
    pos_rot_sigma_deg: float = setting(5.0, ge=0.0, le=90.0)
    pos_rot_max_deg: float = setting(10.0, ge=0.0, le=180.0)
    neg_min_angle_deg: float = setting(20.0, ge=0.0, le=170.0)
    hard_negative_share: float = setting(0.3, ge=0.0, le=1.0)
    hard_negative_range_deg: tuple[float, float] = setting(
        (20.0, 45.0), ge=0.0, le=180.0, ordered=True
    )
    flip_negative_share: float = setting(0.2, ge=0.0, le=1.0)
    scale_negative_share: float = setting(0.0, ge=0.0, le=1.0)
    scale_negative_range: tuple[float, float] = setting((0.12, 0.4), ge=0.01, le=1.5, ordered=True)

    def check(self) -> None:
        """Cross-key rules that single-key checks cannot see."""
        neg_min = self.neg_min_angle_deg
        if self.pos_rot_max_deg >= neg_min and self.positive_share < 1.0:
            raise Invalid(
                "pos_rot_max_deg",
                f"({self.pos_rot_max_deg}) must be below pairs.neg_min_angle_deg ({neg_min})",
            )
        lo, hi = self.hard_negative_range_deg
        if self.hard_negative_share > 0 and hi < neg_min:
            raise Invalid("hard_negative_range_deg", "lies below pairs.neg_min_angle_deg")
        if self.hard_negative_share + self.flip_negative_share > 1.0:
            raise Invalid("hard_negative_share", "+ pairs.flip_negative_share must be <= 1")
        if lo < neg_min and self.hard_negative_share > 0:
            raise Invalid(
                "hard_negative_range_deg",
                f"starts at {lo}, below pairs.neg_min_angle_deg ({neg_min})",
            )


@dataclass
class Shards(Section):
    samples_per_shard: int = setting(1000, ge=1, le=10000000)


@dataclass
class Depth(Section):
    noise_sigma: float = setting(0.001, ge=0.0, le=0.1)
    noise_sigma_quadratic: float = setting(0.0015, ge=0.0, le=0.1)
    hole_prob: float = setting(0.002, ge=0.0, le=1.0)
    hole_size_range: tuple[float, float] = setting((1.0, 6.0), ge=0.0, le=100.0, ordered=True)
    edge_dropout: float = setting(0.3, ge=0.0, le=1.0)


@dataclass
class Sequences(Section):
    num_scenes: int = setting(2, ge=1, le=10000)
    frames: int = setting(60, ge=1, le=100000)
    occlusion: Literal["none", "partial", "heavy"] = "partial"
    width: int = setting(640, ge=32, le=8192)
    height: int = setting(480, ge=32, le=8192)
    focal: float = setting(600.0, ge=10.0, le=20000.0)
    z_range: tuple[float, float] = setting((0.6, 1.1), ge=0.05, le=100.0, ordered=True)
    target_speed: float = setting(0.08, ge=0.0, le=10.0)
    target_rot_speed_deg: float = setting(40.0, ge=0.0, le=720.0)
    camera_motion: float = setting(0.05, ge=0.0, le=10.0)
    default_distractors: int = setting(2, ge=0, le=3)
    occluder_passes: int = setting(1, ge=0, le=100)
    depth_scale: float = setting(0.1, ge=0.001, le=100.0)
    depth_noise: bool = True
    light_intensity: float = setting(3.0, ge=0.0, le=100.0)
    ambient: float = setting(0.35, ge=0.0, le=1.0)
    rgb_ext: Literal["png", "jpg"] = "png"
    family: Literal["training", "heldout"] = "training"


@dataclass
class Detector(Section):
    center_noise: float = setting(_DET["center_noise"], ge=0.0, le=1.0)
    size_noise: float = setting(_DET["size_noise"], ge=0.0, le=1.0)
    miss_prob: float = setting(_DET["miss_prob"], ge=0.0, le=1.0)
    min_visib_fract: float = setting(_DET["min_visib_fract"], ge=0.0, le=1.0)
    score_range: tuple[float, float] = setting(
        tuple(_DET["score_range"]), ge=0.0, le=1.0, ordered=True
    )


@dataclass
class GenConfig(Section):
    """Every section of chpf-gen-data (the meaning of each key: configs/gen_default.yaml)."""

    crop: Crop = field(default_factory=Crop)
    codebook: Codebook = field(default_factory=Codebook)
    obs_pool: ObsPool = field(default_factory=ObsPool)
    occluder_pool: OccluderPool = field(default_factory=OccluderPool)
    background: Background = field(default_factory=Background)
    occlusion: Occlusion = field(default_factory=Occlusion)
    color: Color = field(default_factory=Color)
    noise: Noise = field(default_factory=Noise)
    blur: Blur = field(default_factory=Blur)
    crop_jitter: CropJitter = field(default_factory=CropJitter)
    empty_crops: EmptyCrops = field(default_factory=EmptyCrops)
    pairs: Pairs = field(default_factory=Pairs)
    shards: Shards = field(default_factory=Shards)
    depth: Depth = field(default_factory=Depth)
    sequences: Sequences = field(default_factory=Sequences)
    detector: Detector = field(default_factory=Detector)


# Sections that shape pairs / ae samples (stored in their manifests; a change forces --overwrite).
SAMPLE_SECTIONS = (
    "crop",
    "codebook",
    "obs_pool",
    "occluder_pool",
    "background",
    "occlusion",
    "color",
    "noise",
    "blur",
    "crop_jitter",
    "empty_crops",
    "shards",
)
PAIRS_SECTIONS = (*SAMPLE_SECTIONS, "pairs")
AE_SECTIONS = SAMPLE_SECTIONS


def default_config() -> dict[str, dict[str, Any]]:
    """A fresh copy of the default config as a two-level dict."""
    return to_dict(GenConfig())


def data_pairs_config(manifest: dict[str, Any]) -> dict[str, Any]:
    """The ``pairs`` section a pairs folder was made with, from its manifest (the defaults for
    keys that its manifest predates)."""
    return default_config()["pairs"] | manifest.get("config", {}).get("pairs", {})


def load_config(path: str | Path | None = None, sets: list[str] | None = None) -> dict:
    """Defaults, updated by the YAML file ``path`` and then by ``sets`` ("section.key=value"),
    as a two-level dict; ConfigError (one line) names the file (or --set) and the key."""
    return to_dict(load(GenConfig, path=path, sets=sets or ()))


def sections(cfg: dict, names: tuple[str, ...]) -> dict:
    """The sub-config of the given sections (what a manifest records)."""
    return {s: copy.deepcopy(cfg[s]) for s in names}
