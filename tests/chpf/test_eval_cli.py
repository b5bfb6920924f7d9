"""End-to-end tests of chpf-eval (chpf.eval_cli) on a tiny BOP dataset with trimesh models."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from chpf import bop
from chpf.bop import BopDataset, CameraInfo, GtPose, ModelInfo, ResultRow
from chpf.errors import DatasetError
from chpf.eval_cli import cli, evaluate, format_table
from chpf.eval_targets import read_targets
from chpf.metrics import auc
from chpf.results import HEADER
from tests.helpers import vocap_reference

K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
OFFSET = np.array([0.05, 0.0, 0.0])


def _pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    R, _ = cv2.Rodrigues(rng.normal(size=3))
    return R, np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(0.6, 1.2)])


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Objects 1 (box) and 2 (cylinder, continuous symmetry); scene 1: 10 images with both,
    image 10 has a second instance of object 1; scene 2: 5 images with object 1 only."""
    root = tmp_path_factory.mktemp("evalds")
    box = trimesh.creation.box(extents=[100.0, 70.0, 40.0])  # millimetres, like BOP models
    cyl = trimesh.creation.cylinder(radius=30.0, height=90.0, sections=24)
    (root / "models").mkdir()
    box.export(root / "models" / "obj_000001.ply")
    cyl.export(root / "models" / "obj_000002.ply")
    bop.write_models_info(
        root / "models" / "models_info.json",
        {
            1: ModelInfo(1, float(np.linalg.norm([0.1, 0.07, 0.04]))),
            2: ModelInfo(
                2,
                float(np.hypot(0.06, 0.09)),
                symmetries_continuous=[{"axis": np.array([0, 0, 1.0]), "offset": np.zeros(3)}],
            ),
        },
    )
    rng = np.random.default_rng(7)
    for scene_id, n_im, objs in ((1, 10, (1, 2)), (2, 5, (1,))):
        sdir = bop.scene_dir(root, "test", scene_id)
        cams = {im: CameraInfo(K.copy(), 0.1) for im in range(1, n_im + 1)}
        gt = {im: [GtPose(o, *_pose(rng)) for o in objs] for im in cams}
        if scene_id == 1:
            gt[10].append(GtPose(1, *_pose(rng)))
        bop.write_scene_camera(sdir / "scene_camera.json", cams)
        bop.write_scene_gt(sdir / "scene_gt.json", gt)
    return root


def _box_corners(scale: float = 1.0) -> np.ndarray:
    """The 8 corners (m) of the 100 x 70 x 40 mm box of object 1."""
    half = scale * np.array([0.05, 0.035, 0.02])
    return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half


def _add_hand(pts: np.ndarray, Re, te, Rg, tg) -> float:
    """ADD by its definition (a plain loop over points)."""
    return float(np.mean([np.linalg.norm((Re @ p + te) - (Rg @ p + tg)) for p in pts]))


def _adds_hand(pts: np.ndarray, Re, te, Rg, tg) -> float:
    """ADD-S by its definition (brute-force nearest estimate-posed point)."""
    est = pts @ Re.T + te
    return float(np.mean([np.min(np.linalg.norm(est - (Rg @ p + tg), axis=1)) for p in pts]))


def _gt_rows(root: Path, obj_id: int = 1, offset: np.ndarray | None = None) -> list[ResultRow]:
    ds = BopDataset(root)
    rows = []
    for sid in ds.scene_ids("test"):
        for im, poses in ds.scene("test", sid).gt.items():
            for p in poses:
                if p.obj_id == obj_id:
                    t = p.t if offset is None else p.t + offset
                    rows.append(ResultRow(sid, im, obj_id, 1.0, p.R, t, 0.02))
    return rows


def test_exact_results_score_100(dataset: Path) -> None:
    rows = _gt_rows(dataset)
    rep = evaluate(dataset, rows, "test")
    assert list(rep["objects"]) == ["1"]  # object 2 has no rows: not scored
    e = rep["objects"]["1"]
    assert e["n"] == 16 and e["n_missing"] == 0  # 15 images + a second instance
    assert e["add_auc"] == pytest.approx(100.0, abs=1e-6)
    assert e["adds_auc"] == pytest.approx(100.0, abs=1e-6)
    assert rep["all"]["n"] == 16 and rep["ignored_rows"] == 0


def test_offset_gives_computed_auc(dataset: Path) -> None:
    rows = _gt_rows(dataset, offset=OFFSET)
    rep = evaluate(dataset, rows, "test")
    e = rep["objects"]["1"]
    # a pure 5 cm translation error: ADD is 0.05 m for every instance
    assert e["add_auc"] == pytest.approx(auc(np.full(16, 0.05)))
    assert 45.0 < e["add_auc"] < 56.0
    # default model points: the box's 8 corner vertices (mm -> m), ADD-S by brute force
    corners = _box_corners()
    gt = _gt_rows(dataset)
    expected_adds = [_adds_hand(corners, r.R, r.t + OFFSET, r.R, r.t) for r in gt]
    assert e["adds_auc"] == pytest.approx(vocap_reference(expected_adds), abs=1e-9)
    assert e["adds_auc"] > e["add_auc"]


def test_missing_frames_and_best_score(dataset: Path) -> None:
    rows = [r for r in _gt_rows(dataset) if r.scene_id == 1]  # scene 2 (5 targets) missing
    bad = ResultRow(1, 1, 1, 0.1, np.eye(3), np.array([0, 0, 3.0]))  # lower score: not used
    stray = ResultRow(1, 1, 2, 0.5, np.eye(3), np.array([0, 0, 1.0]))  # object 2 now scored
    nowhere = ResultRow(2, 99, 1, 0.5, np.eye(3), np.array([0, 0, 1.0]))  # no such image
    rep = evaluate(dataset, [bad, *rows, stray, nowhere], "test")
    e = rep["objects"]["1"]
    assert e["n"] == 16 and e["n_missing"] == 5
    expected = auc(np.array([0.0] * 11 + [np.inf] * 5))
    assert e["add_auc"] == pytest.approx(expected) and e["adds_auc"] == pytest.approx(expected)
    assert e["add_auc"] == pytest.approx(100 * 11 / 16, abs=0.5)
    assert rep["objects"]["2"]["n"] == 10 and rep["objects"]["2"]["n_missing"] == 9
    assert rep["all"]["n"] == 26 and rep["all"]["n_missing"] == 14
    assert rep["ignored_rows"] == 1 and rep["duplicate_rows"] == 1  # `nowhere`; `bad` is surplus
    assert rep["duplicate_example"] == {
        "scene_id": 1, "im_id": 1, "obj_id": 1, "rows": 2, "instances": 1, "kept_score": 1.0
    }  # fmt: skip
    only1 = evaluate(dataset, rows, "test", scenes=[1])
    assert only1["objects"]["1"]["add_auc"] == pytest.approx(100.0, abs=1e-6)


def test_two_instances_matched_greedily(dataset: Path) -> None:
    rows = [r for r in _gt_rows(dataset) if (r.scene_id, r.im_id) == (1, 10)]
    assert len(rows) == 2
    rows[0].score, rows[1].score = 0.3, 0.9  # the better-scored row is the second instance's
    rep = evaluate(dataset, rows, "test", scenes=[1])
    e = rep["objects"]["1"]
    assert e["n"] == 11 and e["n_missing"] == 9
    assert e["add_auc"] == pytest.approx(auc(np.array([0.0] * 2 + [np.inf] * 9)))


def test_format_table(dataset: Path) -> None:
    rep = evaluate(dataset, _gt_rows(dataset), "test")
    none = {f"{m}_{k}": None for m in ("add", "adds", "add_s") for k in ("auc", "acc")}
    rep["objects"]["7"] = {"n": 0, "n_missing": 0, **none}
    lines = format_table(rep).splitlines()
    assert "ADD AUC" in lines[0] and "ADD-S AUC" in lines[0] and "ADD(-S) AUC" in lines[0]
    assert lines[1].split() == ["1", "16", "0", "100.00", "100.00", "100.00", "100.00"]
    assert lines[2].split() == ["7", "0", "0", "-", "-", "-", "-"]
    assert lines[-2].startswith("all (pooled)") and lines[-1].startswith("mean of objects")


def _run_cli(monkeypatch: pytest.MonkeyPatch, *args: str) -> int:
    monkeypatch.setattr(sys, "argv", ["chpf-eval", *args])
    with pytest.raises(SystemExit) as ei:
        cli()
    return ei.value.code


def test_cli_end_to_end(dataset: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    res = tmp_path / "res.csv"
    bop.write_results_csv(res, _gt_rows(dataset, offset=OFFSET))
    out = tmp_path / "report.json"
    code = _run_cli(
        monkeypatch, "--dataset", str(dataset), "--results", str(res), "--json", str(out)
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "all" in text and "ADD-S AUC" in text
    rep = json.loads(out.read_text())
    assert set(rep["objects"]) == {"1"} and rep["all"]["n"] == 16
    assert rep["objects"]["1"]["add_auc"] == pytest.approx(auc(np.full(16, 0.05)))


def test_cli_malformed_csv_exits_2(dataset: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    res = tmp_path / "bad.csv"
    res.write_text("scene_id,im_id,obj_id,score,R,t,time\n1,1,1,0.9,1 0 0 0 1 0 0 0 1,0 0 800\n")
    code = _run_cli(monkeypatch, "--dataset", str(dataset), "--results", str(res))
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "bad.csv:2" in err and "\n" not in err
    good = tmp_path / "good.csv"
    bop.write_results_csv(good, _gt_rows(dataset))
    code = _run_cli(monkeypatch, "--dataset", str(tmp_path / "nope"), "--results", str(good))
    assert code == 2 and "nope" in capsys.readouterr().err


# --- model points, ADD(-S), accuracy, pooling, targets ------------------------------------------


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _rotated_rows(root: Path, obj_id: int, deg: float) -> list[ResultRow]:
    """Ground truth of obj_id with the estimate turned by deg about the object's z axis."""
    return [
        ResultRow(r.scene_id, r.im_id, r.obj_id, 1.0, r.R @ _rot_z(deg), r.t, 0.02)
        for r in _gt_rows(root, obj_id)
    ]


def test_model_points_sources(dataset: Path, tmp_path: Path) -> None:
    rows = _rotated_rows(dataset, 1, 30.0)
    gt = _gt_rows(dataset)
    rep = evaluate(dataset, rows, "test")["objects"]["1"]
    hand = [_add_hand(_box_corners(), e.R, e.t, g.R, g.t) for e, g in zip(rows, gt, strict=True)]
    assert rep["add_auc"] == pytest.approx(vocap_reference(hand), abs=1e-9)
    # a point file (metres), as YCB-Video's points.xyz
    pts = np.array([[0.02, 0.0, 0.0], [0.0, 0.03, 0.01], [-0.01, -0.01, 0.0]])
    xyz = tmp_path / "points.xyz"
    np.savetxt(xyz, pts)
    rep = evaluate(dataset, rows, "test", points=xyz)["objects"]["1"]
    hand = [_add_hand(pts, e.R, e.t, g.R, g.t) for e, g in zip(rows, gt, strict=True)]
    assert rep["add_auc"] == pytest.approx(vocap_reference(hand), abs=1e-9)
    # the surface sample only on request: it differs from the 8 corners
    sample = BopDataset(dataset).load_object(1).points
    rep_s = evaluate(dataset, rows, "test", points="sample")["objects"]["1"]
    hand = [_add_hand(sample, e.R, e.t, g.R, g.t) for e, g in zip(rows, gt, strict=True)]
    assert rep_s["add_auc"] == pytest.approx(vocap_reference(hand), abs=1e-9)
    # models_eval/ wins over models/ when present (here a box twice as large)
    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    (copy / "models_eval").mkdir()
    trimesh.creation.box(extents=[200.0, 140.0, 80.0]).export(copy / "models_eval/obj_000001.ply")
    rep = evaluate(copy, rows, "test")["objects"]["1"]
    hand = [_add_hand(_box_corners(2.0), e.R, e.t, g.R, g.t) for e, g in zip(rows, gt, strict=True)]
    assert rep["add_auc"] == pytest.approx(vocap_reference(hand), abs=1e-9)
    # one point file cannot serve two objects; a bad point file is one line
    two = rows + _gt_rows(dataset, 2)
    with pytest.raises(DatasetError, match="one point file for 2 objects"):
        evaluate(dataset, two, "test", points=xyz)
    bad = tmp_path / "bad.xyz"
    bad.write_text("1 2\n3 4\n")
    with pytest.raises(DatasetError, match=r"bad\.xyz: not a point file"):
        evaluate(dataset, rows, "test", points=bad)


def test_add_s_follows_symmetry_accuracy_and_pooling(dataset: Path) -> None:
    # cylinder (symmetric about z, 24 sections): 15 degrees about z maps its vertices onto
    # themselves, so ADD-S = 0 while ADD > 0; ADD(-S) is ADD-S for it
    cyl = _rotated_rows(dataset, 2, 15.0)
    box = _gt_rows(dataset, 1, offset=np.array([0.0, 0.0, 0.0]))
    # the box: every other instance's estimate 1 cm off, the rest 3 cm (diameter 12.8 cm)
    for i, r in enumerate(box):
        r.t = r.t + np.array([0.01 if i % 2 else 0.03, 0.0, 0.0])
    rep = evaluate(dataset, box + cyl[:5], "test")
    c, b = rep["objects"]["2"], rep["objects"]["1"]
    assert c["symmetric"] and not b["symmetric"]
    assert c["adds_auc"] == pytest.approx(100 * 5 / 10, abs=1e-4)  # 5 of 10, exact (float32)
    assert c["add_s_auc"] == c["adds_auc"] and c["add_auc"] < c["adds_auc"]
    assert b["add_s_auc"] == b["add_auc"]
    d_box = float(np.linalg.norm([0.1, 0.07, 0.04]))
    box_add = [0.01 if i % 2 else 0.03 for i in range(16)]
    assert b["add_s_acc"] == pytest.approx(100 * np.mean(np.array(box_add) < 0.1 * d_box))
    assert 0 < b["add_s_acc"] < 100
    # pooled over all 26 instances vs the mean of the two objects' AUCs
    cyl_adds = [0.0] * 5 + [np.inf] * 5
    pooled = vocap_reference(box_add + cyl_adds)
    assert rep["all"]["add_s_auc"] == pytest.approx(pooled, abs=1e-4)
    per_object = (vocap_reference(box_add) + vocap_reference(cyl_adds)) / 2
    assert rep["mean_of_objects"]["add_s_auc"] == pytest.approx(per_object, abs=1e-4)
    assert abs(pooled - per_object) > 1.0  # the two conventions differ here


def test_targets_subset(dataset: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    rows = _gt_rows(dataset, 1, offset=OFFSET)[:4]  # scene 1, images 1-4, 5 cm off
    bop_json = tmp_path / "test_targets_bop19.json"
    bop_json.write_text(
        json.dumps([{"scene_id": 1, "im_id": i, "obj_id": 1, "inst_count": 1} for i in (1, 2)])
    )
    rep = evaluate(dataset, rows, "test", targets=read_targets(bop_json))
    assert rep["all"]["n"] == 2 and rep["all"]["n_missing"] == 0
    keyframes = tmp_path / "keyframe.txt"
    keyframes.write_text("# scene/image\n0001/000001\n0001/000003\n0002/000001\n")
    rep = evaluate(dataset, rows, "test", targets=read_targets(keyframes))
    assert rep["all"]["n"] == 3 and rep["all"]["n_missing"] == 1  # scene 2 image 1 not estimated
    assert rep["all"]["add_auc"] == pytest.approx(vocap_reference([0.05, 0.05, np.inf]))
    res = tmp_path / "res.csv"
    bop.write_results_csv(res, rows)
    bad = tmp_path / "bad.txt"
    bad.write_text("0001/000001\n12 7\n")
    code = _run_cli(
        monkeypatch, "--dataset", str(dataset), "--results", str(res), "--targets", str(bad)
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == "error: " + f"{bad}: line 2: expected scene_id/im_id, got '12 7'"


def _cli_lines(monkeypatch, capsys, dataset: Path, res: Path) -> tuple[int, list[str], list[str]]:
    code = _run_cli(monkeypatch, "--dataset", str(dataset), "--results", str(res))
    cap = capsys.readouterr()
    return code, cap.out.splitlines(), cap.err.strip().splitlines()


def test_cli_empty_results_are_refused(dataset: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    res = tmp_path / "empty.csv"
    for text in ("", HEADER + "\n"):
        res.write_text(text)
        code, out, err = _cli_lines(monkeypatch, capsys, dataset, res)
        assert code == 2 and out == [] and len(err) == 1, (out, err)
        assert "empty.csv: no result rows" in err[0]


def test_cli_duplicates_and_unknown_obj_ids_are_named(
    dataset: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    """Duplicate rows (two runs appended to one file) are called duplicates, with the row kept;
    an obj_id the ground truth lacks, and objects of the dataset with no rows, are warned about
    by id; results whose objects all lack ground truth are refused."""
    rows = _gt_rows(dataset)
    worse = ResultRow(1, 3, 1, 0.5, np.eye(3), np.array([0, 0, 3.0]))
    stray = ResultRow(1, 3, 9, 0.5, np.eye(3), np.array([0, 0, 1.0]))
    res = tmp_path / "two_runs.csv"
    bop.write_results_csv(res, [*rows, rows[0], worse, stray])
    code, out, err = _cli_lines(monkeypatch, capsys, dataset, res)
    assert code == 0
    text = "\n".join(out + err)
    assert "matched no ground-truth instance" not in text
    dup = [line for line in err if "duplicate rows" in line]
    assert len(dup) == 1 and dup[0].startswith("warning: ") and "2 duplicate rows" in dup[0]
    assert f"scene {rows[0].scene_id} image {rows[0].im_id} obj_id 1" in dup[0]
    assert "best-scoring" in dup[0] and "kept" in dup[0]
    ids = [line for line in err if "obj_id" in line and "ground truth" in line]
    assert any("[9]" in line and "lacks" in line for line in ids), err
    assert any("[2]" in line and "no result rows" in line for line in ids), err
    assert len(err) == 3
    only_stray = tmp_path / "stray.csv"
    bop.write_results_csv(only_stray, [stray])
    code, out, err = _cli_lines(monkeypatch, capsys, dataset, only_stray)
    assert code == 2 and out == [] and len(err) == 1 and "obj_ids [9]" in err[0], err
