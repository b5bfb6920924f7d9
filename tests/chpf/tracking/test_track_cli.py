"""chpf-track on a tiny generated BOP dataset with the template bundle (see conftest.py)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chpf.bop import read_results_csv
from chpf.errors import BundleError, ConfigError, DatasetError
from chpf.track_cli import build_parser, cli, main, parse_methods, tracking_config
from chpf.tracking.runlog import COLUMNS, read_log
from tests.helpers import console_error

FRAMES = 8


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A 1-scene, FRAMES-frame occluded sequence of the template bundle's object."""
    from data_gen.config import load_config
    from data_gen.sequences import generate_sequences

    root = tmp_path_factory.mktemp("seq") / "bop"
    sets = {
        "num_scenes": 1,
        "frames": FRAMES,
        "width": 160,
        "height": 120,
        "focal": 150.0,
        "default_distractors": 0,
    }
    cfg = load_config(None, [f"sequences.{k}={v}" for k, v in sets.items()])
    generate_sequences(["box"], root, cfg, seed=0, progress=False)
    return root


CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().out.splitlines()


def test_track_writes_results_logs_table_and_plot_and_resumes(
    template_bundle, dataset, tmp_path, capsys
):
    out = tmp_path / "out"
    args = ["--bundle", template_bundle, "--dataset", dataset, "--method", "chpf,poserbpf++"]
    args += ["--out", out, "--no-progress", "--config", CONFIGS / "track_paper.yaml"]
    code, lines = _run(capsys, *args)
    assert code == 0
    assert lines[0].startswith("detections: simulated detector")
    assert any("ADD-S AUC" in line for line in lines)
    results = out / "chpf_bop-test.csv"
    rows = read_results_csv(results)
    assert 0 < len(rows) <= FRAMES and {r.obj_id for r in rows} == {2}
    assert (out / "poserbpfpp_bop-test.csv").is_file()
    log = read_log(out / "log_chpf.csv")
    assert len(log) == FRAMES and (out / "plots" / "scene_000001.png").stat().st_size > 1000
    weighed = [r.values for r in log if r.values["weighed"]]
    assert weighed  # each logged alpha is the paper's rule on that row's logged sums (6 digits)
    for v in weighed:
        np.testing.assert_allclose(v["alpha"], v["sum_C"] / (v["sum_C"] + v["sum_L"]), rtol=1e-4)
    assert np.isfinite([r.values["err_adds"] for r in log if r.values["ok"]]).all()
    first = results.read_text()

    # rerun: nothing left to do, nothing duplicated
    code, lines = _run(capsys, *args)
    assert (
        code == 0 and results.read_text() == first and len(read_log(out / "log_chpf.csv")) == FRAMES
    )

    # an interrupted run: keep the first 3 frames (+ a partial line) -> the rerun completes the
    # scene with the same poses as the uninterrupted run
    text = results.read_text().splitlines(keepends=True)
    results.write_text("".join(text[:4]) + text[4][:10])
    log_lines = (out / "log_chpf.csv").read_text().splitlines(keepends=True)
    (out / "log_chpf.csv").write_text("".join(log_lines[:4]) + log_lines[4][:7])
    code, _ = _run(capsys, *args)
    assert code == 0
    again = read_results_csv(results)
    assert [r.key for r in again] == [r.key for r in rows]
    for a, b in zip(again, rows, strict=True):  # same poses (the time column differs)
        np.testing.assert_allclose(a.R, b.R, atol=1e-9)
        np.testing.assert_allclose(a.t, b.t, atol=1e-9)
    assert len(read_log(out / "log_chpf.csv")) == FRAMES


def test_detections_file_and_on_the_fly_simulated_detector(
    template_bundle, dataset, tmp_path, capsys
):
    det = tmp_path / "dets.json"
    det.write_text(
        json.dumps(
            [
                {
                    "scene_id": 1,
                    "image_id": i,
                    "category_id": 2,
                    "bbox": [40, 30, 60, 50],
                    "score": 1.0,
                }
                for i in (1, 2, 3)
            ]
        )
    )
    out = tmp_path / "out_det"
    code, lines = _run(
        capsys,
        "--bundle",
        template_bundle,
        "--dataset",
        dataset,
        "--detections",
        det,
        "--out",
        out,
        "--no-progress",
        "--no-plot",
    )
    assert code == 0 and lines[0].startswith(f"detections: detections from {det}")
    log = read_log(out / "log_chpf.csv")
    assert [int(r.values["has_box"]) for r in log] == [1, 1, 1] + [0] * (FRAMES - 3)
    # a detector ran (boxes after the first), so the frames it missed are predict-only
    # (search.box_source auto)
    assert [int(r.values["weighed"]) for r in log] == [1, 1, 1] + [0] * (FRAMES - 3)

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    (copy / "detections_sim.json").unlink()
    code, lines = _run(
        capsys,
        "--bundle",
        template_bundle,
        "--dataset",
        copy,
        "--out",
        tmp_path / "out_sim",
        "--no-progress",
        "--no-plot",
        "--modality",
        "rgbd",
    )
    assert code == 0 and "simulated detector" in lines[0] and "scene_gt_info" in lines[0]


def test_refusals(template_bundle, dataset, tmp_path, capsys):
    manifest = json.loads((template_bundle / "manifest.json").read_text())
    other = tmp_path / "other_bundle"
    shutil.copytree(template_bundle, other)
    manifest["object"]["obj_id"] = 7
    (other / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BundleError, match="obj_id 7"):
        main(["--bundle", str(other), "--dataset", str(dataset), "--out", str(tmp_path / "o")])
    empty = tmp_path / "nogt"
    shutil.copytree(dataset, empty)
    (empty / "detections_sim.json").unlink()
    (empty / "test" / "000001" / "scene_gt_info.json").unlink()
    with pytest.raises(DatasetError, match="no --detections"):
        main(["--bundle", str(template_bundle), "--dataset", str(empty)])
    with pytest.raises(ConfigError):
        parse_methods("chpf,bogus")
    assert parse_methods("all")[0] == "chpf" and "poserbpf++" in parse_methods("all")
    # the console script prints one line and exits 2
    code, err = _console_script(
        ["--bundle", str(tmp_path / "nope"), "--dataset", str(dataset)], capsys
    )
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ")


def test_obj_id_maps_a_bundle_onto_the_datasets_object(template_bundle, dataset, tmp_path, capsys):
    """A bundle whose obj_id (7) is not the dataset's (2) is refused with a hint at --obj-id;
    --obj-id 2 tracks the dataset's object 2 with it and the results name obj_id 2; the model
    check runs on the mapped id (the distractor, obj_id 4, is another object)."""
    other = tmp_path / "bundle7"
    shutil.copytree(template_bundle, other)
    manifest = json.loads((other / "manifest.json").read_text())
    manifest["object"]["obj_id"] = 7
    (other / "manifest.json").write_text(json.dumps(manifest))
    argv = ["--bundle", other, "--dataset", dataset, "--method", "srl", "--out", tmp_path / "o"]
    with pytest.raises(BundleError, match=r"obj_id 7\).*pass --obj-id N"):
        main([str(a) for a in argv])
    code, _ = _run(capsys, *argv, "--obj-id", 2, "--no-progress", "--no-plot")
    assert code == 0
    rows = read_results_csv(next((tmp_path / "o").glob("srl_*.csv")))
    assert rows and {r.obj_id for r in rows} == {2}
    with pytest.raises(BundleError, match="obj_id 4 has diameter"):  # the distractor, obj_id 4
        main([str(a) for a in argv] + ["--obj-id", "4", "--overwrite"])


def test_bundle_of_another_object_with_the_same_obj_id_is_refused(
    template_bundle, dataset, tmp_path, capsys
):
    """The dataset's obj_id 2 is another object: a diameter 5 % or more off the manifest's, or
    (where chpf-gen-data recorded one) another mesh fingerprint, is refused naming both."""
    other = tmp_path / "other_ds"
    shutil.copytree(dataset, other)
    info_path = other / "models" / "models_info.json"
    info = json.loads(info_path.read_text())
    info["2"]["diameter"] = 152.6  # mm; the box bundle's is 319.7
    info_path.write_text(json.dumps(info))
    argv = ["--bundle", template_bundle, "--dataset", other, "--out", tmp_path / "o"]
    with pytest.raises(BundleError) as err:
        main([str(a) for a in argv])
    msg = str(err.value)
    assert "obj_id 2" in msg and "319.7 mm" in msg and "152.6 mm" in msg
    assert str(template_bundle / "manifest.json") in msg and str(info_path) in msg
    assert not (tmp_path / "o").exists()

    info["2"]["diameter"] = 319.7 * 1.03  # within the tolerance: the fingerprint decides
    info_path.write_text(json.dumps(info))
    seq_info_path = other / "sequences_info.json"
    seq_info = json.loads(seq_info_path.read_text())
    target = next(o for o in seq_info["objects"] if o["obj_id"] == 2)
    target["fingerprint"] = "0" * 40
    seq_info_path.write_text(json.dumps(seq_info))
    with pytest.raises(BundleError, match=r"fingerprint 0000000000 but .* has 127c1257ba"):
        main([str(a) for a in argv])
    seq_info_path.unlink()  # no fingerprint recorded: the diameter agrees, tracking goes on
    code, _ = _run(capsys, *argv, "--no-progress", "--no-plot")
    assert code == 0


def _console_script(argv: list[str], capsys) -> tuple[int, list[str]]:
    """Exit code and stderr lines of the chpf-track console script run with ``argv``."""
    saved = sys.argv
    sys.argv = ["chpf-track", *argv]
    try:
        with pytest.raises(SystemExit) as exc:
            cli()
    finally:
        sys.argv = saved
    return exc.value.code, capsys.readouterr().err.strip().splitlines()


def test_set_options_reach_the_trackers_and_bad_ones_exit_2(dataset, capsys):
    args = build_parser().parse_args(
        [
            "--config",
            str(CONFIGS / "track_paper.yaml"),
            "--set",
            "srl.beta=0.5",
            "--set",
            "likelihood.sigma=0.2",
            "--n-particles",
            "20",
        ]
    )
    cfg = tracking_config(args)
    assert cfg.srl.beta == 0.5 and cfg.likelihood.sigma == 0.2 and cfg.filter.n_particles == 20
    assert cfg.candidates.rotations == "uniform"  # the file's keys stay
    for bad, needle in (("srl.betta=1", "unknown key srl.betta"), ("srl.beta=-1", "srl.beta")):
        code, err = _console_script(
            ["--dataset", str(dataset), "--bundle", "b", "--set", bad], capsys
        )
        assert code == 2 and len(err) == 1 and err[0].startswith("error: --set: ")
        assert needle in err[0]


def test_demo_runs_chpf_chrbpf_and_two_baselines(template_bundle, tmp_path, capsys):
    out = tmp_path / "demo"
    code, lines = _run(capsys, "--demo", "--bundle", template_bundle, "--out", out, "--no-progress")
    assert code == 0 and lines[0].startswith("detections: simulated detector")
    table = (out / "auc_table.txt").read_text()
    rows = [line.split()[0] for line in table.splitlines()[2:]]
    assert rows == ["chpf", "chrbpf", "srl", "poserbpf"]
    assert (out / "plots" / "scene_000001.png").is_file()
    assert set(COLUMNS) <= set((out / "log_chpf.csv").read_text().splitlines()[0].split(","))


def _cli_error(capsys, monkeypatch, *argv) -> str:
    return console_error(cli, capsys, monkeypatch, *argv)


def test_rerun_with_other_settings_is_refused_unless_overwrite(
    template_bundle, dataset, tmp_path, capsys, monkeypatch
):
    """8 frames with seed 0 / N = 50, then seed 1 / N = 20 into the same --out: refused, the
    outputs untouched; with --overwrite the folder holds the second run alone."""
    out = tmp_path / "out"
    base = ["--bundle", template_bundle, "--dataset", dataset, "--out", out, "--no-progress"]
    base += ["--no-plot"]
    assert _run(capsys, *base)[0] == 0
    results = out / "chpf_bop-test.csv"
    first = results.read_text()
    settings = json.loads((out / "track_settings.json").read_text())
    assert settings["seed"] == 0 and settings["config"]["filter"]["n_particles"] == 50
    assert settings["methods"] == ["chpf"] and len(settings["bundle"]["sha256"]) == 64

    other = [*base, "--seed", 1, "--n-particles", 20]
    line = _cli_error(capsys, monkeypatch, *other)
    assert "other settings" in line and "config" in line and "seed" in line
    assert results.read_text() == first and len(read_log(out / "log_chpf.csv")) == FRAMES
    # a rerun with the same settings still resumes (nothing to do, nothing appended)
    assert _run(capsys, *base)[0] == 0 and results.read_text() == first

    assert _run(capsys, *other, "--overwrite")[0] == 0
    assert len(read_log(out / "log_chpf.csv")) == FRAMES
    assert len(read_results_csv(results)) <= FRAMES
    fresh = tmp_path / "fresh"
    argv = ["--bundle", template_bundle, "--dataset", dataset, "--out", fresh, "--no-progress"]
    assert _run(capsys, *argv, "--no-plot", "--seed", 1, "--n-particles", 20)[0] == 0
    got, want = read_results_csv(results), read_results_csv(fresh / "chpf_bop-test.csv")
    assert [r.key for r in got] == [r.key for r in want]
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)
    assert json.loads((out / "track_settings.json").read_text())["seed"] == 1


def test_second_writer_on_a_locked_out_folder_refuses(
    template_bundle, dataset, tmp_path, capsys, monkeypatch
):
    """While another process holds --out (here: this test), chpf-track refuses in one line and
    writes no rows."""
    from chpf.outdir import lock_output_dir

    out = tmp_path / "busy"
    with lock_output_dir(out, "chpf-track"):
        line = _cli_error(
            capsys, monkeypatch, "--bundle", template_bundle, "--dataset", dataset, "--out", out
        )
    assert "another command is writing here" in line and "chpf-track, pid" in line
    assert not list(out.glob("*.csv"))
    assert (
        _run(
            capsys,
            "--bundle",
            template_bundle,
            "--dataset",
            dataset,
            "--out",
            out,
            "--no-progress",
            "--no-plot",
        )[0]
        == 0
    )


def test_invalid_detection_boxes_and_missing_depth_are_warned_once(
    template_bundle, dataset, tmp_path
):
    """A detections file with zero-size boxes and an RGB-D dataset missing one depth PNG: one
    warning line each (naming the first frame and the file), the run goes on (was: silent)."""
    ds = tmp_path / "ds"
    shutil.copytree(dataset, ds)
    dets = json.loads((ds / "detections_sim.json").read_text())
    target = sorted((d for d in dets if d["category_id"] == 2), key=lambda d: d["image_id"])
    for d in target[2:4]:
        d["bbox"][2] = 0.0
    (tmp_path / "dets.json").write_text(json.dumps(dets))
    first = target[2]
    depth_png = ds / "test" / "000001" / "depth" / "000005.png"
    depth_png.unlink()
    argv = ["--bundle", template_bundle, "--dataset", ds, "--out", tmp_path / "o", "--no-plot"]
    argv += ["--no-progress", "--detections", tmp_path / "dets.json", "--modality", "rgbd"]
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.run(  # a process of its own: warnings as a user sees them
        [sys.executable, "-m", "chpf.track_cli", *(str(a) for a in argv)],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(root)},
        timeout=300,
    )
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 0, err
    boxes = [line for line in err if "invalid box" in line]
    depth = [line for line in err if "depth" in line]
    assert len(boxes) == 1 and len(depth) == 1 and len(err) == 2, err
    where = f"scene {first['scene_id']} image {first['image_id']}"
    assert boxes[0].startswith("warning: ") and where in boxes[0] and "dets.json" in boxes[0]
    assert depth[0].startswith("warning: ") and str(depth_png) in depth[0]


def test_device_and_precision_options(dataset, tmp_path, capsys):
    """--device cuda without onnxruntime-gpu is one line and exit 2; the first output line says
    where the networks run and at which precision."""
    code, err = _console_script(
        ["--demo", "--device", "cuda", "--out", str(tmp_path / "c")], capsys
    )
    assert code == 2 and len(err) == 1 and "device cuda" in err[0] and "chpf[gpu]" in err[0]
    code, lines = _run(capsys, "--demo", "--method", "srl", "--device", "cpu", "--no-plot",
                       "--no-progress", "--out", tmp_path / "d")  # fmt: skip
    assert code == 0 and "networks on the CPU (CPUExecutionProvider), float32" in lines[0]
    code, lines = _run(capsys, "--demo", "--method", "srl", "--precision", "int8", "--no-plot",
                       "--no-progress", "--out", tmp_path / "i")  # fmt: skip
    assert code == 0 and lines[0].endswith("int8")


@pytest.fixture
def shipped_box_and_mug(template_bundle, tmp_path, monkeypatch) -> Path:
    """A stand-in for chpf/assets/bundles with tiny box and mug bundles."""
    from tests.chpf.tracking.conftest import write_template_bundle

    root = tmp_path / "shipped"
    shutil.copytree(template_bundle, root / "box")
    write_template_bundle(root / "mug", name="mug")
    monkeypatch.setattr("chpf.tracking.demo.bundles_dir", lambda: root)
    return root


def test_demo_object_mug_tracks_the_shipped_mug_sequence(shipped_box_and_mug, tmp_path, capsys):
    from chpf.tracking.demo import ASSETS, shipped_bundle

    assert shipped_bundle() == shipped_box_and_mug / "box"  # the default stays the box
    assert shipped_bundle("mug") == shipped_box_and_mug / "mug"
    out = tmp_path / "demo_mug"
    argv = ["--demo", "--object", "mug", "--method", "srl", "--out", out, "--no-progress"]
    code, lines = _run(capsys, *argv, "--no-plot")
    assert code == 0 and lines[0].startswith("detections: ")
    settings = json.loads((out / "track_settings.json").read_text())
    assert Path(settings["dataset"]) == ASSETS / "demo" / "mug"
    rows = read_results_csv(out / "srl_mug-test.csv")
    assert len(rows) == 60 and {r.obj_id for r in rows} == {1}  # the mug's obj_id
    table = (out / "auc_table.txt").read_text()
    assert [line.split()[0] for line in table.splitlines()[2:]] == ["srl"]


def test_demo_object_refusals_are_one_line(shipped_box_and_mug, capsys, monkeypatch, tmp_path):
    line = _cli_error(capsys, monkeypatch, "--demo", "--object", "can", "--out", tmp_path / "a")
    assert "no shipped bundle for 'can'" in line and "box, mug" in line
    line = _cli_error(capsys, monkeypatch, "--object", "mug", "--dataset", tmp_path)
    assert "--object: only with --demo" in line
    argv = ["--demo", "--object", "mug", "--bundle", shipped_box_and_mug / "box"]
    assert "not both" in _cli_error(capsys, monkeypatch, *argv, "--out", tmp_path / "b")
