"""Helpers shared by several test folders: hand-made ONNX graphs and model bundles.

``onnx`` is imported inside the functions: callers skip with ``pytest.importorskip("onnx")``.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np


def onnx_model(name: str, nodes: list, inputs: list, outputs: list, inits: list) -> bytes:
    """Serialised ONNX model (opset 17, IR version 8) of one graph built with ``onnx.helper``."""
    from onnx import helper

    graph = helper.make_graph(nodes, name, inputs, outputs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    return model.SerializeToString()


def dot_head_model(name: str, e: int, logit_nodes: list, consts: dict[str, float]) -> bytes:
    """CH head ONNX model: obs (B,e), cand (B,e) float -> p_misaligned (B,) = sigmoid(logit).

    ``d = <obs, cand>`` (B,) is computed first; ``logit_nodes`` map ``d`` and the float32
    scalar initialisers ``consts`` (name -> value) to ``logit``."""
    from onnx import TensorProto, helper, numpy_helper

    nodes = [
        helper.make_node("Mul", ["obs", "cand"], ["m"]),
        helper.make_node("ReduceSum", ["m", "axes"], ["d"], keepdims=0),
        *logit_nodes,
        helper.make_node("Sigmoid", ["logit"], ["p_misaligned"]),
    ]
    inits = [numpy_helper.from_array(np.array([1], np.int64), "axes")]
    inits += [numpy_helper.from_array(np.array(v, np.float32), k) for k, v in consts.items()]
    inputs = [
        helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", e]),
        helper.make_tensor_value_info("cand", TensorProto.FLOAT, ["batch", e]),
    ]
    outputs = [helper.make_tensor_value_info("p_misaligned", TensorProto.FLOAT, ["batch"])]
    return onnx_model(name, nodes, inputs, outputs, inits)


def write_bundle(
    root: Path,
    *,
    encoder: bytes,
    head: bytes,
    ch_encoder: bytes | None,
    codebook: dict[str, np.ndarray],
    obj: dict,
    crop: dict,
    training: dict,
    created_by: str,
    compress: bool = False,
) -> Path:
    """Write a model bundle into folder ``root`` (created); returns root.

    ``ch_encoder`` None: the CH shares the AE encoder. ``codebook``: the arrays of
    codebook.npz (rotations (K,3,3), ae_embeddings (K,E), ch_embeddings, depth). ``obj``: the
    manifest's object section, ``crop``: ``CropSpec.to_dict()``. The manifest lists every file
    with its sha256."""
    from chpf.bundle import FORMAT_VERSION

    root.mkdir(parents=True, exist_ok=True)
    shared = ch_encoder is None
    files = {"ae_encoder.onnx": encoder, "ch_head.onnx": head}
    if not shared:
        files["ch_encoder.onnx"] = ch_encoder
    for name, data in files.items():
        (root / name).write_bytes(data)
    (np.savez_compressed if compress else np.savez)(root / "codebook.npz", **codebook)
    names = [*files, "codebook.npz"]
    manifest = {
        "format_version": FORMAT_VERSION,
        "object": obj,
        "crop": crop,
        "embedding_dim": int(codebook["ae_embeddings"].shape[1]),
        "codebook_size": len(codebook["rotations"]),
        "ch_shares_ae_encoder": shared,
        "files": {
            "ae_encoder": "ae_encoder.onnx",
            "ch_obs_encoder": None if shared else "ch_encoder.onnx",
            "ch_head": "ch_head.onnx",
            "codebook": "codebook.npz",
        },
        "sha256": {n: hashlib.sha256((root / n).read_bytes()).hexdigest() for n in names},
        "training": training,
        "created_by": created_by,
    }
    (root / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return root


def vocap_reference(errors, max_threshold: float = 0.1) -> float:
    """VOCap AUC (percent): a line-by-line transcription of the YCB-Video toolbox's MATLAB
    (1-based indices kept as comments), independent of chpf.metrics."""
    D = [float(e) for e in errors]
    n = len(D)
    if n == 0:
        return 0.0
    D = [np.inf if e > max_threshold else e for e in D]  # D(D > max_distance) = inf
    d = sorted(D, key=lambda e: (np.isnan(e), e))  # sort: NaN last
    accuracy = [(i + 1) / n for i in range(n)]  # cumsum(ones(1, n)) / n
    rec = [d[i] for i in range(n) if np.isfinite(d[i])]
    prec = [accuracy[i] for i in range(n) if np.isfinite(d[i])]
    if not rec:
        return 0.0  # prec(end) fails in MATLAB: no success at all
    mrec = [0.0, *rec, max_threshold]
    mpre = [0.0, *prec, prec[-1]]
    for i in range(1, len(mpre)):
        mpre[i] = max(mpre[i], mpre[i - 1])
    ap = 0.0
    for i in range(1, len(mrec)):
        if mrec[i] != mrec[i - 1]:
            ap += (mrec[i] - mrec[i - 1]) * mpre[i]
    return ap / max_threshold * 100.0


DEMO_ROOT = Path(__file__).resolve().parents[1] / "chpf" / "assets" / "demo" / "box"
DEMO_SCENE = DEMO_ROOT / "test" / "000001"
DEMO_K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
"""Intrinsics of every frame of the shipped demo sequence (320x240)."""


PLAIN_FRAMES = 4
"""Frames in the tracking tests' image-folder fixture (tests/chpf/tracking/conftest.py)."""


def demo_frames(n: int) -> list[Path]:
    """The first ``n`` RGB frames of the shipped demo sequence (000001.png ...)."""
    return sorted((DEMO_SCENE / "rgb").glob("*.png"))[:n]


def demo_box(im_id: int) -> list[float]:
    """The demo's visible ground-truth box (x, y, w, h) of the tracked box in image ``im_id``."""
    info = json.loads((DEMO_SCENE / "scene_gt_info.json").read_text())[str(im_id)]
    gt = json.loads((DEMO_SCENE / "scene_gt.json").read_text())[str(im_id)]
    k = next(i for i, g in enumerate(gt) if g["obj_id"] == 2)
    return [float(v) for v in info[k]["bbox_visib"]]


def write_video(path: Path, frames: list[Path], fps: float = 10.0, fourcc: str = "mp4v") -> Path:
    """Write the image files ``frames`` as a video with OpenCV (``fourcc`` codec)."""
    import cv2

    first = cv2.imread(str(frames[0]))
    h, w = first.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened(), path
    for f in frames:
        writer.write(cv2.imread(str(f)))
    writer.release()
    return path


def count_video_frames(path: Path) -> int:
    """Frames OpenCV decodes from a video file."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def console_error(cli, capsys, monkeypatch, *argv) -> str:
    """Run a console script's ``cli()`` with ``argv``; assert exit 2 with one stderr line
    ``error: ...``; return that line."""
    import sys

    import pytest

    monkeypatch.setattr(sys, "argv", ["prog", *(str(a) for a in argv)])
    with pytest.raises(SystemExit) as exc:
        cli()
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    return err[0]
