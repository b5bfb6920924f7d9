"""``chpf-track --demo [--object box|mug]``: a short occluded sequence of a shipped bundle's
object, tracked by CH-PF, CH-RBPF and two baselines (SRL, PoseRBPF) with the default config.

Each sequence is a shipped asset (``chpf/assets/demo/NAME``, a BOP root of RGB frames, ground
truth, simulated detections and the target's model), so the demo needs neither rendering nor
the data generator and gives the same table on every machine. Each was made by
``chpf-gen-data sequences --objects NAME --num-scenes 1 --frames 60 --occlusion partial --seed
0 --width 320 --height 240 --set sequences.focal=300 --set sequences.default_distractors=1``
(its ``sequences_info.json`` records every setting), keeping the RGB frames, the JSON files and
the target's model. ``--seed`` seeds the filters only.
"""

from __future__ import annotations

from pathlib import Path

from chpf.bop import SEQUENCES_INFO, recorded_target_obj_id
from chpf.bundle import Bundle
from chpf.errors import BundleError

DEMO_METHODS = ("chpf", "chrbpf", "srl", "poserbpf")
ASSETS = Path(__file__).resolve().parent.parent / "assets"


def bundles_dir() -> Path:
    """Folder of the bundles shipped with the package (chpf/assets/bundles)."""
    return ASSETS / "bundles"


def shipped_bundles() -> dict[str, Path]:
    """Name -> folder of every shipped bundle (a folder with a manifest.json), sorted."""
    root = bundles_dir()
    found = sorted(p.parent for p in root.glob("*/manifest.json")) if root.is_dir() else []
    return {p.name: p for p in found}


def shipped_bundle(name: str | None = None) -> Path:
    """The shipped bundle ``name`` (e.g. 'mug'), or the first one (the box) without a name;
    BundleError in one line if there is none of that name."""
    found = shipped_bundles()
    if not found:
        raise BundleError(f"{bundles_dir()}: no shipped model bundle; pass --bundle BUNDLE_DIR")
    if name is None:
        return next(iter(found.values()))
    if name not in found:
        raise BundleError(
            f"no shipped bundle for {name!r} (shipped: {', '.join(found)}); pass --bundle "
            "BUNDLE_DIR"
        )
    return found[name]


def demo_dataset(bundle: Bundle) -> Path:
    """BOP root of the shipped demo sequence; BundleError if the bundle is for another object."""
    root = ASSETS / "demo"
    found = {p.parent.name: p.parent for p in root.glob(f"*/{SEQUENCES_INFO}")}
    name = bundle.obj_info.name
    if name not in found:
        raise BundleError(
            f"{bundle.path}: the shipped demo sequences show {', '.join(sorted(found))}, this "
            f"bundle is for {name!r}; run chpf-track --dataset on your own data instead"
        )
    target_id = recorded_target_obj_id(found[name])
    if target_id != bundle.obj_info.obj_id:
        raise BundleError(
            f"{bundle.path}: bundle has obj_id {bundle.obj_info.obj_id}, the demo sequence's "
            f"{name} has obj_id {target_id}"
        )
    return found[name]
