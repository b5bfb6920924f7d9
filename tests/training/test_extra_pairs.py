"""Extra classifier pairs against a frozen candidate codebook (training.extra_pairs)."""

from __future__ import annotations

from pathlib import Path

import lightning.pytorch as pl
import numpy as np
import pytest
import torch

from chpf.errors import ConfigError
from chpf.geometry import RotationGrid, random_rotations
from data_gen.config import default_config
from data_gen.rotations import grid_spacing_deg
from training.checkpoints import load_autoencoder, load_classifier
from training.cli import main
from training.codebook import codebook_arrays, save_codebook
from training.data import PairDataModule
from training.extra_pairs import CandidateCodebook
from training.lit import CHLitModule
from training.model_config import ClassifierConfig, EncoderConfig

ROOT = Path(__file__).resolve().parents[2]


def test_draws_follow_the_data_recipe() -> None:
    """Positives within the perturbation bound plus the grid spacing, negatives at least
    20 deg away with about 30 % of them hard (20-45 deg), crops without the object all
    negative."""
    grid = RotationGrid.uniform(2000)
    pairs = default_config()["pairs"]
    emb = torch.randn(2000, 4)
    book = CandidateCodebook(grid.rotations, emb, pairs, None)
    # a candidate of the same grid finds its own view's embedding
    assert torch.equal(book.embed(grid.rotations[[3, 1999, 7]]), emb[[3, 1999, 7]])
    rng = np.random.default_rng(0)
    R = random_rotations(400, rng)
    shows = np.ones(400, bool)
    shows[:40] = False
    idx, label, angle = book.draw(R, shows, 6, rng)
    assert idx.shape == label.shape == angle.shape == (400, 6)
    assert np.all(label[:40] == 1)
    pos = label[40:] == 0
    assert 0.45 < pos.mean() < 0.55
    spacing = grid_spacing_deg(grid)["max"]
    assert angle[40:][pos].max() <= pairs["pos_rot_max_deg"] + spacing
    neg = angle[40:][~pos]
    assert neg.min() >= pairs["neg_min_angle_deg"]
    assert 0.25 < np.mean(neg <= 45.0) < 0.45  # hard share 0.3 (+ random draws that land there)
    # each index is the grid entry of the angle reported
    R_c = grid.rotations[idx[40:, 0]]
    cos = (np.trace(np.swapaxes(R_c, 1, 2) @ R[40:], axis1=1, axis2=2) - 1) / 2
    np.testing.assert_allclose(np.degrees(np.arccos(np.clip(cos, -1, 1))), angle[40:, 0], atol=1e-3)


def test_extra_pairs_train_the_observed_branch_only(
    ae_dir: Path, pairs_dir: Path, tmp_path: Path, pattern_images, monkeypatch
) -> None:
    """With freeze_candidate + extra_pairs the candidate branch stays the autoencoder's encoder
    while the observed branch and the head learn."""
    monkeypatch.chdir(tmp_path)
    ae_args = ["ae", "--config", str(ROOT / "configs" / "train_ae_tiny.yaml")]
    ae_args += ["--data.data_dir", str(ae_dir), "--trainer.default_root_dir", str(tmp_path / "ae")]
    assert main(ae_args) == 0
    ae_ckpt = tmp_path / "ae" / "checkpoints" / "last.ckpt"
    imgs, R = pattern_images(64, 16, seed=5)
    save_codebook(tmp_path / "cb.npz", codebook_arrays(R, imgs))
    out = tmp_path / "ch"
    args = ["ch", "--config", str(ROOT / "configs" / "train_ch_tiny.yaml")]
    args += ["--data.data_dir", str(pairs_dir), "--trainer.default_root_dir", str(out)]
    args += ["--model.init_from_ae", str(ae_ckpt), "--model.freeze_candidate", "true"]
    args += ["--model.extra_pairs", "4", "--model.candidate_codebook", str(tmp_path / "cb.npz")]
    assert main(args) == 0
    ch, info = load_classifier(out / "checkpoints" / "last.ckpt")
    ae, _ = load_autoencoder(ae_ckpt)
    assert not ch.share_twin and info["model_config"]["share_twin"] is False
    for k, v in ae.encoder.state_dict().items():
        assert torch.equal(ch.cand_encoder.state_dict()[k], v), k
    moved = [k for k, v in ae.encoder.state_dict().items()
             if not torch.equal(ch.obs_encoder.state_dict()[k], v)]  # fmt: skip
    assert moved
    # the codebook is read and checked: crops of another size are refused in one line
    small, R8 = pattern_images(8, 8, seed=6)
    save_codebook(tmp_path / "cb8.npz", codebook_arrays(R8, small))
    bad = [*args[:-1], str(tmp_path / "cb8.npz"), "--trainer.default_root_dir", str(tmp_path / "b")]
    with pytest.raises(ConfigError, match=r"cb8\.npz: codebook crop size 8 differs"):
        main(bad)


def test_refreshed_candidates_follow_the_trained_branch(
    pairs_dir: Path, tmp_path: Path, pattern_images
) -> None:
    """With a trained (shared) candidate branch the extra pairs' candidate embeddings are
    recomputed every candidate_refresh_steps steps: after training they are the codebook
    views' embeddings by the branch as it was at the last refresh."""
    imgs, R = pattern_images(64, 16, seed=5)
    save_codebook(tmp_path / "cb.npz", codebook_arrays(R, imgs))
    lit = CHLitModule(
        ClassifierConfig(EncoderConfig(channels=(8, 16), kernel=3, embedding_dim=16, size=16)),
        lr=3e-3,
        warmup_steps=0,
        extra_pairs=4,
        candidate_codebook=str(tmp_path / "cb.npz"),
        candidate_refresh_steps=3,
    )
    seen: dict[int, np.ndarray] = {}

    class BranchSnapshots(pl.Callback):  # runs before the module's own hook
        def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
            seen[trainer.global_step] = module.embed_crops(module.model.embed_cand, imgs)

    trainer = pl.Trainer(
        max_steps=5,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        callbacks=[BranchSnapshots()],
    )
    trainer.fit(lit, datamodule=PairDataModule(str(pairs_dir), batch_size=8))
    table = lit._candidates.embeddings.numpy()
    assert not np.allclose(seen[0], seen[3], atol=1e-4)  # the branch trained
    np.testing.assert_allclose(table, seen[3], atol=1e-6)  # refreshed at step 3, not at 4
    assert not np.allclose(table, seen[4], atol=1e-6)


def test_crops_cut_at_a_wrong_depth_meet_misaligned_hypotheses_only(
    pattern_images, tmp_path: Path
) -> None:
    """A scale negative's observed crop (depth_ratio off by more than the data's aligned
    bound) is wrong whatever the hypothesis: its extra pairs are drawn as for any crop, about
    half of them near the true orientation, and all are misaligned; the others keep their
    positives."""
    imgs, R = pattern_images(16, 16, seed=5)
    save_codebook(tmp_path / "cb.npz", codebook_arrays(R, imgs))
    lit = CHLitModule(
        ClassifierConfig(EncoderConfig(channels=(8, 16), kernel=3, embedding_dim=16, size=16)),
        extra_pairs=8,
        candidate_codebook=str(tmp_path / "cb.npz"),
        candidate_refresh_steps=3,
    )
    pairs = default_config()["pairs"] | {"scale_negative_share": 0.3}
    lit._candidates = CandidateCodebook(R, torch.randn(16, 16), pairs, None)
    lit._data_pairs_cfg = pairs
    lit._pair_rng = np.random.default_rng(0)
    lit._augment_rng = np.random.default_rng(1)
    drawn = {}
    draw = lit._candidates.draw

    def spy(R_obs, shows, m, rng, wrong_depth):
        drawn["out"] = draw(R_obs, shows, m, rng, wrong_depth)
        return drawn["out"]

    lit._candidates.draw = spy
    ratio = np.array([1.0, 1.02, 0.8, 1.3, 1.0, 0.95, 1.25, 1.0], np.float32)
    batch = {
        "obs_rgb": torch.from_numpy(imgs[:8]),
        "cand_rgb": torch.from_numpy(imgs[8:]),
        "aligned": torch.zeros(8, dtype=torch.uint8),
        "obs_R_allo": torch.from_numpy(R[:8].astype(np.float32)),
        "cand_R_allo": torch.from_numpy(R[8:].astype(np.float32)),
        "angle_deg": torch.full((8,), 90.0),
        "visib_fract": torch.ones(8),
        "depth_ratio": torch.from_numpy(ratio),
    }
    lit._step(batch, train=True)
    labels, angles = drawn["out"][1], drawn["out"][2]  # (8, m), 1 = misaligned
    off = np.abs(np.log(ratio)) >= 0.06
    assert np.all(labels[off] == 1)
    assert (angles[off] < 20).sum() > 4  # right orientation, wrong depth: the hard case
    assert np.all((labels[~off] == 0) == (angles[~off] < 20)) and (labels[~off] == 0).sum() > 4
