"""Model shapes, configs, and that AE and CH losses go down on a fixed batch."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torch import nn

from chpf.config_schema import to_dict
from chpf.errors import ConfigError
from training.lit import AELitModule, CHLitModule, bootstrapped_l2
from training.model_config import (
    ClassifierConfig,
    EncoderConfig,
    HeadConfig,
    PairsMix,
    from_stored,
)
from training.models import Autoencoder, CHClassifier, Encoder, NormalizedEmbedder, Preprocess

TINY_KEYS = {"channels": [8, 16], "kernel": 3, "embedding_dim": 16, "size": 16}
TINY = EncoderConfig(channels=(8, 16), kernel=3, embedding_dim=16, size=16)


def tiny(**changes) -> EncoderConfig:
    return dataclasses.replace(TINY, **changes)


def test_shapes_and_preprocess() -> None:
    crops = torch.randint(0, 256, (5, 16, 16, 3), dtype=torch.uint8)
    x = Preprocess()(crops)
    assert x.shape == (5, 3, 16, 16) and x.dtype == torch.float32
    assert torch.allclose(x[2, 1, 3, 4], crops[2, 3, 4, 1].float() / 255)
    assert x.is_contiguous(memory_format=torch.channels_last)
    recon, z = Autoencoder(TINY)(x)
    assert recon.shape == x.shape and z.shape == (5, 16)
    assert float(recon.detach().min()) >= 0 and float(recon.detach().max()) <= 1
    emb = NormalizedEmbedder(Encoder(TINY))(crops)
    assert torch.allclose(emb.norm(dim=1), torch.ones(5), atol=1e-5)
    enc = Encoder(TINY)
    assert to_dict(enc.config) == {
        **TINY_KEYS,
        "activation": "relu",
        "decoder_norm": "none",
        "decoder_channels": None,
    }


def test_classifier_twin_sharing() -> None:
    shared = CHClassifier(ClassifierConfig(TINY))
    assert shared.obs_encoder is shared.cand_encoder and not shared.shares_ae_encoder
    twin = CHClassifier(ClassifierConfig(TINY, share_twin=False))
    assert twin.obs_encoder is not twin.cand_encoder
    x = torch.rand(3, 3, 16, 16)
    assert shared(x, x).shape == (3,)
    # the shared forward (one batched pass) equals separate branch passes
    ref = shared.head(shared.embed_obs(x), shared.embed_cand(x[[2, 0, 1]]))
    assert torch.allclose(shared(x, x[[2, 0, 1]]), ref, atol=1e-5)


@pytest.mark.parametrize("reduction", [1, 4])
def test_refine_stages_start_as_the_identity_and_train(reduction: int) -> None:
    """Residual blocks added to an encoder compute what it computed (zero-initialised), their
    last convolution gets gradients, a bottleneck's 3x3 convolution is `reduction` times
    narrower, and the stored config without the keys builds no blocks. Seeded: a bottleneck
    of TINY's widths has 2-4 channels, and on 27 of 200 random draws its ReLU passed nothing
    back (no gradient to check)."""
    torch.manual_seed(0)
    base = Encoder(TINY)
    refined = Encoder(TINY, refine_stages=2, refine_reduction=reduction)
    missing, unexpected = refined.load_state_dict(base.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("refine.") for k in missing)
    x = torch.rand(4, 3, 16, 16)
    assert torch.equal(refined(x), base(x))
    refined(x).square().sum().backward()
    convs = [[m for m in b.modules() if isinstance(m, nn.Conv2d)] for b in refined.refine.values()]
    assert all(float(c[-1].weight.grad.abs().sum()) > 0 for c in convs)
    widths = [c[len(c) // 2].out_channels for c in convs]  # the 3x3 convolution's
    assert widths == [w // reduction for w in TINY.channels[-2:]]
    ch = CHClassifier(ClassifierConfig(TINY, refine_stages=1))
    assert set(ch.obs_encoder.refine) == {"1"} and ch.obs_encoder is ch.cand_encoder
    old = from_stored(ClassifierConfig, {"encoder": TINY_KEYS}, "old.ckpt")
    assert old.refine_stages == 0 and not CHClassifier(old).obs_encoder.refine


def test_bad_configs() -> None:
    with pytest.raises(ConfigError, match="size: 20 is not divisible"):
        EncoderConfig(channels=(8, 16, 32), size=20)
    with pytest.raises(ConfigError, match=r"x.ckpt: unknown key model_config\.chanels"):
        from_stored(EncoderConfig, {"chanels": [8]}, "x.ckpt")
    with pytest.raises(ConfigError, match="kernel: must be odd"):
        EncoderConfig(kernel=4)
    with pytest.raises(ConfigError, match="channels: 0 is out of range"):
        EncoderConfig(channels=(8, 0))
    with pytest.raises(ConfigError, match="hidden: 0 is out of range"):
        HeadConfig(hidden=(0, 8))
    with pytest.raises(ConfigError, match="freeze_encoder"):
        CHLitModule(ClassifierConfig(TINY), freeze_encoder=True)
    with pytest.raises(ConfigError, match="freeze_candidate needs init_from_ae"):
        CHLitModule(ClassifierConfig(TINY), freeze_candidate=True)
    with pytest.raises(ConfigError, match="extra_pairs needs a candidate_codebook"):
        CHLitModule(ClassifierConfig(TINY), extra_pairs=4)
    with pytest.raises(ConfigError, match="candidate_refresh_steps is for a trained"):
        CHLitModule(ClassifierConfig(TINY), candidate_refresh_steps=10, freeze_encoder=True)
    with pytest.raises(TypeError, match="hard_share"):
        PairsMix(hard_share=0.5)
    with pytest.raises(ConfigError, match=r"hard_negative_share: 1.5 is out of range \[0.0, 1.0\]"):
        PairsMix(hard_negative_share=1.5)
    with pytest.raises(ConfigError, match=r"x.ckpt: model_config\.activation: expected one of"):
        from_stored(EncoderConfig, {"activation": "gelu"}, "x.ckpt")
    with pytest.raises(ConfigError, match=r"model_config\.encoder\.decoder_norm: expected one"):
        from_stored(ClassifierConfig, {"encoder": {"decoder_norm": "layer"}}, "x.ckpt")
    with pytest.raises(ConfigError, match="decoder_channels: must be 1 to 2 sizes"):
        tiny(decoder_channels=(8, 8, 8))
    with pytest.raises(ConfigError, match="refine_stages: the encoder has 2 stages"):
        ClassifierConfig(TINY, refine_stages=3)
    with pytest.raises(ConfigError, match="refine_stages: must be 0"):
        ClassifierConfig(TINY, refine_stages=1, shares_ae_encoder=True)


def test_activation_and_decoder_norm_options() -> None:
    """leaky_relu reaches the encoder and the decoder; decoder_norm adds batch norms to the
    decoder only; configs without the keys (older checkpoints) build the plain ReLU network."""
    plain = Autoencoder(from_stored(EncoderConfig, TINY_KEYS, "old.ckpt"))
    leaky = Autoencoder(tiny(activation="leaky_relu", decoder_norm="batch"))
    kinds = {type(m) for m in plain.modules()}
    assert torch.nn.ReLU in kinds and torch.nn.LeakyReLU not in kinds
    assert torch.nn.BatchNorm2d not in kinds
    assert not any(isinstance(m, torch.nn.ReLU) for m in leaky.modules())
    assert any(isinstance(m, torch.nn.LeakyReLU) for m in leaky.encoder.modules())
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in leaky.encoder.modules())
    assert sum(isinstance(m, torch.nn.BatchNorm2d) for m in leaky.decoder.modules()) == 2
    assert leaky(torch.rand(2, 3, 16, 16))[0].shape == (2, 3, 16, 16)


def test_decoder_channels_set_the_decoder_widths_only() -> None:
    """decoder_channels narrows the decoder (from the smallest resolution up); the encoder, which
    is what gets exported, is the same network as with the mirrored decoder."""
    narrow = Autoencoder(tiny(decoder_channels=(6, 4)))
    mirrored = Autoencoder(TINY)
    widths = [m.out_channels for m in narrow.decoder.modules() if hasattr(m, "out_channels")]
    assert widths == [4, 4, 3]  # 6 -> 4 (8x8), 4 -> 4 (16x16), output conv to RGB
    assert narrow.decoder.fc.out_features == 6 * 4 * 4
    shapes = {k: v.shape for k, v in narrow.encoder.state_dict().items()}
    assert shapes == {k: v.shape for k, v in mirrored.encoder.state_dict().items()}
    assert narrow(torch.rand(2, 3, 16, 16))[0].shape == (2, 3, 16, 16)


@pytest.mark.filterwarnings("ignore:You are trying to `self.log\\(\\)`")
def test_a_shorter_decoder_reconstructs_the_area_averaged_crop_at_half_size(
    pattern_images,
) -> None:
    """One decoder width fewer than encoder stages stops one upsampling early: the training
    step compares a half-size reconstruction with the 2x2-averaged target (the full-size layers
    are most of a step's work) and still learns; the encoder is unchanged."""
    torch.manual_seed(0)
    short = Autoencoder(tiny(decoder_channels=(6,)))
    x = torch.rand(2, 3, 16, 16)
    assert short.decoder.out_size == 8 and short(x)[0].shape == (2, 3, 8, 8)
    assert torch.allclose(short.recon_target(x)[0, :, 0, 0], x[0, :, :2, :2].mean((1, 2)))
    full = Autoencoder(TINY)
    assert full.recon_target(x) is x
    shapes = {k: v.shape for k, v in full.encoder.state_dict().items()}
    assert shapes == {k: v.shape for k, v in short.encoder.state_dict().items()}
    img, _ = pattern_images(16)
    target = torch.from_numpy(img)
    lit = AELitModule(tiny(decoder_channels=(6,)), lr=1e-2, warmup_steps=0)
    opt = torch.optim.Adam(lit.parameters(), lr=1e-2)
    losses = []
    for _ in range(50):
        loss = lit.training_step({"input_rgb": target, "target_rgb": target}, 0)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]


def test_ae_loss_goes_down_on_fixed_batch(pattern_images) -> None:
    torch.manual_seed(0)
    img, _ = pattern_images(16)
    target = torch.from_numpy(img)
    noisy = (target.short() + torch.randint(-30, 31, target.shape)).clamp(0, 255).to(torch.uint8)
    batch = {"input_rgb": noisy, "target_rgb": target}
    lit = AELitModule(TINY, lr=1e-2, warmup_steps=0)
    opt = torch.optim.Adam(lit.parameters(), lr=1e-2)
    losses = []
    for _ in range(50):
        loss = _ae_loss(lit, batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]


def _ae_loss(lit: AELitModule, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    recon, _ = lit.model(lit._images(batch, "input_rgb"))
    return bootstrapped_l2(recon, lit._images(batch, "target_rgb"), 0.25)


def test_ch_loss_goes_down_on_fixed_batch() -> None:
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(1)
    n = 16
    obs = torch.randint(0, 256, (n, 16, 16, 3), generator=g, dtype=torch.uint8)
    cand = obs.clone()
    aligned = torch.tensor([1, 0] * (n // 2), dtype=torch.uint8)
    cand[aligned == 0] = torch.randint(0, 256, (n // 2, 16, 16, 3), generator=g, dtype=torch.uint8)
    angle = torch.where(aligned == 1, 5.0, 90.0)
    batch = {"obs_rgb": obs, "cand_rgb": cand, "aligned": aligned, "angle_deg": angle}
    batch["visib_fract"] = torch.ones(n)
    lit = CHLitModule(ClassifierConfig(TINY, HeadConfig(hidden=(32, 16))), lr=3e-3)
    opt = torch.optim.Adam(lit.parameters(), lr=3e-3)
    losses = []
    for _ in range(40):
        loss, _, _ = lit._step(batch, train=True)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]
    assert np.isfinite(losses).all()


def test_checkpoint_of_an_older_version_loads(tmp_path) -> None:
    """A checkpoint written before the typed configs (plain-dict hparams, a model_config
    without the later keys) loads as the plain ReLU network it holds, with its weights."""
    from training.checkpoints import load_autoencoder

    ae = Autoencoder(TINY)
    ckpt = {
        "state_dict": {f"model.{k}": v for k, v in ae.state_dict().items()},
        "hyper_parameters": {"encoder": TINY_KEYS, "lr": 1e-3},
        "chpf": {"model_type": "ae", "format_version": 1, "model_config": TINY_KEYS},
    }
    torch.save(ckpt, tmp_path / "old.ckpt")
    loaded, _ = load_autoencoder(tmp_path / "old.ckpt")
    assert loaded.config == TINY and loaded.config.activation == "relu"
    for k, v in ae.state_dict().items():
        assert torch.equal(loaded.state_dict()[k], v), k


def test_both_modules_step_with_adams_fused_kernel_on_the_cpu() -> None:
    """configure_optimizers picks Adam's fused kernel for CPU parameters (the per-tensor loop,
    PyTorch's CPU default, took 4.2 against 0.6 ms a step), and a step with it trains."""
    for module in (AELitModule(TINY), CHLitModule(ClassifierConfig(TINY), extra_pairs=0)):
        opt = module.configure_optimizers()["optimizer"]
        assert opt.defaults["fused"] is True
        before = [p.detach().clone() for p in module.model.parameters()]
        for p in module.model.parameters():
            p.grad = torch.ones_like(p)
        opt.step()
        assert all(
            not torch.equal(a, p) for a, p in zip(before, module.model.parameters(), strict=True)
        )
