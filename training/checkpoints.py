"""Read chpf training checkpoints (Lightning ``.ckpt``): model type, config and weights.

Every checkpoint written by ``AELitModule`` / ``CHLitModule`` carries a ``"chpf"`` entry::

    {"model_type": "ae" | "ch", "format_version": 1,
     "model_config": to_dict of the EncoderConfig (ae) | ClassifierConfig (ch),
     "crop": CropSpec dict or None, "object": manifest object name or None,
     "hparams": the module's hyper-parameters (plain dict)}

and the weights in ``state_dict`` under the prefix ``"model."``.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from pathlib import Path
from typing import Any, TypeVar

import torch

from chpf.errors import ConfigError
from training.model_config import ClassifierConfig, EncoderConfig, from_stored
from training.models import Autoencoder, CHClassifier

CHECKPOINT_FORMAT_VERSION = 1
MODEL_TYPES = {"ae": "an autoencoder", "ch": "a CH classifier"}
M = TypeVar("M", Autoencoder, CHClassifier)


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """The raw checkpoint dict (CPU tensors); ConfigError if missing or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: checkpoint file not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        # Lightning checkpoints may hold plain Python objects beyond tensors (trusted local file).
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as err:
            raise ConfigError(f"{path}: not a readable checkpoint ({type(err).__name__})") from None
    except Exception as err:
        raise ConfigError(f"{path}: not a readable checkpoint ({type(err).__name__})") from None
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise ConfigError(f"{path}: not a Lightning checkpoint (no state_dict)")
    return ckpt


def checkpoint_info(path: str | os.PathLike, expect: str | None = None) -> dict[str, Any]:
    """The ``"chpf"`` entry of a checkpoint; ConfigError if absent or not of type ``expect``."""
    ckpt = load_checkpoint(path)
    return _info(ckpt, Path(path), expect)


def _info(ckpt: dict[str, Any], path: Path, expect: str | None) -> dict[str, Any]:
    info = ckpt.get("chpf")
    if not isinstance(info, dict) or info.get("model_type") not in MODEL_TYPES:
        raise ConfigError(f"{path}: not a chpf training checkpoint (no chpf model type)")
    if int(info.get("format_version", 0)) != CHECKPOINT_FORMAT_VERSION:
        raise ConfigError(
            f"{path}: checkpoint format version {info.get('format_version')} is not supported "
            f"(expected {CHECKPOINT_FORMAT_VERSION})"
        )
    got = info["model_type"]
    if expect is not None and got != expect:
        raise ConfigError(
            f"{path}: is {MODEL_TYPES[got]} checkpoint ('{got}'), "
            f"expected {MODEL_TYPES[expect]} checkpoint ('{expect}')"
        )
    return info


def _model_state(ckpt: dict[str, Any], prefix: str = "model.") -> dict[str, torch.Tensor]:
    sd = ckpt["state_dict"]
    return {k[len(prefix) :]: v for k, v in sd.items() if k.startswith(prefix)}


def _load_model(
    path: str | os.PathLike, model_type: str, cls: type[M], config_cls: type
) -> tuple[M, dict[str, Any]]:
    """``(cls(model_config) with the stored weights, in eval mode, chpf info)`` from a
    checkpoint of ``model_type``."""
    ckpt = load_checkpoint(path)
    info = _info(ckpt, Path(path), model_type)
    model = cls(from_stored(config_cls, info["model_config"], str(path)))
    _load_state(model, _model_state(ckpt), Path(path))
    return model.eval(), info


def load_autoencoder(path: str | os.PathLike) -> tuple[Autoencoder, dict[str, Any]]:
    """``(Autoencoder in eval mode, chpf info)`` from an ``ae`` checkpoint."""
    return _load_model(path, "ae", Autoencoder, EncoderConfig)


def load_classifier(path: str | os.PathLike) -> tuple[CHClassifier, dict[str, Any]]:
    """``(CHClassifier in eval mode, chpf info)`` from a ``ch`` checkpoint."""
    return _load_model(path, "ch", CHClassifier, ClassifierConfig)


def _load_state(model: torch.nn.Module, state: dict[str, torch.Tensor], path: Path) -> None:
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as err:
        first = str(err).strip().splitlines()[0]
        msg = f"{path}: weights do not match the stored model config ({first})"
        raise ConfigError(msg) from None


def state_sha256(module: torch.nn.Module) -> str:
    """sha256 over a module's state dict (names, shapes, float32 bytes): weight identity.

    A ``ch`` checkpoint stores the one of the autoencoder encoder it started from as
    ``chpf.ae_encoder_sha256``; with ``shares_ae_encoder`` the export can check that the AE
    checkpoint it is given holds that very encoder.
    """
    h = hashlib.sha256()
    for name, t in sorted(module.state_dict().items()):
        h.update(name.encode())
        h.update(str(tuple(t.shape)).encode())
        h.update(t.detach().cpu().to(torch.float32).contiguous().numpy().tobytes())
    return h.hexdigest()
