"""Typed model configs of the two learned likelihoods (``chpf-train``'s ``model.*`` sections).

LightningCLI (jsonargparse) reads these dataclasses as nested groups of keys, so YAML files and
``--model.encoder.kernel 3`` are type-checked and unknown keys are refused; ranges and cross-key
rules are checked by ``chpf.config_schema`` (one ConfigError line naming the key). Checkpoints
store them as plain dicts (``chpf.config_schema.to_dict``); ``from_stored`` reads them back.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar

from chpf.config_schema import Invalid, Section, load, setting
from data_gen.config import CROP_KEYS, Pairs


@dataclass
class EncoderConfig(Section):
    """Convolutional encoder (and the training-only decoder of the autoencoder).

    Attributes:
        channels: widths of the ``len(channels)`` stride-2 convolutions (padding kernel // 2);
            then a flatten and one linear layer to the raw embedding.
        kernel: odd convolution kernel size.
        embedding_dim: embedding size E.
        size: crop side S in pixels, divisible by ``2 ** len(channels)``.
        activation: relu, or leaky_relu (slope 0.2).
        decoder_norm: none, or batch (batch norm after each decoder layer; training only). With
            leaky_relu it keeps the autoencoder off the "mean image" plateau.
        decoder_channels: decoder widths from the smallest resolution up (training only, the
            decoder is never exported); null mirrors the encoder. ``len(channels)`` entries
            reconstruct the S x S crop; m fewer stop m upsamplings early and reconstruct it at
            ``S / 2**m`` against the area-averaged target (the full-size layers are most of a
            step's work).
    """

    channels: tuple[int, ...] = setting((32, 64, 128, 256), ge=1)
    kernel: int = setting(5, ge=1)
    embedding_dim: int = setting(128, ge=1)
    size: int = setting(64, ge=1)
    activation: Literal["relu", "leaky_relu"] = "relu"
    decoder_norm: Literal["none", "batch"] = "none"
    decoder_channels: tuple[int, ...] | None = setting(None, ge=1)

    @property
    def feature_side(self) -> int:
        """Side in pixels of the encoder's last feature map (the decoder's first): S / 2**n."""
        return self.size // (2 ** len(self.channels))

    def check(self) -> None:
        n = len(self.channels)
        if n == 0:
            raise Invalid("channels", "needs at least one layer")
        if self.kernel % 2 == 0:
            raise Invalid("kernel", f"must be odd, got {self.kernel}")
        if self.decoder_channels is not None and not 1 <= len(self.decoder_channels) <= n:
            raise Invalid(
                "decoder_channels",
                f"must be 1 to {n} sizes (one per upsampling) or null, got "
                f"{list(self.decoder_channels)}",
            )
        if self.size % (2**n) != 0:
            raise Invalid("size", f"{self.size} is not divisible by 2**{n} (one per conv layer)")


@dataclass
class HeadConfig(Section):
    """CH head: three fully connected layers to one logit.

    Attributes:
        hidden: widths of the two hidden layers.
    """

    hidden: tuple[int, int] = setting((256, 128), ge=1)


@dataclass
class ClassifierConfig(Section):
    """Twin-encoder Counter-Hypothetical classifier.

    Attributes:
        encoder: the encoder of both branches (replaced by the autoencoder's with init_from_ae).
        head: the head on the two normalised embeddings.
        share_twin: one encoder (shared weights) serves both branches.
        shares_ae_encoder: the observed branch is the autoencoder's encoder, frozen (set by
            freeze_encoder): one encoder pass per crop serves L and C at run time.
        refine_stages: a zero-initialised residual 3x3 convolution (``training.models.Residual``)
            follows each of the encoder's last this many stages: depth added to the
            autoencoder's encoder; 0 = none. A separate candidate branch (share_twin false:
            the autoencoder's frozen encoder, freeze_candidate) has none, so that the export
            reuses the autoencoder's codebook embeddings for it.
        refine_reduction: those blocks' inner width is the stage's channels divided by this:
            1 = one full-width 3x3 convolution; r > 1 = a 1x1, 3x3, 1x1 bottleneck.
    """

    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    head: HeadConfig = field(default_factory=HeadConfig)
    share_twin: bool = True
    shares_ae_encoder: bool = False
    refine_stages: int = setting(0, ge=0)
    refine_reduction: int = setting(1, ge=1)

    def check(self) -> None:
        if self.shares_ae_encoder and not self.share_twin:
            raise Invalid("shares_ae_encoder", "needs share_twin (one encoder for both branches)")
        if self.shares_ae_encoder and self.refine_stages:
            raise Invalid("refine_stages", "must be 0 when the autoencoder's encoder is shared")
        if self.refine_stages > len(self.encoder.channels):
            raise Invalid("refine_stages", f"the encoder has {len(self.encoder.channels)} stages")


C = TypeVar("C", EncoderConfig, ClassifierConfig)


def from_stored(cls: type[C], stored: Mapping[str, Any], where: str) -> C:
    """A checkpoint's ``model_config`` dict (``to_dict`` of the config) as ``cls``; keys it
    lacks (checkpoints older than the key) take the defaults, which are the networks those
    checkpoints hold. ConfigError naming ``where`` and ``model_config.<key>`` if invalid."""
    return load(cls, data=stored, where=where, prefix="model_config.")


def _optional(f: dataclasses.Field) -> tuple[str, Any, dataclasses.Field]:
    hint = typing.get_type_hints(Pairs)[f.name]
    return f.name, hint | None, dataclasses.field(default=None, metadata=f.metadata)


# The extra pairs' mix: any key of chpf-gen-data's ``pairs`` section (same types and ranges,
# meanings in configs/gen_default.yaml); null keeps the value the data was drawn with.
PairsMix = dataclasses.make_dataclass(
    "PairsMix",
    [_optional(f) for f in dataclasses.fields(Pairs) if f.name not in CROP_KEYS],
    bases=(Section,),
    namespace={"__module__": __name__, "__doc__": "Overrides of the data's ``pairs`` keys."},
)


def mix_overrides(mix: Any) -> dict[str, Any]:
    """The keys a ``PairsMix`` sets (not null), as plain values."""
    return {
        f.name: list(v) if isinstance(v, tuple) else v
        for f in dataclasses.fields(mix)
        for v in [getattr(mix, f.name)]
        if v is not None
    }
