"""chpf.bundle: loading, validation and batched calls on a small hand-made bundle (no torch).

The ONNX graphs are built with ``onnx.helper`` so that the expected outputs are plain numpy:
encoder = L2-normalise(flatten(crops / 255) @ W), head = sigmoid(-a * <obs, cand> + b).
The torch -> ONNX path is tested in tests/export.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from chpf.bundle import Bundle  # noqa: E402
from chpf.crops import CropSpec  # noqa: E402
from chpf.errors import BundleError, ImageSizeError  # noqa: E402
from chpf.geometry import RotationGrid  # noqa: E402
from tests.helpers import dot_head_model, onnx_model, write_bundle  # noqa: E402

S, E, K = 32, 8, 40
HEAD_A, HEAD_B = 4.0, 1.0


def _encoder_model(w: np.ndarray) -> bytes:
    s = S
    nodes = [
        helper.make_node("Cast", ["crops"], ["f"], to=TensorProto.FLOAT),
        helper.make_node("Mul", ["f", "scale"], ["g"]),
        helper.make_node("Reshape", ["g", "shape"], ["h"]),
        helper.make_node("MatMul", ["h", "W"], ["z"]),
        helper.make_node("LpNormalization", ["z"], ["embedding"], axis=1, p=2),
    ]
    inits = [
        numpy_helper.from_array(np.array(1.0 / 255.0, np.float32), "scale"),
        numpy_helper.from_array(np.array([-1, s * s * 3], np.int64), "shape"),
        numpy_helper.from_array(w.astype(np.float32), "W"),
    ]
    return onnx_model(
        "enc",
        nodes,
        [helper.make_tensor_value_info("crops", TensorProto.UINT8, ["batch", s, s, 3])],
        [helper.make_tensor_value_info("embedding", TensorProto.FLOAT, ["batch", E])],
        inits,
    )


def _head_model() -> bytes:
    logit = [
        helper.make_node("Mul", ["d", "a"], ["e"]),
        helper.make_node("Add", ["e", "b"], ["logit"]),
    ]
    return dot_head_model("head", E, logit, {"a": -HEAD_A, "b": HEAD_B})


def _ref_embed(crops: np.ndarray, w: np.ndarray) -> np.ndarray:
    z = (crops.reshape(len(crops), -1).astype(np.float64) / 255.0) @ w.astype(np.float64)
    return z / np.linalg.norm(z, axis=1, keepdims=True)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def make_bundle(root: Path, shared: bool = False, seed: int = 0) -> dict:
    """Write a valid bundle into ``root``; returns the weights and arrays used."""
    rng = np.random.default_rng(seed)
    w_ae = rng.normal(size=(S * S * 3, E)).astype(np.float32)
    w_ch = rng.normal(size=(S * S * 3, E)).astype(np.float32)
    grid = RotationGrid.uniform(K)
    ae = rng.normal(size=(K, E)).astype(np.float32)
    ae /= np.linalg.norm(ae, axis=1, keepdims=True)
    ch = ae.copy() if shared else rng.normal(size=(K, E)).astype(np.float32)
    ch /= np.linalg.norm(ch, axis=1, keepdims=True)
    depth = rng.uniform(0.5, 1.0, (K, S // 2, S // 2)) * (
        rng.uniform(size=(K, S // 2, S // 2)) > 0.5
    )
    write_bundle(
        root,
        encoder=_encoder_model(w_ae),
        head=_head_model(),
        ch_encoder=None if shared else _encoder_model(w_ch),
        codebook={
            "rotations": grid.rotations.astype(np.float32),
            "ae_embeddings": ae,
            "ch_embeddings": ch,
            "depth": depth.astype(np.float16),
        },
        obj={
            "name": "box",
            "obj_id": 2,
            "diameter": 0.2,
            "symmetries_discrete": [np.diag([-1.0, -1.0, 1.0, 1.0]).tolist()],
            "symmetries_continuous": [],
            "fingerprint": "abc",
        },
        crop=CropSpec(size=S, render_distance=0.8, focal=3.6 * S).to_dict(),
        training={},
        created_by="test",
        compress=True,
    )
    return {"w_ae": w_ae, "w_ch": w_ch, "ae": ae, "ch": ch, "depth": depth, "grid": grid}


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("bundle") / "box"
    return root, make_bundle(root)


def _crops(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, S, S, 3), dtype=np.uint8)


def _rewrite_manifest(root: Path, **changes) -> None:
    m = json.loads((root / "manifest.json").read_text())
    m.update(changes)
    (root / "manifest.json").write_text(json.dumps(m))


def test_load_and_calls_match_reference(made):
    root, ref = made
    b = Bundle.load(root, threads=1)
    assert b.spec.size == S and b.embedding_dim == E and b.codebook_size == K
    assert b.obj_info.name == "box" and b.obj_info.obj_id == 2
    assert b.obj_info.symmetries_discrete.shape == (1, 4, 4)
    assert len(b.grid) == K and not b.shares_encoder
    assert b._ae.get_session_options().intra_op_num_threads == 1
    crops = _crops(50)
    emb = b.embed(crops)
    assert emb.shape == (50, E) and emb.dtype == np.float32
    np.testing.assert_allclose(emb, _ref_embed(crops, ref["w_ae"]), atol=1e-5)
    ch = b.ch_embed(crops)
    np.testing.assert_allclose(ch, _ref_embed(crops, ref["w_ch"]), atol=1e-5)
    idx = np.arange(50) % K
    p = b.p_misaligned(ch, idx)
    want = _sigmoid(-HEAD_A * np.sum(ch * ref["ch"][idx], axis=1) + HEAD_B)
    assert p.shape == (50,)
    np.testing.assert_allclose(p, want, atol=1e-5)
    np.testing.assert_allclose(b.cosine(emb, idx), np.sum(emb * ref["ae"][idx], 1), atol=1e-6)
    np.testing.assert_array_equal(b.nearest(ref["grid"].rotations[idx]), idx)
    d = b.codebook_depth(idx)
    assert d.shape == (50, S // 2, S // 2) and d.dtype == np.float32
    np.testing.assert_allclose(d, ref["depth"][idx], atol=2e-3)
    assert b.depth_K[0, 0] == pytest.approx(b.spec.focal / 2)
    assert b.depth_K[0, 2] == pytest.approx((S // 2 - 1) / 2)
    assert b.embed(crops[:0]).shape == (0, E)


def test_bad_crops_rejected(made):
    b = Bundle.load(made[0])
    with pytest.raises(ImageSizeError, match="expects"):
        b.embed(np.zeros((3, S + 2, S + 2, 3), np.uint8))
    with pytest.raises(ImageSizeError, match="uint8"):
        b.embed(np.zeros((3, S, S, 3), np.float32))


def test_shared_encoder_bundle(tmp_path):
    root = tmp_path / "shared"
    make_bundle(root, shared=True)
    assert not (root / "ch_encoder.onnx").exists()
    b = Bundle.load(root)
    assert b.shares_encoder
    crops = _crops(5)
    np.testing.assert_array_equal(b.ch_embed(crops), b.embed(crops))


def test_tampered_file_sha_mismatch(tmp_path):
    root = tmp_path / "b"
    make_bundle(root)
    data = bytearray((root / "ch_head.onnx").read_bytes())
    data[-1] ^= 0xFF
    (root / "ch_head.onnx").write_bytes(bytes(data))
    with pytest.raises(BundleError, match=r"ch_head\.onnx: sha256 mismatch"):
        Bundle.load(root)


def test_missing_file(tmp_path):
    root = tmp_path / "b"
    make_bundle(root)
    (root / "codebook.npz").unlink()
    with pytest.raises(BundleError, match=r"codebook\.npz: missing bundle file"):
        Bundle.load(root)


def test_missing_manifest_and_folder(tmp_path):
    with pytest.raises(BundleError, match="does not exist"):
        Bundle.load(tmp_path / "nope")
    with pytest.raises(BundleError, match=r"manifest\.json: missing"):
        Bundle.load(tmp_path)


def test_wrong_format_version(tmp_path):
    root = tmp_path / "b"
    make_bundle(root)
    _rewrite_manifest(root, format_version=99)
    with pytest.raises(BundleError, match="unsupported bundle format_version 99"):
        Bundle.load(root)


def test_unsupported_crop_size(tmp_path):
    root = tmp_path / "b"
    make_bundle(root)
    m = json.loads((root / "manifest.json").read_text())
    _rewrite_manifest(root, crop={**m["crop"], "size": 40})
    with pytest.raises(BundleError, match="crop size 40 is not supported"):
        Bundle.load(root)


def test_inconsistent_codebook_size(tmp_path):
    root = tmp_path / "b"
    make_bundle(root)
    _rewrite_manifest(root, codebook_size=K + 1)
    with pytest.raises(BundleError, match=r"codebook\.npz: rotations have shape"):
        Bundle.load(root)


def test_error_messages_are_one_line(tmp_path):
    root = tmp_path / "b"
    make_bundle(root)
    (root / "manifest.json").write_text("{not json")
    with pytest.raises(BundleError) as info:
        Bundle.load(root)
    assert "\n" not in str(info.value) and "manifest.json" in str(info.value)


def test_runtime_does_not_import_torch():
    code = "import sys, chpf.bundle; sys.exit(1 if 'torch' in sys.modules else 0)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_object_info_keeps_the_mesh_files_offset():
    """A manifest records where the tracked frame's origin lies in the mesh file's frame; one
    written before that field (the shipped bundles, centred objects) reads as zero."""
    from chpf.bundle import ObjectInfo

    entry = {"name": "part", "obj_id": 5, "diameter": 0.1, "file_offset": [0.0, 0.02, 0.04]}
    info = ObjectInfo.from_dict(entry)
    np.testing.assert_allclose(ObjectInfo.from_dict(info.to_dict()).file_offset, [0, 0.02, 0.04])
    del entry["file_offset"]
    np.testing.assert_array_equal(ObjectInfo.from_dict(entry).file_offset, np.zeros(3))
