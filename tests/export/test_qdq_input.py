"""export.qdq_input: the int8 encoders read their uint8 crops directly, bit for bit as before."""

from __future__ import annotations

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")

from chpf.tracking.demo import shipped_bundle  # noqa: E402
from export.qdq_input import _embed, _rewrite, fold_input_chain  # noqa: E402
from export.quantize import quantize_qdq  # noqa: E402


def _chain_ops(model: onnx.ModelProto) -> list[str]:
    """The Cast and Mul nodes (the exporter's uint8 -> float chain) of ``model``."""
    return [n.op_type for n in model.graph.node if n.op_type in ("Cast", "Mul")]


@pytest.mark.parametrize("name", ["ae_encoder", "ch_encoder"])
def test_shipped_int8_encoders_read_the_crops_directly(name):
    model = onnx.load(shipped_bundle() / f"{name}.int8.onnx")
    assert not _chain_ops(model) and _rewrite(model) is None


def test_unfolded_quantized_model_folds():
    """A QDQ model with the exporter's Cast / Mul chain (built here from the float32 encoder)
    comes out without it and with the same outputs."""
    rng = np.random.default_rng(1)
    calib = rng.integers(0, 256, (16, 64, 64, 3), dtype=np.uint8)
    calib[0] = 255  # the input's range reaches 1.0: scale 1/255
    model = quantize_qdq(shipped_bundle() / "ae_encoder.onnx", calib)
    assert _chain_ops(onnx.load_from_string(model))
    folded = fold_input_chain(model, calib)
    assert folded is not None and not _chain_ops(onnx.load_from_string(folded))
    crops = rng.integers(0, 256, (10, 64, 64, 3), dtype=np.uint8)
    np.testing.assert_array_equal(
        _embed(onnx.load_from_string(folded), crops), _embed(onnx.load_from_string(model), crops)
    )


def test_float32_encoder_is_left_alone():
    assert fold_input_chain((shipped_bundle() / "ae_encoder.onnx").read_bytes()) is None
