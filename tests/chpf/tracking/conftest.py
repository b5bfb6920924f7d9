"""Shared fixtures for the tracking tests: a synthetic moving pose and its detection boxes; an
image folder of the demo's first frames and its camera file (the plain-input tests)."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass

import numpy as np
import pytest

from chpf.geometry import axis_angle_to_matrix, project_points
from tests.helpers import (
    DEMO_K,
    PLAIN_FRAMES,
    demo_frames,
    dot_head_model,
    onnx_model,
    write_bundle,
)

K_CAM = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
OBJ_SIZE = 0.15  # metres, extent used for the synthetic boxes


@dataclass
class SyntheticSequence:
    """Ground-truth poses (T,3,3), (T,3) of a slowly moving, rotating object and its boxes."""

    R: np.ndarray
    t: np.ndarray
    K: np.ndarray
    rgb: np.ndarray

    def box(self, i: int) -> tuple[float, float, float, float]:
        u, v = project_points(self.t[i], self.K)
        s = self.K[0, 0] * OBJ_SIZE / self.t[i, 2]
        return (float(u - s / 2), float(v - s / 2), float(s), float(s))

    def __len__(self) -> int:
        return int(self.t.shape[0])


def make_sequence(n: int = 60) -> SyntheticSequence:
    i = np.arange(n, dtype=np.float64)
    aa = np.stack([np.full(n, 0.3), 0.02 * i, np.full(n, 0.1)], axis=-1)
    t = np.stack([0.05 + 0.002 * i, np.full(n, -0.02), 0.8 + 0.001 * i], axis=-1)
    rgb = np.zeros((480, 640, 3), np.uint8)
    return SyntheticSequence(axis_angle_to_matrix(aa), t, K_CAM.copy(), rgb)


@pytest.fixture
def sequence() -> SyntheticSequence:
    return make_sequence()


# ----------------------------------------------------------------------------------------------
# A "template" model bundle: no training, real geometry. The encoder is ONNX built with
# onnx.helper: average-pool the crop 2x2, subtract its mean, L2-normalise (so the cosine is a
# normalised cross-correlation of the crop with a rendered codebook view); the classifier head is
# p_misaligned = sigmoid(HEAD_A * (HEAD_B - <obs, cand>)). The codebook is rendered with
# chpf.crops.render_crops. It makes a weak but real likelihood to test the runtime end to end.

TB_OBJECT = "box"
TB_SIZE = 32
TB_CODEBOOK = 512
HEAD_A, HEAD_B = 12.0, 0.6
SEQ_K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
SEQ_W, SEQ_H = 320, 240
OCCLUDER_R = axis_angle_to_matrix(np.array([np.pi / 2, 0.0, 0.0]))  # a can: seen from its side


def _template_encoder(size: int) -> bytes:
    from onnx import TensorProto, helper, numpy_helper

    e = 3 * (size // 2) ** 2
    nodes = [
        helper.make_node("Cast", ["crops"], ["f"], to=TensorProto.FLOAT),
        helper.make_node("Transpose", ["f"], ["chw"], perm=[0, 3, 1, 2]),
        helper.make_node("AveragePool", ["chw"], ["p"], kernel_shape=[2, 2], strides=[2, 2]),
        helper.make_node("Reshape", ["p", "shape"], ["flat"]),
        helper.make_node("ReduceMean", ["flat"], ["mean"], axes=[1], keepdims=1),
        helper.make_node("Sub", ["flat", "mean"], ["centred"]),
        helper.make_node("LpNormalization", ["centred"], ["embedding"], axis=1, p=2),
    ]
    return onnx_model(
        "template_encoder",
        nodes,
        [helper.make_tensor_value_info("crops", TensorProto.UINT8, ["batch", size, size, 3])],
        [helper.make_tensor_value_info("embedding", TensorProto.FLOAT, ["batch", e])],
        [numpy_helper.from_array(np.array([-1, e], np.int64), "shape")],
    )


def _template_head(e: int) -> bytes:
    from onnx import helper

    logit = [
        helper.make_node("Sub", ["b", "d"], ["x"]),
        helper.make_node("Mul", ["x", "a"], ["logit"]),
    ]
    return dot_head_model("template_head", e, logit, {"a": HEAD_A, "b": HEAD_B})


_VIEWS: dict = {}


def write_template_bundle(
    root, shared: bool = True, size: int = TB_SIZE, k: int = TB_CODEBOOK, name: str = TB_OBJECT
):
    """Write a template bundle of the built-in ``name`` (default TB_OBJECT) into folder
    ``root``; returns root."""
    import onnxruntime as ort

    from chpf.crops import CropSpec, render_crops
    from chpf.geometry import RotationGrid
    from chpf.objects import get_object, object_fingerprint
    from export.codebook import downsample_depth

    obj = get_object(name)
    spec = CropSpec.for_object(obj.diameter, size=size)
    grid = RotationGrid.uniform(k)
    key = (size, k, name)
    if key not in _VIEWS:  # render once per session for both bundles
        _VIEWS[key] = render_crops(None, obj, grid.rotations, spec)
    views = _VIEWS[key]
    enc = _template_encoder(size)
    sess = ort.InferenceSession(enc, providers=["CPUExecutionProvider"])
    emb = sess.run(None, {"crops": views.rgb})[0].astype(np.float32)
    return write_bundle(
        root,
        encoder=enc,
        head=_template_head(emb.shape[1]),
        ch_encoder=None if shared else enc,
        codebook={
            "rotations": grid.rotations.astype(np.float32),
            "ae_embeddings": emb,
            "ch_embeddings": emb,
            "depth": downsample_depth(views.depth, 2).astype(np.float16),
        },
        obj={
            "name": obj.name,
            "obj_id": obj.obj_id,
            "diameter": obj.diameter,
            "symmetries_discrete": [],
            "symmetries_continuous": [],
            "fingerprint": object_fingerprint(obj),
        },
        crop=spec.to_dict(),
        training={"note": "template bundle for tests (no training)"},
        created_by="tests/chpf/tracking/conftest.py",
    )


@pytest.fixture(scope="session")
def template_bundle(tmp_path_factory):
    """Path of a template bundle whose CH shares the AE encoder."""
    pytest.importorskip("onnx")
    return write_template_bundle(tmp_path_factory.mktemp("bundles") / "shared", shared=True)


@pytest.fixture(scope="session")
def template_bundle_split(tmp_path_factory):
    """Path of a template bundle with a separate CH observed-branch encoder."""
    pytest.importorskip("onnx")
    return write_template_bundle(tmp_path_factory.mktemp("bundles") / "split", shared=False)


@dataclass
class RenderedSequence:
    """Rendered frames of TB_OBJECT moving slowly: rgb (T,H,W,3), depth (T,H,W), masks, poses."""

    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    R: np.ndarray
    t: np.ndarray
    K: np.ndarray

    def box(self, i: int) -> tuple[float, float, float, float] | None:
        ys, xs = np.nonzero(self.mask[i])
        if xs.size == 0:
            return None
        x0, y0 = float(xs.min()), float(ys.min())
        return (x0, y0, float(xs.max()) - x0 + 1.0, float(ys.max()) - y0 + 1.0)

    def __len__(self) -> int:
        return int(self.t.shape[0])


def render_sequence(
    n: int = 24, name: str = TB_OBJECT, z: float = 0.55, occluder: str | None = None
) -> RenderedSequence:
    """n frames of built-in object ``name`` at about ``z`` metres, moving and turning slowly.

    ``occluder``: a built-in object that passes in front of it at 0.6 z, from left to right,
    covering its centre around frame n / 2; then ``mask`` (and the box) is the visible part.
    """
    from chpf.objects import get_object
    from chpf.render import Renderer

    obj = get_object(name)
    occ = get_object(occluder) if occluder is not None else None
    i = np.arange(n, dtype=np.float64)
    aa = np.stack([0.6 + 0.02 * i, 0.4 - 0.015 * i, 0.2 + 0.01 * i], axis=-1)
    R = axis_angle_to_matrix(aa)
    s = z / 0.55  # the box's path, scaled with the distance
    t = np.stack([s * (-0.03 + 0.003 * i), s * (0.02 - 0.001 * i), z + s * 0.002 * i], axis=-1)
    rgb = np.zeros((n, SEQ_H, SEQ_W, 3), np.uint8)
    depth = np.zeros((n, SEQ_H, SEQ_W), np.float32)
    mask = np.zeros((n, SEQ_H, SEQ_W), bool)
    with Renderer(SEQ_W, SEQ_H) as r:
        for k in range(n):
            scene = [(obj, R[k], t[k])]
            if occ is not None:  # crosses the object's ray at frame n / 2, 1.2 diameters a side
                side = 0.6 * (t[k, :2] / t[k, 2]) * z
                dx = 1.2 * obj.diameter * 0.6 * (2.0 * k / max(n - 1, 1) - 1.0)
                scene.append((occ, OCCLUDER_R, np.array([side[0] + dx, side[1], 0.6 * z])))
            out = r.render(scene, SEQ_K)
            rgb[k], depth[k] = out.rgb, out.depth
            mask[k] = out.masks[0] if occ is None else out.visible_masks[0]
    return RenderedSequence(rgb, depth, mask, R, t, SEQ_K.copy())


@pytest.fixture(scope="session")
def rendered_sequence() -> RenderedSequence:
    return render_sequence()


@pytest.fixture
def sequence_renderer():
    """render_sequence(n, name, z) for tests that need another object or length."""
    return render_sequence


@pytest.fixture
def images(tmp_path):
    """A folder of the demo's first PLAIN_FRAMES RGB frames."""
    folder = tmp_path / "rgb"
    folder.mkdir()
    for f in demo_frames(PLAIN_FRAMES):
        shutil.copy(f, folder)
    return folder


@pytest.fixture
def camera(tmp_path):
    """A camera JSON (K, width, height) of the demo's frames."""
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({"K": DEMO_K.tolist(), "width": 320, "height": 240}))
    return path
