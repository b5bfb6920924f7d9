"""Codebook over a uniform SO(3) grid: embeddings of rendered crops and reduced depth crops.

Entry k is the object rendered at allocentric orientation ``grid.rotations[k]`` at (0, 0, D_r)
with the crop intrinsics (``chpf.crops.render_crops`` convention), taken from the cached render
pool of ``data_gen.pool.codebook_pool``. Embeddings are computed with the *exported* ONNX
graphs through onnxruntime, i.e. with exactly the numbers the runtime will compare against.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from chpf.geometry import RotationGrid

DEFAULT_CODEBOOK_SIZE = 20000
DEFAULT_DEPTH_FACTOR = 2
EMBED_BATCH = 256

EmbedFn = Callable[[np.ndarray], np.ndarray]


@dataclass
class Codebook:
    """Arrays of ``codebook.npz`` (see ``chpf.bundle``)."""

    rotations: np.ndarray  # (K,3,3) float32, allocentric
    ae_embeddings: np.ndarray  # (K,E) float32, unit norm
    ch_embeddings: np.ndarray  # (K,E) float32, unit norm
    depth: np.ndarray  # (K,Sd,Sd) float16 metres, 0 = empty

    def arrays(self) -> dict[str, np.ndarray]:
        """The npz members by name; ``ch_embeddings`` is left out when it is the AE's own."""
        arrays = {
            "rotations": self.rotations,
            "ae_embeddings": self.ae_embeddings,
            "depth": self.depth,
        }
        if self.ch_embeddings is not self.ae_embeddings:
            arrays["ch_embeddings"] = self.ch_embeddings
        return arrays


def downsample_depth(depth: np.ndarray, factor: int = DEFAULT_DEPTH_FACTOR) -> np.ndarray:
    """Reduce depth crops (K,S,S) float metres by ``factor`` -> (K,S/f,S/f) float32.

    Each output pixel is the mean of the valid (> 0) pixels of its f x f block, or 0 when fewer
    than half of the block is valid (so the silhouette neither grows nor shrinks on average).
    The block centres sit where the scaled intrinsics (focal / f, centre (Sd - 1) / 2) put them.
    """
    k, s, s2 = depth.shape
    if s != s2 or factor < 1 or s % factor != 0:
        raise ValueError(f"downsample_depth: cannot reduce {depth.shape} by {factor}")
    sd = s // factor
    blocks = depth.astype(np.float32, copy=False).reshape(k, sd, factor, sd, factor)
    valid = blocks > 0
    count = valid.sum(axis=(2, 4))
    total = np.where(valid, blocks, 0.0).sum(axis=(2, 4), dtype=np.float64)
    keep = count * 2 >= factor * factor
    out = np.zeros((k, sd, sd), np.float32)
    np.divide(total, np.maximum(count, 1), out=out, where=keep, casting="unsafe")
    return out


def embed_all(
    fn: EmbedFn, crops: np.ndarray, batch: int = EMBED_BATCH, desc: str | None = None
) -> np.ndarray:
    """Apply an embedding function to (K,S,S,3) uint8 crops in batches -> (K,E) float32."""
    n = crops.shape[0]
    parts: list[np.ndarray] = []
    with tqdm(total=n, desc=desc, unit="crop", disable=desc is None, leave=False) as bar:
        for start in range(0, n, batch):
            chunk = np.ascontiguousarray(crops[start : start + batch])
            parts.append(np.asarray(fn(chunk), dtype=np.float32))
            bar.update(chunk.shape[0])
    return np.concatenate(parts, axis=0)


def render_pool(
    obj, spec, k: int, cache_dir: str | os.PathLike | None, workers: int = 1, progress: bool = True
):
    """``(RotationGrid, CropBatch)`` of the codebook views (cached; renders with a progress bar)."""
    from data_gen.pool import codebook_pool  # renders with OpenGL: import only when needed

    root = None if cache_dir is None else Path(cache_dir)
    return codebook_pool(obj, spec, k, root, workers=int(workers), progress=progress)


def build_codebook(
    grid: RotationGrid,
    rgb: np.ndarray,
    depth: np.ndarray,
    ae_embed: EmbedFn,
    ch_embed: EmbedFn | None,
    depth_factor: int = DEFAULT_DEPTH_FACTOR,
    batch: int = EMBED_BATCH,
    progress: bool = True,
) -> Codebook:
    """Codebook from rendered views: rgb (K,S,S,3) uint8, depth (K,S,S) metres.

    ``ch_embed`` embeds the classifier's candidate branch; None = same as ``ae_embed``
    (the classifier shares the autoencoder's encoder), and the AE embeddings are reused.
    """
    k = len(grid)
    if rgb.shape[0] != k or depth.shape[0] != k:
        raise ValueError(f"build_codebook: {k} rotations but {rgb.shape[0]} rgb crops")
    ae = embed_all(ae_embed, rgb, batch, "embed AE" if progress else None)
    if ch_embed is None:
        ch = ae
    else:
        ch = embed_all(ch_embed, rgb, batch, "embed CH" if progress else None)
    return Codebook(
        rotations=grid.rotations.astype(np.float32),
        ae_embeddings=ae,
        ch_embeddings=ch,
        depth=downsample_depth(depth, depth_factor).astype(np.float16),
    )
