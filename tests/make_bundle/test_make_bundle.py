"""chpf-make-bundle: every stage on a tiny preset, a rerun does nothing, refusals."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from chpf.bundle import Bundle
from chpf.errors import ConfigError
from make_bundle.cli import main
from make_bundle.plan import parse_budget

ARGS = ["--object", "box", "--preset", "tiny", "--budget", "5m", "--no-progress", "--workers", "1"]


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("mb") / "box"
    assert main([*ARGS, "--out", str(out)]) == 0
    return out


def test_every_stage_writes_a_bundle_and_report(made: Path) -> None:
    Bundle.load(made)
    rep = (made / "report.md").read_text()
    for stage in ("ae_data", "pairs_data", "heldout", "train_ae", "codebook", "train_ch",
                  "export", "evaluate", "sequence", "track"):  # fmt: skip
        assert f"| {stage} |" in rep
    assert "chpf" in rep and "poserbpf" in rep
    # the report card: the figures, the visibility and scale-error bands among them
    for key in ("pairs.classifier.auc_hard", "pairs.classifier.auc_hard_lo",
                "pairs.classifier.auc_far",
                "pairs.classifier.auc_hard_by_visibility.0.3-0.6.auc",
                "pairs.classifier.auc_hard_by_scale_off.0.08+.n_pos",
                "ae.augmented_by_visibility.0.9-1.median_deg"):  # fmt: skip
        assert f"| {key} |" in rep, key
    assert (made / "contact_sheet.png").is_file()
    assert list(made.glob("track_*.png"))


def test_the_autoencoder_validates_on_crops_without_jitter(made: Path) -> None:
    """Its retrieval error (which picks best-*.ckpt) read the training crops' shift."""
    from data_gen.config import shifts_ae_targets
    from data_gen.shards import read_manifest

    work = made.parent / "box.work"
    cfg = yaml.safe_load(next((work / "run_ae").rglob("config.yaml")).read_text())
    assert Path(cfg["data"]["val_dir"]) == work / "ae_val"
    assert shifts_ae_targets(read_manifest(work / "ae")["config"])
    assert not shifts_ae_targets(read_manifest(work / "ae_val")["config"])


def test_rerun_does_nothing(made: Path, capsys: pytest.CaptureFixture) -> None:
    before = {p: os.stat(p).st_mtime_ns for p in made.rglob("*")}
    assert main([*ARGS, "--out", str(made)]) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert {p: os.stat(p).st_mtime_ns for p in made.rglob("*")} == before


def test_other_settings_refused(made: Path) -> None:
    with pytest.raises(ConfigError, match="other settings"):
        main([*ARGS, "--out", str(made), "--seed", "3"])


def test_mm_mesh_given_as_metres_is_refused(tmp_path: Path, capsys) -> None:
    mesh = trimesh.creation.box(extents=np.array([120.0, 80.0, 40.0]))  # millimetres
    path = tmp_path / "part.ply"
    mesh.export(path)
    with pytest.raises(SystemExit) as e:
        import sys

        from make_bundle.cli import cli

        old = sys.argv
        sys.argv = ["chpf-make-bundle", "--object", str(path), "--out", str(tmp_path / "b")]
        try:
            cli()
        finally:
            sys.argv = old
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "mm" in err
    assert not (tmp_path / "b.work").exists()


def test_a_mesh_file_makes_a_bundle_that_tracks_its_sequence(tmp_path: Path) -> None:
    """A mesh file has obj_id 0 in its bundle and the first free id (5) in the generated
    sequence: the track stage must track that one (it stopped the duck's 90-minute run)."""
    mesh = trimesh.creation.box(extents=np.array([0.08, 0.06, 0.04]))
    mesh.visual.vertex_colors = np.random.default_rng(0).integers(0, 255, (8, 4), np.uint8)
    mesh.export(tmp_path / "part.ply")
    args = [*ARGS[2:], "--object", str(tmp_path / "part.ply"), "--out", str(tmp_path / "b")]
    assert main(args) == 0
    assert Bundle.load(tmp_path / "b").obj_info.obj_id == 0
    tracked = (tmp_path / "b.work" / "track_stdout.txt").read_text()
    assert "chpf" in tracked and "poserbpf" in tracked


def test_parse_budget() -> None:
    assert parse_budget("90m") == 5400 and parse_budget("1h30m") == 5400
    assert parse_budget("45s") == 45 and parse_budget("10m") == 600
    with pytest.raises(ConfigError):
        parse_budget("soon")


def test_plan_scales_with_the_measured_rates() -> None:
    from make_bundle.measure import Rates
    from make_bundle.plan import format_plan, make_plan

    fast = make_plan(600, rates=Rates(500.0, 8.0, "bf16-mixed"))
    slow = make_plan(600, rates=Rates(100.0, 4.0, "32-true"))
    assert slow.pairs_n < fast.pairs_n and slow.ae_steps < fast.ae_steps
    assert slow.ch_steps < fast.ch_steps
    assert "| train_ae |" in format_plan(fast) and "| total |" in format_plan(fast)
    with pytest.raises(ConfigError, match="at least 5m"):
        make_plan(60)


def test_a_quiet_machines_probe_plans_the_recipes_pool() -> None:
    """The duck's quiet 90-minute run read 267 renders/s and composed pairs at the recipe's rate
    (592/s): its plan should hold the recipe's 120,000-render pool (it planned 72,072)."""
    from make_bundle.measure import Rates
    from make_bundle.plan import make_plan

    plan = make_plan(5400, rates=Rates(267.0, 13.26, "bf16-mixed"), spent_s=20.0)
    assert plan.pairs_pool == 120_000 and plan.pairs_n >= 600_000


@pytest.mark.parametrize("budget", [600, 5400])
def test_a_low_step_probe_does_not_cut_the_trainings_short(budget) -> None:
    """The probe read 0.28 steps/s where the training ran 0.65 (README): the step caps leave
    room for a few times the probed rate, and the trainings follow their max_time."""
    from make_bundle.measure import Rates
    from make_bundle.plan import AE_STEPS_PER_S, CH_STEPS_PER_S, make_plan

    plan = make_plan(budget, rates=Rates(157.0, 0.28, "bf16-mixed"))
    ch_rate = CH_STEPS_PER_S * 0.28 / AE_STEPS_PER_S
    assert plan.ae_steps >= 3 * 0.28 * plan.ae_time_s
    assert plan.ch_steps >= 3 * ch_rate * plan.ch_time_s


def test_both_trainings_schedule_their_lr_by_time(made: Path) -> None:
    for run in ("run_ae", "run_ch"):
        cfgs = list((made.parent / "box.work" / run).rglob("config.yaml"))
        assert cfgs, run
        assert yaml.safe_load(cfgs[0].read_text())["model"]["lr_schedule_by_time"] is True
    rep = (made / "report.md").read_text()
    assert "4 steps in" in rep  # the stage table says how many steps each training ran


@pytest.mark.parametrize("budget", [300, 600, 5400])
@pytest.mark.parametrize("rates", [None, (500.0, 8.0), (60.0, 2.0)])
def test_the_plan_accounts_for_every_stage_within_the_budget(budget, rates) -> None:
    from make_bundle.measure import Rates
    from make_bundle.plan import MARGIN, OVERHEAD_S, make_plan

    r = Rates(*rates, "32-true") if rates else None
    try:
        plan = make_plan(budget, rates=r, spent_s=20.0)
    except ConfigError as err:  # too short for this machine: said so, not overrun
        assert budget == 300 and "fixed costs" in str(err)
        return
    assert set(plan.est_s) == set(plan.sizes())  # every stage has an estimate
    assert all(plan.est_s[k] >= v for k, v in OVERHEAD_S.items())
    assert plan.est_s["train_ae"] >= plan.ae_time_s and plan.est_s["train_ch"] >= plan.ch_time_s
    assert 20.0 + sum(plan.est_s.values()) <= budget * (1 - MARGIN) + 1


def test_training_is_shortened_to_end_by_the_deadline(tmp_path: Path) -> None:
    import time

    from make_bundle.plan import OVERHEAD_S, TRAIN_MIN_S, make_plan
    from make_bundle.stages import Ctx

    plan = make_plan(600)
    ctx = Ctx("box", "m", tmp_path, tmp_path, plan, 1, 0, [], False, tmp_path)
    assert ctx.train_seconds("train_ae", plan.ae_time_s) == plan.ae_time_s  # no deadline
    late = plan.after("train_ae") + OVERHEAD_S["train_ae"] + 40
    ctx.deadline = time.monotonic() + late
    assert 35 <= ctx.train_seconds("train_ae", plan.ae_time_s) <= 40
    assert "max_time" in ctx.notes["train_ae"]
    ctx.deadline = time.monotonic()  # already late: the floor
    assert ctx.train_seconds("train_ch", plan.ch_time_s) == TRAIN_MIN_S


def test_training_takes_the_time_earlier_stages_saved(tmp_path: Path) -> None:
    """The mug's pairs took 10.2 of their planned 20.1 minutes: the trainings get that time
    (the autoencoder its share of the two, the classifier the rest), the margin stays free."""
    import time

    from make_bundle.plan import MARGIN, OVERHEAD_S, make_plan
    from make_bundle.stages import Ctx

    plan = make_plan(5400)
    ctx = Ctx("box", "m", tmp_path, tmp_path, plan, 1, 0, [], False, tmp_path)
    on_time = plan.after("train_ae") + OVERHEAD_S["train_ae"] + plan.ae_time_s
    ctx.deadline = time.monotonic() + on_time + 5400 * MARGIN / 2
    assert abs(ctx.train_seconds("train_ae", plan.ae_time_s) - plan.ae_time_s) <= 1  # on time
    ctx.notes.clear()
    ctx.deadline += 600  # ten minutes ahead
    share = plan.ae_time_s / (plan.ae_time_s + plan.ch_time_s)
    got = ctx.train_seconds("train_ae", plan.ae_time_s)
    assert abs(got - (plan.ae_time_s + 600 * share)) <= 2
    assert "ran early" in ctx.notes["train_ae"]
    on_time = plan.after("train_ch") + OVERHEAD_S["train_ch"] + plan.ch_time_s
    ctx.deadline = time.monotonic() + on_time + 5400 * MARGIN / 2 + 300
    assert abs(ctx.train_seconds("train_ch", plan.ch_time_s) - (plan.ch_time_s + 300)) <= 2
    tiny = Ctx("box", "m", tmp_path, tmp_path, make_plan(300, "tiny"), 1, 0, [], False, tmp_path)
    tiny.deadline = time.monotonic() + 10_000
    assert tiny.train_seconds("train_ae", 60) == 60  # the tiny preset: as planned


def test_no_progress_turns_off_the_trainings_bars(made: Path) -> None:
    for run in ("run_ae", "run_ch"):
        (cfg,) = (made.parent / "box.work" / run).rglob("config.yaml")
        assert yaml.safe_load(cfg.read_text())["trainer"]["enable_progress_bar"] is False


def test_an_interrupted_stage_restarts_cleanly(made: Path, capsys) -> None:
    work = made.parent / "box.work"
    (work / "done" / "track.json").unlink()  # as if killed during tracking
    (work / "track" / "stale.txt").write_text("half-written")
    assert main([*ARGS, "--out", str(made)]) == 0
    out = capsys.readouterr().out
    assert "| track | CH-PF + PoseRBPF |" in out and "| export | K = 64 |" in out
    assert "== track" in out and "== export" not in out
    assert not (work / "track" / "stale.txt").exists() and (work / "done" / "track.json").is_file()


def _shard_files(work: Path) -> dict[Path, int]:
    return {p: p.stat().st_mtime_ns for d in ("ae", "pairs", "ae_test", "pairs_test")
            for p in sorted((work / d).glob("shard_*.npz"))}  # fmt: skip


def test_shard_jobs_then_a_final_run_make_the_bundle(tmp_path: Path, capsys) -> None:
    out = tmp_path / "box"
    work = tmp_path / "box.work"
    assert main([*ARGS, "--out", str(out), "--shard", "0", "--num-shards", "2"]) == 0
    first = _shard_files(work)
    names = {p.name for p in first if p.parent.name == "pairs"}
    assert names == {"shard_00000.npz", "shard_00002.npz"}  # 4 shards of 16: job 0's two
    assert not (work / "run_ae").exists() and not list((work / "done").glob("*.json"))
    assert main([*ARGS, "--out", str(out), "--shard", "1", "--num-shards", "2"]) == 0
    both = _shard_files(work)
    assert {p.name for p in both if p.parent.name == "pairs"} == {
        f"shard_{i:05d}.npz" for i in range(4)
    }
    assert all(both[p] == t for p, t in first.items())  # job 1 left job 0's shards alone
    assert "without --shard" in capsys.readouterr().out
    assert main([*ARGS, "--out", str(out)]) == 0
    assert _shard_files(work) == both  # the final run made no shard again, it trained
    Bundle.load(out)
    assert (out / "report.md").is_file()


@pytest.mark.parametrize("shard", [["--shard", "2", "--num-shards", "2"], ["--num-shards", "2"]])
def test_a_bad_shard_is_one_line_and_exit_2(tmp_path: Path, capsys, shard) -> None:
    import sys

    from make_bundle.cli import cli

    old = sys.argv
    sys.argv = ["chpf-make-bundle", *ARGS, "--out", str(tmp_path / "b"), *shard]
    try:
        with pytest.raises(SystemExit) as e:
            cli()
    finally:
        sys.argv = old
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--shard" in err
    assert not (tmp_path / "b.work").exists()


def test_trainer_options_reach_both_trainings(tmp_path: Path, capfd) -> None:
    # as tests/training/test_ddp.py for chpf-train: two CPU processes (gloo) per training
    ddp = ["--trainer.strategy", "ddp", "--trainer.devices", "2", "--trainer.accelerator", "cpu"]
    out = tmp_path / "box"
    assert main([*ARGS, "--out", str(out), *ddp]) == 0
    logs = capfd.readouterr()
    for run in ("run_ae", "run_ch"):
        (cfg,) = (tmp_path / "box.work" / run).rglob("config.yaml")
        trainer = yaml.safe_load(cfg.read_text())["trainer"]
        assert (trainer["strategy"], str(trainer["devices"]), trainer["accelerator"]) == (
            "ddp", "2", "cpu"
        )  # fmt: skip
    assert (logs.out + logs.err).count("MEMBER: 2/2") >= 2  # a world of two, each training
    Bundle.load(out)


def test_a_mesh_off_its_origin_makes_a_bundle_that_reports_poses_in_its_frame(
    tmp_path: Path,
) -> None:
    """A CAD-like part whose origin is at its base: every stage runs on the centred part, the
    bundle records where the centre is in the file, and its test sequence (the file's frame,
    as a user's dataset would be) passes the bundle's dataset check and is tracked."""
    from chpf.objects import load_mesh, object_fingerprint

    mesh = trimesh.creation.box(extents=np.array([0.12, 0.08, 0.05]))
    rng = np.random.default_rng(0)
    mesh.visual.face_colors = rng.integers(0, 256, (len(mesh.faces), 4), dtype=np.uint8) | 255
    mesh.apply_translation((0.0, 0.0, 0.025))  # the origin on its bottom face
    path = tmp_path / "obj_000007.ply"
    mesh.export(path)
    out = tmp_path / "part"
    args = [a if a != "box" else str(path) for a in ARGS]
    assert main([*args, "--out", str(out)]) == 0
    info = Bundle.load(out).obj_info
    np.testing.assert_allclose(info.file_offset, (0.0, 0.0, 0.025), atol=1e-9)
    assert info.obj_id == 7 and info.fingerprint == object_fingerprint(load_mesh(path))
    rep = (out / "report.md").read_text()
    assert "| track |" in rep and "poserbpf" in rep and "| (0.0, 0.0, 25.0) mm |" in rep


def test_the_held_out_pairs_hold_enough_hard_negatives_to_pin_their_auc() -> None:
    """About 1,000 hard negatives in the default budget's held-out pairs: the hard-negative
    AUC's 95 % interval is then about 0.02 wide (the duck's: 0.926-0.944; 0.906-0.946 with the
    260 of 2,000 pairs)."""
    from make_bundle.plan import make_plan

    root = Path(__file__).resolve().parents[2]
    mix = yaml.safe_load((root / "configs" / "gen_default.yaml").read_text())["pairs"]
    plan = make_plan(5400)
    assert plan.test_n * (1 - mix["positive_share"]) * mix["hard_negative_share"] >= 1000


def test_the_held_out_sets_are_evaluated_whole(tmp_path: Path, monkeypatch) -> None:
    """training.evaluate reads 4,000 samples unless told otherwise: the held-out sets are
    larger, and only the training family is subsampled."""
    import training.evaluate
    from make_bundle import stages
    from make_bundle.plan import make_plan

    calls: list[list[str]] = []
    monkeypatch.setattr(training.evaluate, "main", lambda argv: calls.append(argv) or 0)
    ctx = stages.Ctx(
        obj="box", unit="m", out=tmp_path / "b", work=tmp_path / "b.work", plan=make_plan(5400),
        workers=1, seed=0, trainer_args=[], progress=False, cache=tmp_path / "cache",
    )  # fmt: skip
    stages.evaluate(ctx)
    whole = {
        Path(a[a.index("--data" if "--data" in a else "--pairs") + 1]).name: (
            "--max-samples" in a and a[a.index("--max-samples") + 1] == "0"
        )
        for a in calls
    }
    assert whole == {"ae_test": True, "pairs": False, "pairs_test": True}
