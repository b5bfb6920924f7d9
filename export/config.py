"""Export settings (``configs/export.yaml`` or command-line flags)."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from chpf.errors import ConfigError
from export.codebook import DEFAULT_CODEBOOK_SIZE, DEFAULT_DEPTH_FACTOR, EMBED_BATCH
from export.onnx_export import PARITY_TOL


@dataclass
class ExportConfig:
    """What ``chpf-export`` builds.

    codebook_size: K, entries of the uniform SO(3) codebook grid.
    depth_factor: codebook depth crops are S / depth_factor pixels wide.
    embed_batch: crops per onnxruntime call while embedding the codebook.
    parity_samples: real crops used for the onnxruntime-vs-torch check.
    parity_tol: max abs difference allowed in that check.
    threads: onnxruntime intra-op threads used during the export.
    workers: render processes for the codebook pool (used when it is not cached yet).
    cache_dir: render-pool cache folder (None = data_gen's default).
    unit: unit of a mesh file given as --object ("m" or "mm").
    """

    codebook_size: int = DEFAULT_CODEBOOK_SIZE
    depth_factor: int = DEFAULT_DEPTH_FACTOR
    embed_batch: int = EMBED_BATCH
    parity_samples: int = 64
    parity_tol: float = PARITY_TOL
    threads: int = 2
    workers: int = 2
    cache_dir: str | None = None
    unit: str = "m"

    def __post_init__(self) -> None:
        self.validate()

    def validate(self, where: str = "export config") -> None:
        """ConfigError on out-of-range values."""
        if int(self.codebook_size) < 1:
            raise ConfigError(f"{where}: codebook_size must be >= 1, got {self.codebook_size}")
        if int(self.depth_factor) < 1:
            raise ConfigError(f"{where}: depth_factor must be >= 1, got {self.depth_factor}")
        if int(self.embed_batch) < 1 or int(self.parity_samples) < 2:
            raise ConfigError(f"{where}: embed_batch must be >= 1 and parity_samples >= 2")
        if not float(self.parity_tol) > 0:
            raise ConfigError(f"{where}: parity_tol must be > 0, got {self.parity_tol}")
        if int(self.threads) < 1 or int(self.workers) < 1:
            raise ConfigError(
                f"{where}: threads and workers must be >= 1, got {self.threads}, {self.workers}"
            )
        if self.unit not in ("m", "mm"):
            raise ConfigError(f"{where}: unit must be 'm' or 'mm', got {self.unit!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "export config") -> ExportConfig:
        """From a dict; ConfigError on unknown keys or bad values."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ConfigError(f"{where}: unknown keys {unknown} (known: {sorted(names)})")
        cfg = cls.__new__(cls)
        for f in dataclasses.fields(cls):
            setattr(cfg, f.name, d.get(f.name, f.default))
        try:
            cfg.validate(where)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"{where}: bad value ({err})") from None
        return cfg

    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> ExportConfig:
        """From a YAML mapping (an optional top-level ``export:`` key is unwrapped)."""
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except (OSError, yaml.YAMLError) as err:
            raise ConfigError(f"{path}: cannot read export config ({err})") from None
        if isinstance(data, dict) and set(data) == {"export"}:
            data = data["export"] or {}
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: export config must be a mapping")
        return cls.from_dict(data, str(path))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (recorded in the manifest)."""
        return dataclasses.asdict(self)
