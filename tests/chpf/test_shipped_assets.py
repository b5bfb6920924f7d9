"""The shipped bundles (chpf/assets/bundles) and demo sequences (chpf/assets/demo): each bundle
loads, fits the 25 MB a shipped bundle may take, and has a demo sequence of its object."""

from __future__ import annotations

import json

import pytest

from chpf.bop import SEQUENCES_INFO
from chpf.bundle import Bundle
from chpf.tracking.demo import ASSETS, demo_dataset, shipped_bundles

MAX_BUNDLE_BYTES = 25_000_000  # 25 MB


def test_the_box_is_shipped_and_first() -> None:
    names = list(shipped_bundles())
    assert names and names[0] == "box"  # the default of --demo, the bench, the tests


@pytest.mark.parametrize("name", list(shipped_bundles()))
def test_each_shipped_bundle_loads_fits_and_has_its_demo(name: str) -> None:
    path = shipped_bundles()[name]
    size = sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    assert size <= MAX_BUNDLE_BYTES, f"{name}: {size / 1e6:.1f} MB"
    bundle = Bundle.load(path)
    assert bundle.obj_info.name == name
    root = demo_dataset(bundle)  # BundleError if the demo is missing or of another obj_id
    info = json.loads((root / SEQUENCES_INFO).read_text())
    assert info["objects"][0] == {**info["objects"][0], "name": name, "role": "target"}


def test_every_demo_sequence_has_its_frames_and_target_model() -> None:
    for info_path in (ASSETS / "demo").glob(f"*/{SEQUENCES_INFO}"):
        root = info_path.parent
        target = json.loads(info_path.read_text())["objects"][0]
        assert len(list((root / "test" / "000001" / "rgb").glob("*.png"))) == 60
        assert (root / "models" / f"obj_{target['obj_id']:06d}.ply").is_file()
        models = json.loads((root / "models" / "models_info.json").read_text())
        assert list(models) == [str(target["obj_id"])]
