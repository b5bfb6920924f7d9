"""Networks of the two learned likelihoods: the autoencoder (L) and the CH classifier (C).

Each network is built from its typed config (``training.model_config``: ``EncoderConfig`` for
the encoder and the autoencoder, ``ClassifierConfig`` for the classifier), kept as ``.config``.

Image tensors are float ``(B, 3, S, S)`` in ``[0, 1]`` (RGB); ``Preprocess`` turns the runtime's
uint8 ``(B, S, S, 3)`` crops into that layout (the result has channels_last strides, which the
convolutions use without a copy).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from chpf.errors import ConfigError
from training.model_config import ClassifierConfig, EncoderConfig, HeadConfig


def make_activation(cfg: EncoderConfig) -> nn.Module:
    """The config's activation module (ReLU, or LeakyReLU with slope 0.2)."""
    if cfg.activation == "leaky_relu":
        return nn.LeakyReLU(0.2, inplace=True)
    return nn.ReLU(inplace=True)


class Preprocess(nn.Module):
    """uint8 ``(B, S, S, 3)`` RGB -> float32 ``(B, 3, S, S)`` in [0, 1] (channels_last strides)."""

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return crops.permute(0, 3, 1, 2).to(torch.float32) * (1.0 / 255.0)


class Residual(nn.Module):
    """``x + f(relu(x))`` whose last convolution is zero-initialised: the identity at first, so
    that it can be added to a trained encoder without changing what it computes.

    ``reduction`` 1: ``f`` is one full-width 3x3 convolution (C -> C). ``reduction`` r > 1: a
    bottleneck, 1x1 (C -> C/r), ReLU, 3x3 (C/r -> C/r), ReLU, 1x1 (C/r -> C), about r**2
    times cheaper for the same depth.
    """

    def __init__(self, channels: int, reduction: int = 1) -> None:
        super().__init__()
        if reduction == 1:
            self.conv: nn.Module = nn.Conv2d(channels, channels, 3, padding=1)
            last = self.conv
        else:
            inner = max(channels // reduction, 1)
            last = nn.Conv2d(inner, channels, 1)
            self.conv = nn.Sequential(
                nn.Conv2d(channels, inner, 1), nn.ReLU(inplace=True),
                nn.Conv2d(inner, inner, 3, padding=1), nn.ReLU(inplace=True), last,
            )  # fmt: skip
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv(F.relu(x))


class Encoder(nn.Module):
    """Convolutional encoder: float ``(B, 3, S, S)`` in [0, 1] -> raw embedding ``(B, E)``.

    ``refine_stages`` > 0: a ``Residual`` block (inner width reduced ``refine_reduction``
    times) follows each of that many last stride-2 stages (the classifier's extra depth on top
    of the autoencoder's encoder).
    """

    def __init__(
        self, config: EncoderConfig | None = None, refine_stages: int = 0, refine_reduction: int = 1
    ) -> None:
        super().__init__()
        cfg = config or EncoderConfig()
        self.config = cfg
        k = cfg.kernel
        layers: list[nn.Module] = []
        c_in = 3
        for c in cfg.channels:
            layers += [nn.Conv2d(c_in, c, k, stride=2, padding=k // 2), make_activation(cfg)]
            c_in = c
        self.convs = nn.Sequential(*layers)
        # stage i is layers 2i (convolution) and 2i + 1 (activation)
        n = len(cfg.channels)
        if refine_stages > n:
            raise ConfigError(f"refine_stages: {refine_stages} > the encoder's {n} stages")
        last = range(n - refine_stages, n)
        self.refine = nn.ModuleDict(
            {str(i): Residual(cfg.channels[i], refine_reduction) for i in last}
        )
        self.out_hw = cfg.feature_side
        self.fc = nn.Linear(c_in * self.out_hw * self.out_hw, cfg.embedding_dim)

    @property
    def embedding_dim(self) -> int:
        return self.config.embedding_dim

    @property
    def size(self) -> int:
        return self.config.size

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x
        for i in range(len(self.convs) // 2):
            h = self.convs[2 * i + 1](self.convs[2 * i](h))
            if str(i) in self.refine:
                h = self.refine[str(i)](h)
        return self.fc(torch.flatten(h, 1))


class Decoder(nn.Module):
    """Mirror of ``Encoder``: embedding ``(B, E)`` -> image ``(B, 3, s, s)`` in [0, 1] (sigmoid),
    ``s = out_size``: the crop side S, or less with fewer ``decoder_channels`` than encoder
    stages (each one fewer halves it)."""

    def __init__(self, config: EncoderConfig | None = None) -> None:
        super().__init__()
        cfg = config or EncoderConfig()
        self.config = cfg
        ch = list(cfg.decoder_channels or reversed(cfg.channels))
        k = cfg.kernel
        self.in_hw = cfg.feature_side  # the encoder's last feature map
        self.out_size = self.in_hw * 2 ** len(ch)
        self.in_ch = ch[0]
        self.fc = nn.Linear(cfg.embedding_dim, ch[0] * self.in_hw * self.in_hw)
        self.fc_act = make_activation(cfg)
        layers: list[nn.Module] = []
        outs = [*ch[1:], ch[-1]]
        for c_in, c_out in zip(ch, outs, strict=True):
            layers.append(
                nn.ConvTranspose2d(c_in, c_out, k, stride=2, padding=k // 2, output_padding=1)
            )
            if cfg.decoder_norm == "batch":
                layers.append(nn.BatchNorm2d(c_out))
            layers.append(make_activation(cfg))
        layers.append(nn.Conv2d(outs[-1], 3, k, padding=k // 2))
        self.deconvs = nn.Sequential(*layers)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h = self.fc_act(self.fc(z)).view(-1, self.in_ch, self.in_hw, self.in_hw)
        return torch.sigmoid(self.deconvs(h))


class Autoencoder(nn.Module):
    """Augmented-autoencoder: ``forward(x) -> (recon (B,3,s,s) in [0,1], z (B,E) raw)``, ``s``
    the decoder's ``out_size`` (``recon_target`` gives the matching target)."""

    def __init__(self, config: EncoderConfig | None = None) -> None:
        super().__init__()
        cfg = config or EncoderConfig()
        self.config = cfg
        self.encoder = Encoder(cfg)
        self.decoder = Decoder(cfg)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z = self.encoder(x)
        return self.decoder(z), z

    def recon_target(self, target: torch.Tensor) -> torch.Tensor:
        """The reconstruction's target: ``target`` ``(B, 3, S, S)`` area-averaged to the
        decoder's ``out_size`` (itself when that is S)."""
        factor = target.shape[-1] // self.decoder.out_size
        return target if factor == 1 else F.avg_pool2d(target, factor)


class CHHead(nn.Module):
    """Three FC layers on ``cat[obs_n * cand_n, |obs_n - cand_n|]`` -> logit ``(B,)``.

    Inputs are L2-normalised embeddings ``(B, E)``. The logit is that of P(misaligned).
    """

    def __init__(self, embedding_dim: int, config: HeadConfig | None = None) -> None:
        super().__init__()
        self.config = config or HeadConfig()
        hidden = self.config.hidden
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

    def __init__(self, config: ClassifierConfig | None = None) -> None:
        super().__init__()
        cfg = config or ClassifierConfig()
        self.config = cfg
        self.shares_ae_encoder = cfg.shares_ae_encoder
        self.share_twin = cfg.share_twin
        self.obs_encoder = Encoder(cfg.encoder, cfg.refine_stages, cfg.refine_reduction)
        # a separate candidate branch is the autoencoder's frozen encoder (freeze_candidate)
        self.cand_encoder = self.obs_encoder if self.share_twin else Encoder(cfg.encoder)
        self.head = CHHead(cfg.encoder.embedding_dim, cfg.head)

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
