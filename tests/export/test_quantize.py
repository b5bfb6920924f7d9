"""chpf-quantize on a copy of the shipped bundle with the shipped demo's crops: int8 encoders
that agree with float32, recorded in the manifest and loaded by precision; refusals."""

from __future__ import annotations

import json
import shutil
import stat

import numpy as np
import pytest

from chpf.bundle import Bundle
from chpf.errors import BundleError, ConfigError
from chpf.tracking.demo import demo_dataset, shipped_bundle
from chpf.tracking.tracker import Tracker
from export.quantize import _embed, calibration_crops, quantize_bundle
from export.quantize_cli import main


@pytest.fixture(scope="module")
def crops():
    bundle = Bundle.load(shipped_bundle())
    return calibration_crops(demo_dataset(bundle), bundle, 128)


@pytest.fixture
def copy(tmp_path):
    out = tmp_path / "box"
    shutil.copytree(shipped_bundle(), out)
    for extra in out.glob("*.int8.onnx"):  # the shipped bundle may carry int8 files already
        extra.unlink()
    manifest = json.loads((out / "manifest.json").read_text())
    for name in manifest.get("precisions", {}).get("int8", {}).get("files", {}).values():
        manifest["sha256"].pop(name, None)
    manifest.pop("precisions", None)
    (out / "manifest.json").write_text(json.dumps(manifest))
    return out


def test_calibration_crops_show_the_object_near_its_true_place(crops):
    assert crops.shape == (128, 64, 64, 3) and crops.dtype == np.uint8
    assert crops.std() > 20  # real image content, not blank crops


def test_int8_encoders_agree_with_float32_and_load_by_precision(copy, crops):
    with pytest.raises(BundleError, match=r"no int8 encoders.*chpf-quantize --bundle"):
        Bundle.load(copy, precision="int8")
    report = quantize_bundle(copy, crops, source="demo")
    assert set(report.files) == {"ae_encoder", "ch_obs_encoder"}
    assert min(report.min_cosine.values()) >= 0.99 and report.crops == (64, 64)
    manifest = json.loads((copy / "manifest.json").read_text())
    entry = manifest["precisions"]["int8"]
    assert entry["files"] == report.files and entry["calibration"]["source"] == "demo"
    for name in report.files.values():
        path = copy / name
        assert (
            manifest["sha256"][name]
            and path.stat().st_size < 0.4 * (copy / "ae_encoder.onnx").stat().st_size
        )
        assert path.stat().st_mode & stat.S_IRGRP  # the umask's mode, not mkstemp's 0600
    f32, i8 = Bundle.load(copy), Bundle.load(copy, precision="int8")
    assert (f32.precision, i8.precision) == ("float32", "int8")
    e32, e8 = f32.embed(crops[:16]), i8.embed(crops[:16])
    assert np.all(np.sum(e32 * e8, axis=1) > 0.99) and not np.array_equal(e32, e8)
    tracker = Tracker.from_bundle(f32, config={"runtime": {"precision": "int8"}})
    assert tracker.bundle.precision == "int8"
    with pytest.raises(ConfigError, match="unknown precision"):
        Bundle.load(copy, precision="int4")


def test_disagreement_writes_nothing(copy, crops):
    before = sorted(p.name for p in copy.iterdir())
    manifest = (copy / "manifest.json").read_bytes()
    with pytest.raises(BundleError, match=r"agree with float32 down to cosine .* nothing written"):
        quantize_bundle(copy, crops, min_cosine=1.0)
    assert sorted(p.name for p in copy.iterdir()) == before
    assert (copy / "manifest.json").read_bytes() == manifest


def test_obj_id_maps_the_bundle_onto_the_datasets_id(copy, tmp_path, capsys):
    """A dataset that names the object by another obj_id: refused with the hint, then used
    with --obj-id."""
    bundle = Bundle.load(copy)
    data = tmp_path / "seq"
    shutil.copytree(demo_dataset(bundle), data)
    own, other = bundle.obj_info.obj_id, bundle.obj_info.obj_id + 40
    for gt_file in data.glob("test/*/scene_gt.json"):
        gt = json.loads(gt_file.read_text())
        for poses in gt.values():
            for p in poses:
                p["obj_id"] = other if p["obj_id"] == own else p["obj_id"]
        gt_file.write_text(json.dumps(gt))
    args = ["--bundle", str(copy), "--dataset", str(data), "--crops", "64"]
    with pytest.raises(BundleError, match=f"obj_id {own} .*--obj-id N names the dataset's"):
        main(args)
    assert main([*args, "--obj-id", str(other)]) == 0
    assert "calibrated on 32 crops" in capsys.readouterr().out


def test_cli_uses_the_demo_crops_for_the_shipped_object(copy, capsys):
    assert main(["--bundle", str(copy), "--crops", "64"]) == 0
    out = capsys.readouterr().out
    assert "ae_encoder.int8.onnx" in out and "runtime.precision=int8" in out
    assert Bundle.load(copy, precision="int8").precision == "int8"


def test_shipped_int8_encoders_agree_with_float32_on_this_cpu(crops) -> None:
    """The shipped box's int8 encoders (7-bit weights) agree with its float32 ones on the demo's
    check crops on the CPU at hand: with 8-bit weights, CPUs without VNNI overflowed
    onnxruntime's u8s8 sums (AVX2-only AMD EPYC: lowest cosine 0.833, README)."""
    root = shipped_bundle("box")
    manifest = Bundle.load(root).manifest
    int8_files = manifest["precisions"]["int8"]["files"]  # key -> the int8 file, as loaded
    assert set(int8_files) == {"ae_encoder", "ch_obs_encoder"}
    held = crops[len(crops) // 2 :]
    for key, i8 in int8_files.items():
        f32 = manifest["files"][key]
        cos = np.sum(_embed(root / i8, held, 2) * _embed(root / f32, held, 2), axis=1)
        assert cos.min() >= 0.99, (i8, cos.min())
