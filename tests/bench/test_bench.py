"""chpf-bench: the quick suite end to end, resume, shards and merge, bad input, statistics."""

from __future__ import annotations

import csv
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from bench import cli
from bench.stats import bootstrap, reacquisition, tracked_stat
from chpf.bop import BopDataset, read_results_csv
from chpf.errors import OutputError
from tests.helpers import vocap_reference


def _main(*args: str) -> int:
    return cli.main(list(args))


def _exit(monkeypatch: pytest.MonkeyPatch, *args: str) -> int:
    monkeypatch.setattr(sys, "argv", ["chpf-bench", *args])
    with pytest.raises(SystemExit) as ei:
        cli.cli()
    return ei.value.code


def _run_quick(out: Path, cache: Path, *extra: str) -> int:
    """chpf-bench run of the quick suite into ``out``, sequences cached in ``cache``."""
    return _main(
        "run",
        "--suite",
        "quick",
        "--out",
        str(out),
        "--cache-dir",
        str(cache),
        "--no-progress",
        *extra,
    )


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("bench-cache")


@pytest.fixture(scope="module")
def quick(tmp_path_factory, cache) -> Path:
    out = tmp_path_factory.mktemp("bench") / "quick"
    assert _run_quick(out, cache) == 0
    return out


def _auc_rows(out: Path) -> list[dict[str, str]]:
    with open(out / "report" / "auc.csv", newline="") as f:
        return list(csv.DictReader(f))


def _adds_hand(pts: np.ndarray, Re, te, Rg, tg) -> float:
    """ADD-S by its definition: brute-force nearest estimate-posed point (metres)."""
    est = pts @ Re.T + te
    gt = pts @ Rg.T + tg
    d = np.sqrt(((gt[:, None, :] - est[None, :, :]) ** 2).sum(-1))
    return float(d.min(axis=1).mean())


def test_quick_suite_report_is_scored_as_computed_by_hand(quick: Path) -> None:
    rep = quick / "report"
    for name in (
        "report.md",
        "auc.csv",
        "tracking.csv",
        "alpha.csv",
        "report.json",
        "auc_by_level.png",
        "curves.png",
        "overlays.png",
    ):
        assert (rep / name).is_file(), name
    assert list(rep.glob("sequence_*.png"))
    md = (rep / "report.md").read_text()
    assert "| chpf | rgb |" in md and "| srl | rgbd |" in md
    assert "## Doubt: alpha by frame state" in md
    suite = json.loads((quick / "suite.json").read_text())
    jobs = sorted((quick / "jobs").iterdir())
    levels = len(suite["sequences"]["occlusion"])
    assert len(jobs) == 2 * 2 * levels  # 2 methods x 2 modalities x 1 scene per level
    # independent scoring of chpf's ADD-S AUC on the heavy sequence: its result CSV, the
    # model's vertices read with trimesh, brute-force ADD-S, the toolbox's VOCap transcription
    seqs = json.loads((quick / "sequences.json").read_text())
    heavy = next(s for s in seqs if s["level"] == "heavy")
    ds = BopDataset(heavy["root"])
    scene = ds.scene("test", heavy["scene_id"])
    pts = np.asarray(trimesh.load(ds.model_path(2), process=False).vertices) / 1000.0
    job = next(j for j in jobs if j.name.startswith("box-heavy-01-chpf-rgb"))
    est = {r.im_id: r for p in job.glob("chpf_*.csv") for r in read_results_csv(p)}
    errors, visib = [], []
    for im in scene.image_ids():
        gt = next(p for p in scene.gt[im] if p.obj_id == 2)
        r = est.get(im)
        errors.append(np.inf if r is None else _adds_hand(pts, r.R, r.t, gt.R, gt.t))
        visib.append(scene.gt_info[im][0].visib_fract)
    row = next(
        r
        for r in _auc_rows(quick)
        if (r["method"], r["occlusion"], r["frames"], r["metric"])
        == ("chpf", "heavy", "all", "ADD-S")
    )
    assert float(row["auc"]) == pytest.approx(vocap_reference(errors), abs=2e-3)
    occluded = [e for e, v in zip(errors, visib, strict=True) if v < 0.75]
    assert occluded  # the heavy level hides the target
    row = next(
        r
        for r in _auc_rows(quick)
        if (r["method"], r["occlusion"], r["frames"], r["metric"])
        == ("chpf", "heavy", "occluded", "ADD-S")
    )
    assert float(row["auc"]) == pytest.approx(vocap_reference(occluded), abs=2e-3)


def test_rerun_resumes(quick: Path, cache: Path, capsys) -> None:
    jobs = sorted((quick / "jobs").iterdir())
    (jobs[0] / "summary.json").unlink()
    kept = (jobs[1] / "summary.json").stat().st_mtime_ns
    before = _auc_rows(quick)
    capsys.readouterr()
    assert _run_quick(quick, cache) == 0
    out = capsys.readouterr().out
    assert f"1 jobs run ({len(jobs) - 1} already done)" in out
    assert "building" not in out  # the sequences came from the cache
    assert (jobs[0] / "summary.json").is_file()
    assert (jobs[1] / "summary.json").stat().st_mtime_ns == kept
    assert _auc_rows(quick) == before  # the redone job repeats its poses


def test_shards_merge_to_the_same_report(quick: Path, cache: Path, tmp_path: Path) -> None:
    a, b, merged = tmp_path / "a", tmp_path / "b", tmp_path / "merged"
    for i, d in enumerate((a, b)):
        assert _run_quick(d, cache, "--shard", str(i), "--num-shards", "2") == 0
        assert not (d / "report").exists()  # one shard of several: no report
    n_a, n_b = (len(list((d / "jobs").iterdir())) for d in (a, b))
    assert n_a + n_b == len(list((quick / "jobs").iterdir())) and n_a and n_b
    assert _main("merge", "--out", str(merged), str(a), str(b)) == 0
    assert _auc_rows(merged) == _auc_rows(quick)


def test_bad_input_is_one_line(
    quick: Path, cache: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    bad = tmp_path / "suite.yaml"
    bad.write_text("name: x\nsequences:\n  frame: 10\n")
    assert _exit(monkeypatch, "run", "--suite", str(bad), "--out", str(tmp_path / "o")) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(bad) in err and "unknown key sequences.frame" in err
    # a shard folder of another suite
    other = tmp_path / "other"
    shutil.copytree(quick, other)
    rec = json.loads((other / "suite.json").read_text())
    rec["seeds"], rec["suite_hash"] = [5], "0123456789abcdef"
    (other / "suite.json").write_text(json.dumps(rec))
    code = _exit(monkeypatch, "merge", "--out", str(tmp_path / "m"), str(quick), str(other))
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and f"{other}: results of another suite" in err
    # a run into a folder of another suite
    code = _exit(
        monkeypatch,
        "run",
        "--suite",
        "quick",
        "--out",
        str(other),
        "--cache-dir",
        str(cache),
        "--no-progress",
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "holds results of another suite" in err
    # a bundle that fails to load
    broken = tmp_path / "bundle"
    broken.mkdir()
    code = _exit(
        monkeypatch,
        "run",
        "--suite",
        "quick",
        "--bundles",
        str(broken),
        "--out",
        str(tmp_path / "o2"),
        "--cache-dir",
        str(cache),
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and str(broken) in err and "manifest" in err
    # an unknown method
    code = _exit(
        monkeypatch, "run", "--suite", "quick", "--methods", "nope", "--out", str(tmp_path / "o3")
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and "unknown 'nope'" in err


def test_bootstrap_value_and_interval() -> None:
    # two seeds, three sequences: the value is the mean over seeds of the pooled AUC
    d = np.ones(2)
    s0 = [(np.array([0.01, 0.02]), d), (np.array([0.05, np.inf]), d), (np.array([0.03, 0.2]), d)]
    s1 = [(np.array([0.02, 0.02]), d), (np.array([0.04, 0.06]), d), (np.array([np.inf] * 2), d)]
    est = bootstrap([s0, s1], lambda e, _: vocap_reference(e), 200)
    pooled = [np.concatenate([e for e, _ in s]) for s in (s0, s1)]
    assert est.value == pytest.approx(np.mean([vocap_reference(p) for p in pooled]))
    assert est.lo <= est.value <= est.hi and est.hi - est.lo > 1.0
    assert (est.n_sequences, est.n_frames) == (3, 6)
    same = bootstrap([[s0[0]] * 3], lambda e, _: vocap_reference(e), 50)
    assert same.lo == same.hi == pytest.approx(same.value)  # identical sequences: no spread
    # tracked share: error below 0.1 diameter
    assert tracked_stat(np.array([0.01, 0.05, np.inf]), np.array([0.2, 0.2, 0.2])) == (
        pytest.approx(100 / 3)
    )


def test_reacquisition_times() -> None:
    ok = np.array([1, 1, 0, 0, 1, 0, 1, 1, 0, 0], bool)
    assert reacquisition(ok) == ([2, 1], 1)  # lost at 2 (back at 4), at 5 (back at 6), at 8
    assert reacquisition(np.zeros(5, bool)) == ([], 0)  # never tracked: no loss


def test_bench_imports_chpf_and_data_gen_only() -> None:
    """bench sits beside data_gen: it may use chpf and data_gen, never torch or training."""
    import ast

    import bench

    forbidden = {"torch", "torchvision", "lightning", "onnx", "training", "export"}
    for path in Path(bench.__file__).parent.rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        roots = {
            a.name.split(".")[0]
            for n in ast.walk(tree)
            if isinstance(n, ast.Import)
            for a in n.names
        }
        roots |= {
            n.module.split(".")[0]
            for n in ast.walk(tree)
            if isinstance(n, ast.ImportFrom) and n.level == 0 and n.module
        }
        assert not roots & forbidden, (path.name, roots & forbidden)


def test_likelihoods_at_the_truth_by_visible_fraction(quick: Path, tmp_path: Path) -> None:
    """Every visible instance of the tracked object is scored once, in its band; the shipped
    classifier calls the well visible ones aligned; a folder that is no run is one line."""
    assert _main("likelihoods", str(quick)) == 0
    with open(quick / "report" / "likelihoods.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    seqs = json.loads((quick / "sequences.json").read_text())
    visible = []
    for s in seqs:
        scene = BopDataset(s["root"]).scene("test", s["scene_id"])
        visible += [
            info.visib_fract
            for im in scene.image_ids()
            for gt, info in zip(scene.gt[im], scene.gt_info[im], strict=True)
            if gt.obj_id == s["obj_id"] and info.bbox_visib[2] > 0
        ]
    assert sum(int(r["frames"]) for r in rows) == len(visible)
    top = next(r for r in rows if r["band"] == "90%-100%")
    assert int(top["frames"]) == sum(v >= 0.9 for v in visible)
    assert float(top["mean_C"]) < 0.2 and float(top["aligned_pct"]) > 90.0  # the classifier's C
    assert float(top["mean_C_near"]) < 0.5  # a few degrees and millimetres off: still aligned
    with pytest.raises(OutputError, match="not a chpf-bench run folder"):
        _main("likelihoods", str(tmp_path))


def test_alpha_by_frame_state_averages_each_seeds_mean() -> None:
    """The report's alpha table: per state, the mean of the seeds' means over the frames of
    that state (tracked < 0.1 d, lost > 0.5 d, occluded / hidden and tracked)."""
    from bench.report import Figures

    d = 0.2

    def summary(seed: int, adds: list[float], visib: list[float], alpha: list[float]) -> dict:
        return {
            "method": "chpf",
            "modality": "rgb",
            "sequence": "s1",
            "seed": seed,
            "level": "heavy",
            "diameter": d,
            "adds": np.array(adds),
            "visib": np.array(visib),
            "alpha": np.array(alpha),
        }

    suite = {
        "methods": ["chpf"],
        "modalities": ["rgb"],
        "sequences": {"occlusion": ["heavy"]},
        "seeds": [0, 1],
        "report": {"bootstrap": 10},
    }
    s0 = summary(0, [0.01, 0.01, 0.5, 0.01], [1.0, 0.5, 0.5, 0.2], [0.1, 0.3, 0.9, np.nan])
    s1 = summary(1, [0.01, 0.2, np.inf, 0.01], [1.0, 1.0, 0.5, 0.6], [0.2, 0.5, 0.7, 0.4])
    got = Figures(suite, [s0, s1]).alpha_by_state("chpf", "rgb")
    assert got["tracked"] == pytest.approx((0.25, 0.2, 0.3, 4))  # seed 0: (0.1+0.3)/2, seed 1: 0.3
    assert got["lost"] == pytest.approx((0.75, 0.6, 0.9, 3))  # 0.9; (0.5 + 0.7) / 2
    assert got["occluded tracked"] == pytest.approx((0.35, 0.3, 0.4, 2))
    assert got["hidden tracked"][3] == 0  # its only frame has no alpha


def test_near_poses_lie_within_a_tenth_of_the_diameter() -> None:
    """The poses `likelihoods` scores near the truth are off it, and within 0.1 d by ADD."""
    from bench.likelihoods import NEAR, near_poses
    from chpf.geometry import random_rotations
    from chpf.metrics import add

    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.1, 0.1, (500, 3))
    d = float(np.max(np.linalg.norm(pts[:, None] - pts[None], axis=2)))
    for R in random_rotations(5, rng):
        t = np.array([0.05, -0.02, 0.8])
        Rn, tn = near_poses(R, t, d, rng)
        assert Rn.shape == (NEAR, 3, 3) and tn.shape == (NEAR, 3)
        errs = [add(pts, Rn[i], tn[i], R, t) for i in range(NEAR)]
        assert 0.0 < min(errs) and max(errs) < 0.1 * d


def test_every_shipped_suite_loads_under_its_own_name() -> None:
    """Each YAML in bench/suites is a valid suite whose name is its file's (``--suite dev2``);
    the development suites draw other sequences than the reported default suite."""
    from bench.suite import SUITES_DIR, load_suite

    suites = {p.stem: load_suite(p.stem) for p in sorted(SUITES_DIR.glob("*.yaml"))}
    assert {"default", "dev", "dev2", "quick"} <= set(suites)
    assert all(s.name == stem for stem, s in suites.items())
    reported = suites["default"].sequences.seed
    assert reported not in {suites["dev"].sequences.seed, suites["dev2"].sequences.seed}


def test_suites_name_shipped_bundles(tmp_path: Path, monkeypatch) -> None:
    """'shipped' is every shipped bundle, a shipped bundle's name is that one; the quick suite
    tracks the box alone whatever else is shipped."""
    pytest.importorskip("onnx")
    from bench.sequences import resolve_bundles
    from bench.suite import load_suite
    from tests.chpf.tracking.conftest import write_template_bundle

    root = tmp_path / "shipped"
    write_template_bundle(root / "box")
    write_template_bundle(root / "mug", name="mug")
    monkeypatch.setattr("chpf.tracking.demo.bundles_dir", lambda: root)
    monkeypatch.chdir(tmp_path)  # no folder named box or mug here

    def names(**over) -> list[tuple[str, int]]:
        return [(r.name, r.obj_id) for r in resolve_bundles(load_suite("quick", over))]

    assert names() == [("box", 2)]
    assert names(bundles=["mug"]) == [("mug", 1)]
    assert names(bundles=["shipped"]) == [("box", 2), ("mug", 1)]


def test_forced_loss_counts_frames_to_reacquisition_and_whether_the_run_was_tracked_before():
    from bench.forced_loss import reacquisition, tracked_before

    summary = {"diameter": 0.2, "adds": [0.01, 0.01, None, 0.05, 0.03, 0.01]}  # jump at 2
    assert reacquisition(summary, 2) == 3 and tracked_before(summary, 2)
    lost_early = {"diameter": 0.2, "adds": [0.01, 0.03, 0.05, 0.05, 0.05, 0.05]}
    assert reacquisition(lost_early, 2) is None and not tracked_before(lost_early, 2)
