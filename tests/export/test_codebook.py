"""export.codebook and export.onnx_export pieces that need no rendering."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from chpf.errors import BundleError
from chpf.geometry import RotationGrid
from export import onnx_export as ox
from export.codebook import build_codebook, downsample_depth, embed_all
from training.model_config import EncoderConfig, HeadConfig
from training.models import CHHead, Encoder

TINY = EncoderConfig(channels=(8, 16), kernel=3, embedding_dim=16, size=32)


def test_downsample_depth_valid_mean():
    d = np.zeros((1, 4, 4), np.float32)
    d[0, :2, :2] = [[1.0, 2.0], [3.0, 4.0]]  # 4 valid -> 2.5
    d[0, :2, 2:] = [[1.0, 0.0], [3.0, 0.0]]  # 2 valid -> 2.0
    d[0, 2:, :2] = [[1.0, 0.0], [0.0, 0.0]]  # 1 valid -> 0 (less than half)
    out = downsample_depth(d, 2)
    np.testing.assert_allclose(out[0], [[2.5, 2.0], [0.0, 0.0]])
    assert out.dtype == np.float32
    with pytest.raises(ValueError):
        downsample_depth(np.zeros((1, 5, 5)), 2)


def test_embed_all_batches_match_one_call():
    rng = np.random.default_rng(0)
    crops = rng.integers(0, 256, (23, 4, 4, 3), dtype=np.uint8)

    def fn(c):
        return c.reshape(len(c), -1)[:, :5].astype(np.float32)

    np.testing.assert_array_equal(embed_all(fn, crops, batch=5), fn(crops))


def test_build_codebook_reuses_ae_embeddings():
    grid = RotationGrid.uniform(10)
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (10, 8, 8, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 1.0, (10, 8, 8)).astype(np.float32)

    def fn(c):
        return c.reshape(len(c), -1)[:, :4].astype(np.float32)

    book = build_codebook(grid, rgb, depth, fn, None, progress=False)
    assert book.ch_embeddings is book.ae_embeddings
    assert book.depth.shape == (10, 4, 4) and book.depth.dtype == np.float16
    assert book.rotations.dtype == np.float32
    np.testing.assert_allclose(book.rotations, grid.rotations, atol=1e-6)


def test_onnx_parity_and_refusal():
    torch.manual_seed(0)
    enc = Encoder(TINY).eval()
    sess = ox.make_session(ox.export_encoder(enc), threads=1)
    crops = np.random.default_rng(2).integers(0, 256, (7, 32, 32, 3), dtype=np.uint8)
    err = ox.check_parity("enc", sess, ox.embedder_module(enc), {"crops": crops})
    assert err <= 1e-4
    emb = sess.run(None, {"crops": crops})[0]
    assert emb.shape == (7, 16)
    np.testing.assert_allclose(np.linalg.norm(emb, axis=1), 1.0, atol=1e-5)
    head = CHHead(16, HeadConfig(hidden=(8, 8))).eval()
    hs = ox.make_session(ox.export_head(head), threads=1)
    inputs = {"obs": emb, "cand": np.ascontiguousarray(emb[::-1])}
    assert ox.check_parity("head", hs, ox.head_module(head), inputs) <= 1e-4
    p = hs.run(None, inputs)[0]
    assert p.shape == (7,) and np.all((p > 0) & (p < 1))
    other = Encoder(TINY).eval()  # different weights -> refused
    with pytest.raises(BundleError, match="enc: onnxruntime differs from torch"):
        ox.check_parity("enc", sess, ox.embedder_module(other), {"crops": crops})
