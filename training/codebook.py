"""Evaluation codebooks: rotations of a uniform SO(3) grid + clean codebook-convention crops.

``python -m training.codebook --data DIR --k 4096 --out val_codebook.npz`` renders (or reuses
from data_gen's pool cache) the object of a shard folder at ``RotationGrid.uniform(k)`` with the
folder's crop spec, and writes an npz with:

* ``rotations`` (K,3,3) float32 allocentric codebook orientations,
* ``crops`` (K,S,S,3) uint8 RGB,
* ``symmetries_discrete`` (M,4,4) float64 (metres) and ``symmetries_continuous_axes`` (C,3),
* ``crop_size`` () int.

``AELitModule(val_codebook=...)`` and ``training.evaluate`` measure retrieval errors against it.
"""

from __future__ import annotations

import argparse
import os
from typing import Any

import numpy as np

from chpf.atomic import atomic_save_npz
from chpf.console import run_main
from chpf.objects import MESH_UNITS


def render_eval_codebook(
    data_dir: str | os.PathLike,
    k: int,
    object_name: str | None = None,
    unit: str | None = None,
    cache_dir: str | None = None,
    workers: int = 1,
    progress: bool = True,
) -> dict[str, np.ndarray]:
    """Codebook arrays (see module docstring) for the object and crop spec of ``data_dir``.

    The object is the one the data was made from (``data_gen.shards.manifest_object``);
    ``object_name`` (built-in name or mesh path, in ``unit``) overrides it and must have the
    manifest's fingerprint (DatasetError otherwise).
    """
    from chpf.crops import CropSpec
    from data_gen.pool import codebook_pool
    from data_gen.shards import manifest_object, read_manifest

    man = read_manifest(data_dir)
    obj = manifest_object(data_dir, object_name, unit)
    spec = CropSpec.from_dict(man["crop"])
    grid, crops = codebook_pool(obj, spec, int(k), cache_dir, workers=workers, progress=progress)
    return codebook_arrays(
        grid.rotations, np.asarray(crops.rgb), obj.symmetries_discrete, obj.symmetries_continuous
    )


def codebook_arrays(
    rotations: np.ndarray,
    crops: np.ndarray,
    symmetries_discrete: Any = (),
    symmetries_continuous: Any = (),
) -> dict[str, np.ndarray]:
    """Pack codebook arrays in the npz layout of this module."""
    disc = np.asarray([np.asarray(T, np.float64) for T in symmetries_discrete]).reshape(-1, 4, 4)
    axes = np.asarray([np.asarray(c["axis"], np.float64) for c in symmetries_continuous]).reshape(
        -1, 3
    )
    return {
        "rotations": np.asarray(rotations, np.float32),
        "crops": np.asarray(crops, np.uint8),
        "symmetries_discrete": disc,
        "symmetries_continuous_axes": axes,
        "crop_size": np.asarray(crops.shape[1], np.int64),
    }


def save_codebook(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    """Atomic uncompressed npz write."""
    atomic_save_npz(path, arrays)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m training.codebook",
        description="Build an evaluation codebook (grid rotations + clean crops).",
    )
    p.add_argument("--data", required=True, help="chpf-gen-data folder (object and crop spec)")
    p.add_argument("--k", type=int, default=4096, help="codebook size (uniform SO(3) grid)")
    p.add_argument("--out", required=True, help="output .npz")
    p.add_argument("--object", default=None, help="built-in name or mesh (default: manifest's)")
    p.add_argument(
        "--unit", default=None, choices=list(MESH_UNITS), help="--object's unit (default m)"
    )
    p.add_argument("--cache-dir", default=None, help="data_gen pool cache folder")
    p.add_argument("--workers", type=int, default=1)
    a = p.parse_args(argv)
    arrays = render_eval_codebook(a.data, a.k, a.object, a.unit, a.cache_dir, a.workers)
    save_codebook(a.out, arrays)
    print(f"wrote {a.out}: {arrays['rotations'].shape[0]} entries, crop {arrays['crop_size']}")
    return 0


cli = run_main(main)

if __name__ == "__main__":
    cli()
