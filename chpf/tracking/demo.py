"""``chpf-track --demo``: a short occluded sequence of the shipped bundle's object, tracked by
CH-PF and two baselines.

The sequence is generated once with ``data_gen.sequences`` (BOP layout, simulated detector)
into a cache folder (``$CHPF_CACHE`` or ``~/.cache/chpf``) keyed by the object's fingerprint
and the seed, and reused on later runs.
"""

from __future__ import annotations

import os
from pathlib import Path

from chpf.bundle import Bundle
from chpf.errors import BundleError

DEMO_METHODS = ("chpf", "srl", "poserbpf")
DEMO_SEQUENCE = {
    "num_scenes": 1,
    "frames": 60,
    "occlusion": "partial",
    "width": 320,
    "height": 240,
    "focal": 300.0,
    "default_distractors": 1,
}


def bundles_dir() -> Path:
    """Folder of the bundles shipped with the package (chpf/assets/bundles)."""
    return Path(__file__).resolve().parent.parent / "assets" / "bundles"


def shipped_bundle() -> Path:
    """The first shipped bundle folder (one with a manifest.json); BundleError if none."""
    root = bundles_dir()
    found = sorted(p.parent for p in root.glob("*/manifest.json")) if root.is_dir() else []
    if not found:
        raise BundleError(f"{root}: no shipped model bundle; pass --bundle BUNDLE_DIR")
    return found[0]


def cache_dir() -> Path:
    """Cache root for generated demo data."""
    env = os.environ.get("CHPF_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "chpf"


def demo_dataset(bundle: Bundle, seed: int = 0, frames: int | None = None) -> Path:
    """BOP root of the demo sequence for the bundle's object (generated on first use)."""
    from chpf.objects import BUILTIN_OBJECTS
    from data_gen.config import load_config
    from data_gen.sequences import generate_sequences

    name = bundle.obj_info.name
    if name not in BUILTIN_OBJECTS:
        raise BundleError(
            f"{bundle.path}: the demo generates built-in objects only "
            f"({', '.join(BUILTIN_OBJECTS)}), this bundle is for {name!r}; "
            "run chpf-track --dataset on your own data instead"
        )
    seq = dict(DEMO_SEQUENCE)
    if frames is not None:
        seq["frames"] = int(frames)
    fp = (bundle.obj_info.fingerprint or "nofp")[:12]
    root = cache_dir() / "demo" / f"{name}-{fp}-s{seed}-f{seq['frames']}"
    cfg = load_config(None, [f"sequences.{k}={v}" for k, v in seq.items()])
    # overwrite: a cache made by another version's settings is replaced, a matching one reused
    generate_sequences([name], root, cfg, seed, split="test", overwrite=True, progress=True)
    return root
