"""Training-time occluders and appearance changes (training.batch_augment)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from chpf.config_schema import load
from chpf.errors import ConfigError
from training.batch_augment import (
    BatchAugment,
    add_occluders,
    augment_batch,
    change_appearance,
    occluder_mask,
    reframe,
)


def _crops(b: int = 16, s: int = 32) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    return torch.rand(b, 3, s, s, generator=g)


def test_occluder_masks_cover_part_of_the_crop() -> None:
    rng = np.random.default_rng(0)
    covered = [occluder_mask(64, 0.2, rng).mean() for _ in range(200)]
    assert np.mean(np.array(covered) > 0) > 0.97 and max(covered) < 0.9  # rarely off the crop
    assert 0.05 < np.mean(covered) < 0.3  # about the asked bounding-box area, less for shapes


def test_occluders_change_only_the_drawn_share_of_crops() -> None:
    x = _crops(64)
    cfg = BatchAugment(occluder_share=0.5)
    y = add_occluders(x, cfg, np.random.default_rng(1))
    changed = (y != x).flatten(1).any(1)
    assert 16 < int(changed.sum()) < 48
    assert torch.equal(y[~changed], x[~changed]) and y.min() >= 0 and y.max() <= 1
    again = add_occluders(x, cfg, np.random.default_rng(1))
    assert torch.equal(y, again)  # the rng decides everything


def test_off_by_default_and_identity() -> None:
    x = _crops()
    assert not BatchAugment().active
    assert augment_batch(x, BatchAugment(), np.random.default_rng(0)) is x


def test_colour_cast_darkens_channels_and_blur_smooths() -> None:
    x = _crops(32)
    cast = change_appearance(x, BatchAugment(colour_cast=0.5), np.random.default_rng(0))
    ratio = cast.mean(dim=(2, 3)) / x.mean(dim=(2, 3))
    assert ratio.max() <= 1.0 + 1e-6 and ratio.min() < 0.8
    blur = BatchAugment(blur_share=1.0, blur_sigma=(1.5, 1.5))
    y = change_appearance(x, blur, np.random.default_rng(0))

    def roughness(t: torch.Tensor) -> float:
        return float((t[..., 1:] - t[..., :-1]).abs().mean())

    assert roughness(y) < 0.5 * roughness(x)
    assert y.mean() == pytest.approx(float(x.mean()), abs=0.01)  # blurring keeps the mean


def test_reframing_zooms_and_shifts_each_crop_as_drawn() -> None:
    """A bright square in the middle of each crop comes out larger or smaller by the drawn zoom
    and moved by the drawn shift (crop sides, x then y)."""
    b, s = 24, 64
    x = torch.zeros(b, 3, s, s)
    x[:, :, 24:40, 24:40] = 1.0
    cfg = BatchAugment(zoom_sigma=0.2, shift_sigma=0.05)
    y = reframe(x, cfg, np.random.default_rng(3))
    replay = np.random.default_rng(3)
    zoom = np.exp(replay.normal(0.0, 0.2, b))
    shift = replay.normal(0.0, 0.05, (b, 2))
    mass = y[:, 0].sum(dim=(1, 2)).numpy()
    np.testing.assert_allclose(mass / 256.0, zoom**2, rtol=0.03)
    coords = torch.arange(s, dtype=torch.float32) + 0.5
    cx = (y[:, 0].sum(1) * coords).sum(1).numpy() / mass
    cy = (y[:, 0].sum(2) * coords).sum(1).numpy() / mass
    np.testing.assert_allclose(cx - 32.0, shift[:, 0] * s, atol=0.1)
    np.testing.assert_allclose(cy - 32.0, shift[:, 1] * s, atol=0.1)
    assert BatchAugment(zoom_sigma=0.05).active
    assert reframe(x, BatchAugment(), np.random.default_rng(0)) is x


def test_ranges_are_checked() -> None:
    with pytest.raises(ConfigError, match="brightness"):
        load(BatchAugment, data={"brightness": [1.5, 0.5]}, where="t")
    with pytest.raises(ConfigError, match="occluder_share"):
        load(BatchAugment, data={"occluder_share": 1.5}, where="t")


def test_classifier_trains_on_augmented_crops(
    pairs_dir, tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """chpf-train ch draws the configured augmentation onto every training batch's observed
    crops (not the validation's) and records it in the checkpoint."""
    import training.lit as lit
    from training.cli import main

    seen: list[BatchAugment] = []

    def spy(x: torch.Tensor, cfg: BatchAugment, rng: np.random.Generator) -> torch.Tensor:
        seen.append(cfg)
        return augment_batch(x, cfg, rng)

    monkeypatch.setattr(lit, "augment_batch", spy)
    monkeypatch.chdir(tmp_path)
    cfg = str(lit.Path(__file__).resolve().parents[2] / "configs" / "train_ch_tiny.yaml")
    args = ["ch", "--config", cfg, "--data.data_dir", str(pairs_dir)]
    args += ["--trainer.default_root_dir", str(tmp_path / "runs")]
    args += ["--model.augment.occluder_share", "1.0", "--model.augment.colour_cast", "0.3"]
    assert main(args) == 0
    assert len(seen) == 4 and all(c.occluder_share == 1.0 and c.active for c in seen)
    ckpt = torch.load(tmp_path / "runs" / "checkpoints" / "last.ckpt", weights_only=False)
    assert ckpt["hyper_parameters"]["augment"]["colour_cast"] == 0.3


def test_augment_config_turns_it_on_over_the_default_recipe(tmp_path) -> None:
    """configs/train_ch.yaml leaves the augmentation off (the shipped classifier);
    configs/train_ch_augment.yaml on top of it turns it on."""
    from pathlib import Path

    from training.cli import make_cli

    root = Path(__file__).resolve().parents[2] / "configs"
    base = ["--model.init_from_ae", "null", "--model.extra_pairs", "0"]
    base += ["--trainer.default_root_dir", str(tmp_path)]

    def augment(*configs: str) -> BatchAugment:
        args = [a for c in configs for a in ("--config", str(root / c))]
        ns = make_cli("ch", [*args, *base]).config["model"]["augment"]
        return BatchAugment(**vars(ns))

    assert not augment("train_ch.yaml").active
    on = augment("train_ch.yaml", "train_ch_augment.yaml")
    assert on.active and on.occluder_share == 0.5 and on.colour_cast == 0.35
