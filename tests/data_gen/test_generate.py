"""pairs / ae commands: shards + manifest, determinism, resume, sharding, refusal, reader."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from chpf.errors import DatasetError
from chpf.geometry import geodesic_angle
from data_gen import cli
from data_gen.shards import FIELDS, ShardDataset


def _files(d):
    return {p.name: p.read_bytes() for p in sorted(d.iterdir()) if not p.name.startswith(".")}


def _gen(kind, out, make_args, *extra, n=100, seed=7, sets=()):
    argv = [
        kind,
        "--object",
        "mug",
        "--out",
        str(out),
        "--n",
        str(n),
        "--seed",
        str(seed),
        *make_args(*sets),
        *extra,
    ]
    assert cli.main(argv) == 0


@pytest.fixture(scope="module")
def pairs_ref(tmp_path_factory, make_args):
    out = tmp_path_factory.mktemp("pairs") / "ref"
    _gen("pairs", out, make_args)
    return out


def test_pairs_shards_and_manifest(pairs_ref):
    man = json.loads((pairs_ref / "manifest.json").read_text())
    for key in (
        "kind",
        "format_version",
        "object",
        "object_fingerprint",
        "crop",
        "seed",
        "config",
        "samples_per_shard",
        "num_samples",
        "shards",
    ):
        assert key in man
    assert man["kind"] == "pairs" and man["num_samples"] == 100 and man["seed"] == 7
    assert [s["n"] for s in man["shards"]] == [40, 40, 20]
    assert man["crop"]["size"] == 32
    ds = ShardDataset(pairs_ref)
    assert len(ds) == 100 and ds.num_shards == 3
    for i in range(3):
        arrays = ds.load_shard(i)
        for k, (dt, shp) in FIELDS["pairs"].items():
            assert arrays[k].dtype == dt and arrays[k].shape[1:] == shp(32)
        assert arrays["aligned"].mean() == pytest.approx(0.5, abs=0.05)
    s = ds[57]
    assert s["obs_rgb"].shape == (32, 32, 3) and s["cand_depth"].dtype == np.float16
    np.testing.assert_array_equal(s["obs_rgb"], ds.load_shard(1)["obs_rgb"][17])
    # candidate depth: metres around D_r where the object is, 0 elsewhere
    d = ds.load_shard(0)["cand_depth"].astype(np.float32)
    D_r = man["crop"]["render_distance"]
    assert np.all((d == 0) | (np.abs(d - D_r) < 0.6 * D_r / 4))


def test_stored_poses_respect_the_labels(pairs_ref):
    man = json.loads((pairs_ref / "manifest.json").read_text())
    ds = ShardDataset(pairs_ref)
    a = {
        k: np.concatenate([ds.load_shard(i)[k] for i in range(ds.num_shards)])
        for k in ("obs_R_allo", "cand_R_allo", "aligned", "angle_deg")
    }
    ang = np.degrees(geodesic_angle(a["obs_R_allo"].astype(float), a["cand_R_allo"].astype(float)))
    pos = a["aligned"] == 1
    bound = man["labels"]["positive_max_angle_deg"]
    assert bound == pytest.approx(10.0 + man["labels"]["codebook_grid_spacing_deg"]["max"])
    assert ang[pos].max() <= bound + 1e-2
    assert ang[~pos].min() >= 20.0 - 1e-2
    np.testing.assert_allclose(ang, a["angle_deg"], atol=0.05)


def test_same_seed_same_bytes_and_resume(pairs_ref, tmp_path, make_args):
    out = tmp_path / "again"
    _gen("pairs", out, make_args)
    assert _files(out) == _files(pairs_ref)
    # interrupted run: last shard missing -> rerun completes it to the same bytes
    (out / "shard_00002.npz").unlink()
    (out / "shard_00000.npz").write_bytes(b"")  # a broken shard is redone too
    _gen("pairs", out, make_args)
    assert _files(out) == _files(pairs_ref)
    # another seed gives other data
    other = tmp_path / "other"
    _gen("pairs", other, make_args, seed=8)
    assert _files(other)["shard_00000.npz"] != _files(pairs_ref)["shard_00000.npz"]


def test_num_shards_split_equals_single_run(pairs_ref, tmp_path, make_args):
    out = tmp_path / "split"
    _gen("pairs", out, make_args, "--shard", "1", "--num-shards", "2")
    assert sorted(p.name for p in out.glob("shard_*")) == ["shard_00001.npz"]
    with pytest.raises(DatasetError):
        ShardDataset(out)
    assert len(ShardDataset(out, allow_partial=True)) == 40
    _gen("pairs", out, make_args, "--shard", "0", "--num-shards", "2")
    assert _files(out) == _files(pairs_ref)


def test_workers_do_not_change_bytes(pairs_ref, tmp_path, make_args):
    out = tmp_path / "workers"
    _gen("pairs", out, make_args, "--workers", "2")
    assert _files(out) == _files(pairs_ref)


def test_refuses_folder_of_another_config(pairs_ref, tmp_path, make_args, monkeypatch, capsys):
    out = tmp_path / "refuse"
    _gen("pairs", out, make_args, n=40)
    before = _files(out)
    argv = [
        "pairs",
        "--object",
        "mug",
        "--out",
        str(out),
        "--n",
        "40",
        "--seed",
        "7",
        *make_args("occlusion.prob=0.9"),
    ]
    monkeypatch.setattr(sys, "argv", ["chpf-gen-data", *argv])
    with pytest.raises(SystemExit) as ex:
        cli.cli()
    err = capsys.readouterr().err
    assert ex.value.code == 2 and err.count("\n") == 1 and "another config" in err
    assert "config.occlusion.prob" in err
    assert _files(out) == before
    assert cli.main([*argv, "--overwrite"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["config"]["occlusion"]["prob"] == 0.9
    # a non-empty foreign folder is refused too
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(DatasetError):
        cli.main(["pairs", "--object", "mug", "--out", str(foreign), "--n", "4", *make_args()])


def test_ae_dataset(tmp_path, make_args):
    out = tmp_path / "ae"
    _gen("ae", out, make_args, n=50, sets=("empty_crops.ae_share=0.2",))
    ds = ShardDataset(out)
    assert ds.kind == "ae" and len(ds) == 50
    a = ds.load_shard(0)
    for k, (dt, shp) in FIELDS["ae"].items():
        assert a[k].dtype == dt and a[k].shape == (40, *shp(32))
    # empty crops (a particle far off the object): textured input, black target, no mask
    empty = a["visib_fract"] == 0
    assert 2 <= empty.sum() <= 16
    assert a["target_rgb"][empty].max() == 0 and not a["target_mask"][empty].any()
    assert a["input_rgb"][empty].std() > 5
    a = {k: v[~empty] for k, v in a.items()}
    assert a["target_mask"].sum((1, 2)).min() > 50
    # the target is clean: black outside its silhouette (anti-aliased, bilinearly re-cut)
    import cv2

    near = np.stack(
        [cv2.dilate(m.astype(np.uint8), np.ones((5, 5), np.uint8)) for m in a["target_mask"]]
    ).astype(bool)
    assert a["target_rgb"][~near].max() == 0
    assert np.all((a["visib_fract"] > 0) & (a["visib_fract"] <= 1))
    # the same pools serve ae: only the sample kind differs
    man = json.loads((out / "manifest.json").read_text())
    assert "pairs" not in man["config"] and man["kind"] == "ae"


def test_mesh_file_object(tmp_path, make_args):
    """Any mesh works as --object (here the built-in can exported in mm)."""
    from chpf.objects import builtin_object

    mesh = builtin_object("can").mesh.copy()
    mesh.apply_scale(1000.0)
    path = tmp_path / "can_mm.ply"
    path.write_bytes(mesh.export(file_type="ply"))
    out = tmp_path / "mesh_pairs"
    assert (
        cli.main(
            [
                "ae",
                "--object",
                str(path),
                "--unit",
                "mm",
                "--out",
                str(out),
                "--n",
                "8",
                *make_args(),
            ]
        )
        == 0
    )
    man = json.loads((out / "manifest.json").read_text())
    assert man["object"] == "can_mm"
    assert man["object_info"]["diameter"] == pytest.approx(builtin_object("can").diameter, rel=1e-3)
    assert len(ShardDataset(out)) == 8


def test_contact_sheet_of_pairs(pairs_ref, tmp_path):
    import cv2

    png = tmp_path / "sheet.png"
    assert cli.main(["contact-sheet", str(pairs_ref), "--out", str(png), "--n", "8"]) == 0
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] > 100 and img.shape[1] > 400


def test_tools_find_the_mesh_a_folder_was_made_from(tmp_path, make_args):
    """Data made from a mesh file records its path and unit: the evaluation codebook is built
    for it without --object (it failed with 'obj_000001_textured: neither a built-in object nor
    a mesh file'); a mesh that has moved is one line naming --object MESH, and --object with
    the moved file (or another object, refused by its fingerprint) decides."""
    import shutil

    import trimesh

    from data_gen.shards import manifest_object
    from training.codebook import render_eval_codebook

    mesh = trimesh.creation.box(extents=(0.08, 0.05, 0.12))
    mesh.visual.vertex_colors = np.tile([200, 60, 30, 255], (len(mesh.vertices), 1))
    path = tmp_path / "meshes" / "obj_000001_textured.ply"
    path.parent.mkdir()
    mesh.export(path)
    out = tmp_path / "ae"
    assert cli.main(["ae", "--object", str(path), "--out", str(out), "--n", "8",
                     *make_args()]) == 0  # fmt: skip
    man = json.loads((out / "manifest.json").read_text())
    assert man["object_source"] == {"path": str(path.resolve()), "unit": "m"}
    obj = manifest_object(out)
    assert obj.source == str(path.resolve()) and obj.obj_id == 1
    cb = render_eval_codebook(out, 16, progress=False)
    assert cb["rotations"].shape[0] == 16
    moved = tmp_path / "elsewhere.ply"
    shutil.move(path, moved)
    with pytest.raises(DatasetError, match=r"manifest.json: made from the mesh .* pass --object"):
        manifest_object(out)
    assert manifest_object(out, str(moved)).source == str(moved.resolve())
    with pytest.raises(DatasetError, match=r"fingerprints differ.*--object MESH"):
        manifest_object(out, "mug")
