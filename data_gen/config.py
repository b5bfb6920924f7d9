"""Generator configuration: defaults, YAML loading and validation.

A config is a two-level dict ``{section: {key: value}}``. ``configs/gen_default.yaml`` documents
every key; a user YAML may set any subset. Unknown sections/keys, wrong types and out-of-range
values raise ``ConfigError`` with one line naming the file and the key.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from chpf.detections import SIMULATED_DETECTOR_DEFAULTS as _DET
from chpf.errors import ConfigError

Check = Callable[[Any, str], Any]  # (value, "file: section.key") -> normalised value


def _num(lo: float | None = None, hi: float | None = None, integer: bool = False) -> Check:
    """A number in [lo, hi] (ints accepted for floats)."""

    def check(v: Any, where: str) -> Any:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {v!r}")
        if integer and (not isinstance(v, int) and not float(v).is_integer()):
            raise ConfigError(f"{where}: expected an integer, got {v!r}")
        if not math.isfinite(float(v)):
            raise ConfigError(f"{where}: expected a finite number, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise ConfigError(f"{where}: {v!r} is out of range [{lo}, {hi}]")
        return int(v) if integer else float(v)

    return check


def _range(lo: float | None = None, hi: float | None = None) -> Check:
    """A pair [a, b] of numbers with lo <= a <= b <= hi."""
    one = _num(lo, hi)

    def check(v: Any, where: str) -> Any:
        if not isinstance(v, (list, tuple)) or len(v) != 2:
            raise ConfigError(f"{where}: expected a pair [min, max], got {v!r}")
        a, b = one(v[0], where), one(v[1], where)
        if a > b:
            raise ConfigError(f"{where}: min {a} > max {b}")
        return [a, b]

    return check


def _bool(v: Any, where: str) -> bool:
    if not isinstance(v, bool):
        raise ConfigError(f"{where}: expected true or false, got {v!r}")
    return v


def _opt_str(v: Any, where: str) -> str | None:
    if v is not None and not isinstance(v, str):
        raise ConfigError(f"{where}: expected a path string or null, got {v!r}")
    return v


def _choice(*options: str) -> Check:
    def check(v: Any, where: str) -> str:
        if v not in options:
            raise ConfigError(f"{where}: expected one of {', '.join(options)}, got {v!r}")
        return v

    return check


def _str_list(v: Any, where: str) -> list[str]:
    if not isinstance(v, (list, tuple)) or not all(isinstance(s, str) for s in v):
        raise ConfigError(f"{where}: expected a list of names, got {v!r}")
    return list(v)


# (default, check) per key. Keep in sync with configs/gen_default.yaml (a test checks it).
SCHEMA: dict[str, dict[str, tuple[Any, Check]]] = {
    "crop": {"size": (64, _num(16, 512, integer=True))},
    "codebook": {"size": (4096, _num(8, 200000, integer=True))},
    "obs_pool": {
        "num_entries": (2000, _num(1, 1000000, integer=True)),
        "margin": (1.5, _num(1.0, 3.0)),
        "image_width": (640, _num(32, 8192, integer=True)),
        "image_height": (480, _num(32, 8192, integer=True)),
        "focal_range": ([500.0, 1100.0], _range(10.0, 20000.0)),
        "z_range": ([0.4, 1.5], _range(0.01, 100.0)),
        "min_z_diameters": (2.0, _num(0.8, 100.0)),
        "lights_per_entry": (1, _num(1, 8, integer=True)),
        "light_intensity_range": ([1.5, 6.0], _range(0.0, 100.0)),
        "ambient_range": ([0.15, 0.6], _range(0.0, 1.0)),
        "seed": (0, _num(0, 2**31 - 1, integer=True)),
    },
    "occluder_pool": {
        "objects": (["mug", "box", "can", "drill"], _str_list),
        "num_entries": (300, _num(1, 100000, integer=True)),
        "seed": (0, _num(0, 2**31 - 1, integer=True)),
    },
    "background": {
        "image_dir": (None, _opt_str),
        "image_share": (0.5, _num(0.0, 1.0)),
        "max_images": (500, _num(1, 100000, integer=True)),
        "num_textures": (64, _num(1, 10000, integer=True)),
        "texture_size": (256, _num(32, 2048, integer=True)),
        "plain_share": (0.05, _num(0.0, 1.0)),
        "clutter_max": (2, _num(0, 10, integer=True)),
        "seed": (0, _num(0, 2**31 - 1, integer=True)),
    },
    "occlusion": {
        "prob": (0.5, _num(0.0, 1.0)),
        "fraction_range": ([0.05, 0.7], _range(0.0, 0.95)),
        "object_share": (0.5, _num(0.0, 1.0)),
        "scale_range": ([0.5, 1.2], _range(0.1, 5.0)),
    },
    "color": {
        "prob": (0.8, _num(0.0, 1.0)),
        "brightness": (0.25, _num(0.0, 1.0)),
        "contrast": (0.3, _num(0.0, 1.0)),
        "saturation": (0.3, _num(0.0, 1.0)),
        "channel_gain": (0.1, _num(0.0, 1.0)),
    },
    "noise": {
        "prob": (0.5, _num(0.0, 1.0)),
        "sigma_max": (8.0, _num(0.0, 64.0)),
    },
    "blur": {
        "prob": (0.3, _num(0.0, 1.0)),
        "sigma_max": (1.2, _num(0.0, 10.0)),
    },
    "crop_jitter": {
        "xy_sigma": (0.04, _num(0.0, 1.0)),
        "z_sigma": (0.05, _num(0.0, 0.5)),
        "ae_target": ("follow", _choice("follow", "centred")),
    },
    "empty_crops": {
        "ae_share": (0.08, _num(0.0, 1.0)),
        "pairs_negative_share": (0.15, _num(0.0, 1.0)),
        "plain_share": (0.5, _num(0.0, 1.0)),
    },
    "pairs": {
        "positive_share": (0.5, _num(0.0, 1.0)),
        "pos_rot_sigma_deg": (5.0, _num(0.0, 90.0)),
        "pos_rot_max_deg": (10.0, _num(0.0, 180.0)),
        "neg_min_angle_deg": (20.0, _num(0.0, 170.0)),
        "hard_negative_share": (0.3, _num(0.0, 1.0)),
        "hard_negative_range_deg": ([20.0, 45.0], _range(0.0, 180.0)),
        "flip_negative_share": (0.2, _num(0.0, 1.0)),
    },
    "shards": {"samples_per_shard": (1000, _num(1, 10000000, integer=True))},
    "depth": {
        "noise_sigma": (0.001, _num(0.0, 0.1)),
        "noise_sigma_quadratic": (0.0015, _num(0.0, 0.1)),
        "hole_prob": (0.002, _num(0.0, 1.0)),
        "hole_size_range": ([1.0, 6.0], _range(0.0, 100.0)),
        "edge_dropout": (0.3, _num(0.0, 1.0)),
    },
    "sequences": {
        "num_scenes": (2, _num(1, 10000, integer=True)),
        "frames": (60, _num(1, 100000, integer=True)),
        "occlusion": ("partial", _choice("none", "partial", "heavy")),
        "width": (640, _num(32, 8192, integer=True)),
        "height": (480, _num(32, 8192, integer=True)),
        "focal": (600.0, _num(10.0, 20000.0)),
        "z_range": ([0.6, 1.1], _range(0.05, 100.0)),
        "target_speed": (0.08, _num(0.0, 10.0)),
        "target_rot_speed_deg": (40.0, _num(0.0, 720.0)),
        "camera_motion": (0.05, _num(0.0, 10.0)),
        "default_distractors": (2, _num(0, 3, integer=True)),
        "occluder_passes": (1, _num(0, 100, integer=True)),
        "depth_scale": (0.1, _num(0.001, 100.0)),
        "depth_noise": (True, _bool),
        "light_intensity": (3.0, _num(0.0, 100.0)),
        "ambient": (0.35, _num(0.0, 1.0)),
        "rgb_ext": ("png", _choice("png", "jpg")),
    },
    "detector": {
        "center_noise": (_DET["center_noise"], _num(0.0, 1.0)),
        "size_noise": (_DET["size_noise"], _num(0.0, 1.0)),
        "miss_prob": (_DET["miss_prob"], _num(0.0, 1.0)),
        "min_visib_fract": (_DET["min_visib_fract"], _num(0.0, 1.0)),
        "score_range": (list(_DET["score_range"]), _range(0.0, 1.0)),
    },
}

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
    """A fresh copy of the default config."""
    return {s: {k: copy.deepcopy(d) for k, (d, _) in keys.items()} for s, keys in SCHEMA.items()}


def merge_config(
    base: dict[str, dict[str, Any]], override: Any, source: str = "config"
) -> dict[str, dict[str, Any]]:
    """Validated copy of ``base`` updated with ``override`` ({section: {key: value}})."""
    if override is None:
        return copy.deepcopy(base)
    if not isinstance(override, dict):
        raise ConfigError(
            f"{source}: expected a mapping of sections, got {type(override).__name__}"
        )
    out = copy.deepcopy(base)
    for section, keys in override.items():
        if section not in SCHEMA:
            raise ConfigError(f"{source}: unknown section {section!r} (known: {', '.join(SCHEMA)})")
        if keys is None:
            continue
        if not isinstance(keys, dict):
            raise ConfigError(f"{source}: section {section!r} must be a mapping")
        for key, value in keys.items():
            if key not in SCHEMA[section]:
                raise ConfigError(
                    f"{source}: unknown key {section}.{key} (known: {', '.join(SCHEMA[section])})"
                )
            out[section][key] = SCHEMA[section][key][1](value, f"{source}: {section}.{key}")
    return out


def load_config(path: str | Path | None = None, sets: list[str] | None = None) -> dict:
    """Defaults, updated by the YAML file ``path`` and then by ``sets`` ("section.key=value")."""
    cfg = default_config()
    if path is not None:
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as err:
            raise ConfigError(f"{p}: cannot read config ({err.strerror})") from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as err:
            line = getattr(getattr(err, "problem_mark", None), "line", None)
            at = f" at line {line + 1}" if line is not None else ""
            raise ConfigError(f"{p}: not valid YAML{at}") from None
        cfg = merge_config(cfg, data, str(p))
    for item in sets or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise ConfigError(f"--set {item!r}: expected section.key=value")
        dotted, raw = item.split("=", 1)
        section, key = dotted.split(".", 1)
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"--set {item!r}: value is not valid YAML") from None
        cfg = merge_config(cfg, {section: {key: value}}, "--set")
    source = " + ".join(([str(path)] if path is not None else []) + (["--set"] if sets else []))
    check_consistency(cfg, source or "config")
    return cfg


def check_consistency(cfg: dict, source: str = "config") -> None:
    """Cross-key rules that single-key checks cannot see (``source`` names the config)."""
    p = cfg["pairs"]
    if p["pos_rot_max_deg"] >= p["neg_min_angle_deg"] and p["positive_share"] < 1.0:
        raise ConfigError(
            f"{source}: pairs.pos_rot_max_deg ({p['pos_rot_max_deg']}) must be below "
            f"pairs.neg_min_angle_deg ({p['neg_min_angle_deg']})"
        )
    lo, hi = p["hard_negative_range_deg"]
    if p["hard_negative_share"] > 0 and hi < p["neg_min_angle_deg"]:
        raise ConfigError(
            f"{source}: pairs.hard_negative_range_deg lies below pairs.neg_min_angle_deg"
        )
    if p["hard_negative_share"] + p["flip_negative_share"] > 1.0:
        raise ConfigError(
            f"{source}: pairs.hard_negative_share + pairs.flip_negative_share must be <= 1"
        )
    if lo < p["neg_min_angle_deg"] and p["hard_negative_share"] > 0:
        raise ConfigError(
            f"{source}: pairs.hard_negative_range_deg starts at {lo}, below "
            f"pairs.neg_min_angle_deg ({p['neg_min_angle_deg']})"
        )


def sections(cfg: dict, names: tuple[str, ...]) -> dict:
    """The sub-config of the given sections (what a manifest records)."""
    return {s: copy.deepcopy(cfg[s]) for s in names}
