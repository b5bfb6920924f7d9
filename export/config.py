"""Export settings (``configs/export_default.yaml``, ``--set key=value`` or command-line flags)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

from chpf.config_schema import Section, load, read_yaml, setting, to_dict
from chpf.errors import ConfigError
from export.codebook import DEFAULT_CODEBOOK_SIZE, DEFAULT_DEPTH_FACTOR, EMBED_BATCH
from export.onnx_export import PARITY_TOL


@dataclass
class ExportConfig(Section):
    """What ``chpf-export`` builds.

    codebook_size: K, entries of the uniform SO(3) codebook grid.
    depth_factor: codebook depth crops are S / depth_factor pixels wide.
    embed_batch: crops per onnxruntime call while embedding the codebook.
    parity_samples: real crops used for the onnxruntime-vs-torch check.
    parity_tol: max abs difference allowed in that check.
    threads: onnxruntime intra-op threads used during the export.
    workers: render processes for the codebook pool (used when it is not cached yet).
    cache_dir: render-pool cache folder (None = data_gen's default).
    unit: unit of a mesh file given as --object ("m", "cm" or "mm").
    obj_id: the bundle's dataset object id (None = the object's own: a built-in's, the one in
    a BOP model file name such as obj_000005.ply, else 0).
    """

    codebook_size: int = setting(DEFAULT_CODEBOOK_SIZE, ge=1)
    depth_factor: int = setting(DEFAULT_DEPTH_FACTOR, ge=1)
    embed_batch: int = setting(EMBED_BATCH, ge=1)
    parity_samples: int = setting(64, ge=2)
    parity_tol: float = setting(PARITY_TOL, gt=0.0)
    threads: int = setting(2, ge=1)
    workers: int = setting(2, ge=1)
    cache_dir: str | None = None
    unit: Literal["m", "cm", "mm"] = "m"
    obj_id: int | None = setting(None, ge=0)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "export config") -> ExportConfig:
        """From a dict; ConfigError (one line naming ``where`` and the key) on unknown keys or
        bad values."""
        return load(cls, data=d, where=where)

    @classmethod
    def from_yaml(cls, path: str | os.PathLike, sets: Iterable[str] = ()) -> ExportConfig:
        """From a YAML mapping (an optional top-level ``export:`` key is unwrapped), then
        ``sets`` ("key=value")."""
        data = read_yaml(path) or {}
        if isinstance(data, dict) and set(data) == {"export"}:
            data = data["export"] or {}
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: export config must be a mapping")
        cfg = load(cls, data=data, where=str(path))
        return load(cls, sets=sets, base=cfg)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (recorded in the manifest)."""
        return to_dict(self)
