"""Networks of the two learned likelihoods: the autoencoder (L) and the CH classifier (C).

All model configs are plain dicts (JSON/YAML friendly) so that ``export`` can rebuild a network
from a checkpoint's hyper-parameters:

* encoder config: ``{"channels": [32, 64, 128, 256], "kernel": 5, "embedding_dim": 128,
  "size": 64, "activation": "relu", "decoder_norm": "none"}`` -- ``len(channels)`` stride-2
  convolutions (padding ``kernel // 2``, then ``activation``: relu or leaky_relu with slope
  0.2), a flatten and one linear layer to the raw (un-normalised) embedding. ``size`` must be
  divisible by ``2 ** len(channels)``. ``decoder_norm: batch`` puts batch normalisation after
  each decoder layer (training only: the decoder is never exported); with leaky_relu it keeps
  the autoencoder off the "mean image" plateau where the plain version can stall.
  ``decoder_channels`` (training only) sets the decoder's widths from the smallest resolution
  up (``len(channels)`` entries); null mirrors the encoder. The decoder dominates the step
  time (its last layers work at the full crop size), so narrower ones train faster.
* head config: ``{"hidden": [256, 128]}`` -- three fully connected layers to one logit.
* classifier config: ``{"encoder": <encoder config>, "head": <head config>,
  "share_twin": True, "shares_ae_encoder": False}``.

Image tensors are float ``(B, 3, S, S)`` in ``[0, 1]`` (RGB); ``Preprocess`` turns the runtime's
uint8 ``(B, S, S, 3)`` crops into that layout (the result has channels_last strides, which the
convolutions use without a copy).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from chpf.errors import ConfigError

DEFAULT_ENCODER: dict[str, Any] = {
    "channels": [32, 64, 128, 256],
    "kernel": 5,
    "embedding_dim": 128,
    "size": 64,
    "activation": "relu",
    "decoder_norm": "none",
    "decoder_channels": None,
}
ACTIVATIONS = ("relu", "leaky_relu")
DECODER_NORMS = ("none", "batch")
DEFAULT_HEAD: dict[str, Any] = {"hidden": [256, 128]}


def encoder_config(
    channels: Sequence[int] = (32, 64, 128, 256),
    kernel: int = 5,
    embedding_dim: int = 128,
    size: int = 64,
    activation: str = "relu",
    decoder_norm: str = "none",
    decoder_channels: Sequence[int] | None = None,
) -> dict[str, Any]:
    """Validated encoder config dict (see module docstring); ConfigError on bad values."""
    cfg = {
        "channels": [int(c) for c in channels],
        "kernel": int(kernel),
        "embedding_dim": int(embedding_dim),
        "size": int(size),
        "activation": str(activation),
        "decoder_norm": str(decoder_norm),
        "decoder_channels": None
        if decoder_channels is None
        else [int(c) for c in decoder_channels],
    }
    _check_encoder_config(cfg)
    return cfg


def _check_encoder_config(cfg: Mapping[str, Any]) -> None:
    unknown = set(cfg) - set(DEFAULT_ENCODER)
    if unknown:
        raise ConfigError(f"encoder config: unknown keys {sorted(unknown)}")
    ch = list(cfg.get("channels", DEFAULT_ENCODER["channels"]))
    k = int(cfg.get("kernel", DEFAULT_ENCODER["kernel"]))
    size = int(cfg.get("size", DEFAULT_ENCODER["size"]))
    e = int(cfg.get("embedding_dim", DEFAULT_ENCODER["embedding_dim"]))
    if not ch or any(int(c) <= 0 for c in ch):
        raise ConfigError(f"encoder config: channels must be positive integers, got {ch}")
    if k < 1 or k % 2 == 0:
        raise ConfigError(f"encoder config: kernel must be odd and >= 1, got {k}")
    if e < 1:
        raise ConfigError(f"encoder config: embedding_dim must be >= 1, got {e}")
    act = cfg.get("activation", DEFAULT_ENCODER["activation"])
    if act not in ACTIVATIONS:
        raise ConfigError(f"encoder config: activation must be one of {ACTIVATIONS}, got {act!r}")
    norm = cfg.get("decoder_norm", DEFAULT_ENCODER["decoder_norm"])
    if norm not in DECODER_NORMS:
        raise ConfigError(
            f"encoder config: decoder_norm must be one of {DECODER_NORMS}, got {norm!r}"
        )
    dec = cfg.get("decoder_channels")
    if dec is not None and (len(dec) != len(ch) or any(int(c) <= 0 for c in dec)):
        raise ConfigError(
            f"encoder config: decoder_channels must be {len(ch)} positive integers "
            f"(one per conv layer) or null, got {dec}"
        )
    if size % (2 ** len(ch)) != 0:
        raise ConfigError(
            f"encoder config: size {size} is not divisible by 2**{len(ch)} (one per conv layer)"
        )


def _full_encoder_config(cfg: Mapping[str, Any] | None) -> dict[str, Any]:
    merged = copy.deepcopy(DEFAULT_ENCODER)
    merged.update(dict(cfg or {}))
    _check_encoder_config(merged)
    merged["channels"] = [int(c) for c in merged["channels"]]
    if merged["decoder_channels"] is not None:
        merged["decoder_channels"] = [int(c) for c in merged["decoder_channels"]]
    return merged


def make_activation(cfg: Mapping[str, Any]) -> nn.Module:
    """The config's activation module (ReLU, or LeakyReLU with slope 0.2)."""
    if cfg["activation"] == "leaky_relu":
        return nn.LeakyReLU(0.2, inplace=True)
    return nn.ReLU(inplace=True)


class Preprocess(nn.Module):
    """uint8 ``(B, S, S, 3)`` RGB -> float32 ``(B, 3, S, S)`` in [0, 1] (channels_last strides)."""

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return crops.permute(0, 3, 1, 2).to(torch.float32) * (1.0 / 255.0)


class Encoder(nn.Module):
    """Convolutional encoder: float ``(B, 3, S, S)`` in [0, 1] -> raw embedding ``(B, E)``."""

    def __init__(
        self,
        channels: Sequence[int] | Mapping[str, Any] = (32, 64, 128, 256),
        kernel: int = 5,
        embedding_dim: int = 128,
        size: int = 64,
    ) -> None:
        super().__init__()
        if isinstance(channels, Mapping):
            cfg = _full_encoder_config(channels)
        else:
            cfg = encoder_config(channels, kernel, embedding_dim, size)
        self.config: dict[str, Any] = cfg
        ch = cfg["channels"]
        k = cfg["kernel"]
        layers: list[nn.Module] = []
        c_in = 3
        for c in ch:
            layers += [nn.Conv2d(c_in, c, k, stride=2, padding=k // 2), make_activation(cfg)]
            c_in = c
        self.convs = nn.Sequential(*layers)
        self.out_hw = cfg["size"] // (2 ** len(ch))
        self.fc = nn.Linear(c_in * self.out_hw * self.out_hw, cfg["embedding_dim"])

    @property
    def embedding_dim(self) -> int:
        return int(self.config["embedding_dim"])

    @property
    def size(self) -> int:
        return int(self.config["size"])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.convs(x)
        return self.fc(torch.flatten(h, 1))


class Decoder(nn.Module):
    """Mirror of ``Encoder``: embedding ``(B, E)`` -> image ``(B, 3, S, S)`` in [0, 1] (sigmoid)."""

    def __init__(self, config: Mapping[str, Any] | None = None) -> None:
        super().__init__()
        cfg = _full_encoder_config(config)
        self.config: dict[str, Any] = cfg
        ch = cfg["decoder_channels"] or list(reversed(cfg["channels"]))
        k = cfg["kernel"]
        self.in_hw = cfg["size"] // (2 ** len(ch))
        self.in_ch = ch[0]
        self.fc = nn.Linear(cfg["embedding_dim"], ch[0] * self.in_hw * self.in_hw)
        self.fc_act = make_activation(cfg)
        layers: list[nn.Module] = []
        outs = [*ch[1:], ch[-1]]
        for c_in, c_out in zip(ch, outs, strict=True):
            layers.append(
                nn.ConvTranspose2d(c_in, c_out, k, stride=2, padding=k // 2, output_padding=1)
            )
            if cfg["decoder_norm"] == "batch":
                layers.append(nn.BatchNorm2d(c_out))
            layers.append(make_activation(cfg))
        layers.append(nn.Conv2d(outs[-1], 3, k, padding=k // 2))
        self.deconvs = nn.Sequential(*layers)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h = self.fc_act(self.fc(z)).view(-1, self.in_ch, self.in_hw, self.in_hw)
        return torch.sigmoid(self.deconvs(h))


class Autoencoder(nn.Module):
    """Augmented-autoencoder: ``forward(x) -> (recon (B,3,S,S) in [0,1], z (B,E) raw)``."""

    def __init__(self, config: Mapping[str, Any] | None = None) -> None:
        super().__init__()
        cfg = _full_encoder_config(config)
        self.config: dict[str, Any] = cfg
        self.encoder = Encoder(cfg)
        self.decoder = Decoder(cfg)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z = self.encoder(x)
        return self.decoder(z), z


class CHHead(nn.Module):
    """Three FC layers on ``cat[obs_n * cand_n, |obs_n - cand_n|]`` -> logit ``(B,)``.

    Inputs are L2-normalised embeddings ``(B, E)``. The logit is that of P(misaligned).
    """

    def __init__(self, embedding_dim: int, hidden: Sequence[int] = (256, 128)) -> None:
        super().__init__()
        hidden = [int(h) for h in hidden]
        if len(hidden) != 2 or any(h < 1 for h in hidden):
            raise ConfigError(f"head config: hidden must be two positive sizes, got {hidden}")
        self.config: dict[str, Any] = {"hidden": hidden}
        self.embedding_dim = int(embedding_dim)
        self.mlp = nn.Sequential(
            nn.Linear(2 * self.embedding_dim, hidden[0]),
            nn.ReLU(inplace=True),
            nn.Linear(hidden[0], hidden[1]),
            nn.ReLU(inplace=True),
            nn.Linear(hidden[1], 1),
        )

    def forward(self, obs_n: torch.Tensor, cand_n: torch.Tensor) -> torch.Tensor:
        feats = torch.cat([obs_n * cand_n, (obs_n - cand_n).abs()], dim=1)
        return self.mlp(feats).squeeze(1)


class CHClassifier(nn.Module):
    """Twin-encoder Counter-Hypothetical classifier.

    ``forward(obs, cand)`` takes float ``(B, 3, S, S)`` crops in [0, 1] and returns the logit
    ``(B,)`` of P(misaligned). ``obs_encoder`` and ``cand_encoder`` are the same module when
    ``share_twin`` (default). ``shares_ae_encoder`` marks the mode where the observed branch is
    the autoencoder's (frozen) encoder: one encoder pass per crop serves both L and C at run time.
    """

    def __init__(self, config: Mapping[str, Any] | None = None) -> None:
        super().__init__()
        cfg = full_classifier_config(config)
        self.config: dict[str, Any] = cfg
        self.shares_ae_encoder: bool = bool(cfg["shares_ae_encoder"])
        self.share_twin: bool = bool(cfg["share_twin"])
        self.obs_encoder = Encoder(cfg["encoder"])
        self.cand_encoder = self.obs_encoder if self.share_twin else Encoder(cfg["encoder"])
        self.head = CHHead(cfg["encoder"]["embedding_dim"], cfg["head"]["hidden"])

    def embed_obs(self, obs: torch.Tensor) -> torch.Tensor:
        """Normalised observed-branch embeddings ``(B, E)``."""
        return F.normalize(self.obs_encoder(obs), dim=1)

    def embed_cand(self, cand: torch.Tensor) -> torch.Tensor:
        """Normalised candidate-branch embeddings ``(B, E)``."""
        return F.normalize(self.cand_encoder(cand), dim=1)

    def embed_pair(self, obs: torch.Tensor, cand: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Normalised embeddings ``(B, E)`` of both crops (one batched pass when shared)."""
        if self.share_twin:
            both = F.normalize(self.obs_encoder(torch.cat([obs, cand], 0)), dim=1)
            return both[: obs.shape[0]], both[obs.shape[0] :]
        return self.embed_obs(obs), self.embed_cand(cand)

    def forward(self, obs: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return self.head(*self.embed_pair(obs, cand))


def full_classifier_config(config: Mapping[str, Any] | None) -> dict[str, Any]:
    """Classifier config with defaults filled in and validated (ConfigError on unknown keys)."""
    cfg = dict(config or {})
    allowed = {"encoder", "head", "share_twin", "shares_ae_encoder"}
    unknown = set(cfg) - allowed
    if unknown:
        raise ConfigError(f"classifier config: unknown keys {sorted(unknown)}")
    head = copy.deepcopy(DEFAULT_HEAD)
    head.update(dict(cfg.get("head") or {}))
    if set(head) - {"hidden"}:
        raise ConfigError(f"head config: unknown keys {sorted(set(head) - {'hidden'})}")
    head["hidden"] = [int(h) for h in head["hidden"]]
    return {
        "encoder": _full_encoder_config(cfg.get("encoder")),
        "head": head,
        "share_twin": bool(cfg.get("share_twin", True)),
        "shares_ae_encoder": bool(cfg.get("shares_ae_encoder", False)),
    }


def build_encoder(cfg: Mapping[str, Any] | None) -> Encoder:
    """Encoder from a config dict (missing keys take the defaults)."""
    return Encoder(_full_encoder_config(cfg))


def build_autoencoder(cfg: Mapping[str, Any] | None) -> Autoencoder:
    """Autoencoder from an encoder config dict (the decoder mirrors it)."""
    return Autoencoder(cfg)


def build_classifier(cfg: Mapping[str, Any] | None) -> CHClassifier:
    """CH classifier from a classifier config dict."""
    return CHClassifier(cfg)


class NormalizedEmbedder(nn.Module):
    """Runtime graph of one branch: uint8 ``(N, S, S, 3)`` RGB -> L2-normalised ``(N, E)``.

    This is what ``export`` writes to ONNX (input "crops", output "embedding").
    """

    def __init__(self, encoder: Encoder) -> None:
        super().__init__()
        self.preprocess = Preprocess()
        self.encoder = encoder

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.encoder(self.preprocess(crops)), dim=1)


class HeadProbability(nn.Module):
    """Runtime head graph: normalised ``obs``, ``cand`` ``(N, E)`` -> P(misaligned) ``(N,)``."""

    def __init__(self, head: CHHead) -> None:
        super().__init__()
        self.head = head

    def forward(self, obs: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.head(obs, cand))
