"""What a ``chpf-track --out`` folder was made with, and how its outputs are cleared.

``track_settings`` is recorded as ``track_settings.json`` beside the outputs (see
``chpf.outdir.claim_settings``): a rerun with the same settings resumes, one with other
settings is refused unless ``--overwrite``, which first removes every output of the old run.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from chpf.bundle import MANIFEST, Bundle
from chpf.config_schema import to_dict
from chpf.hashing import sha256_file
from chpf.tracking.config import TrackConfig
from chpf.tracking.methods import method_names
from chpf.tracking.run_dataset import method_tag

SETTINGS_FILE = "track_settings.json"
REPORTS = ("auc_table.txt", "runs.json")
"""Files a run writes besides its per-method CSVs (and the ``plots`` folder)."""


def file_record(path: Path | None) -> dict[str, str] | None:
    """{"path": absolute, "sha256"} of an input file (None stays None)."""
    if path is None:
        return None
    return {"path": str(Path(path).resolve()), "sha256": sha256_file(path)}


def bop_inputs(
    dataset: Path, split: str, scenes: list[int], detections: Path | None
) -> dict[str, Any]:
    """The input part of a BOP run's settings: the dataset, split and scenes and the detections
    file (sha256; None = the dataset's or the simulated detector)."""
    return {
        "dataset": str(Path(dataset).resolve()),
        "split": split,
        "scenes": [int(s) for s in scenes],
        "detections": file_record(detections),
    }


def _bundle_record(bundle: Bundle) -> dict[str, str]:
    return {"path": str(bundle.path.resolve()), "sha256": sha256_file(bundle.path / MANIFEST)}


def track_settings(
    bundle: Bundle | list[Bundle],
    inputs: dict[str, Any],
    methods: list[str],
    modality: str,
    seed: int,
    config: TrackConfig,
) -> dict[str, Any]:
    """Everything the outputs depend on: the bundle (manifest sha256, which covers every file;
    several bundles: ``bundles``, a list of them in order), the inputs (``bop_inputs``, or a
    plain input's files and boxes), the methods, modality, seed and the full tracking config."""
    bundles = bundle if isinstance(bundle, list) else [bundle]
    if len(bundles) == 1:
        which: dict[str, Any] = {"bundle": _bundle_record(bundles[0])}
    else:
        which = {"bundles": [_bundle_record(b) for b in bundles]}
    return {
        **which,
        **inputs,
        "methods": list(methods),
        "modality": modality,
        "seed": int(seed),
        "config": to_dict(config),
    }


def clear_outputs(out: Path) -> None:
    """Remove every chpf-track output in ``out`` (result CSVs and logs of any method and
    object, plots, reports); other files stay."""
    for m in method_names():
        tag = method_tag(m)
        logs = [out / f"log_{tag}.csv", *out.glob(f"log_{tag}_obj*.csv")]
        for p in [*out.glob(f"{tag}_*.csv"), *logs]:
            p.unlink(missing_ok=True)
    for name in REPORTS:
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / "plots", ignore_errors=True)
