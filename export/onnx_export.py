"""torch -> ONNX for the runtime graphs, and the onnxruntime-vs-torch parity check.

Encoders are exported with the preprocessing and the L2 normalisation inside the graph
(``training.models.NormalizedEmbedder``): input "crops" uint8 (N,S,S,3) RGB, output "embedding"
float32 (N,E). The head (``training.models.HeadProbability``) takes "obs" and "cand" float32
(N,E) and returns "p_misaligned" float32 (N,) with the sigmoid inside. The batch axis is dynamic.

We use the TorchScript-based exporter (``dynamo=False``): the torch.export-based one needs
``onnxscript``, which the [train] extra does not install, and these graphs need nothing newer.
Models are exported to bytes in memory, so nothing reaches the disk before the parity check.
"""

from __future__ import annotations

import io
import warnings
from collections.abc import Mapping

import numpy as np
import onnxruntime as ort
import torch
from torch import nn

from chpf.bundle import session_options
from chpf.errors import BundleError
from training.models import CHHead, Encoder, HeadProbability, NormalizedEmbedder

OPSET = 17
PARITY_TOL = 1e-4


def _export(
    module: nn.Module,
    args: tuple[torch.Tensor, ...],
    input_names: list[str],
    output_names: list[str],
) -> bytes:
    """Export ``module`` (eval mode, CPU) with a dynamic first axis on every input and output."""
    module = module.eval()
    dynamic = {name: {0: "batch"} for name in [*input_names, *output_names]}
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation notice
        torch.onnx.export(
            module,
            args,
            buf,
            input_names=input_names,
            output_names=output_names,
            dynamic_axes=dynamic,
            opset_version=OPSET,
            do_constant_folding=True,
            dynamo=False,
        )
    return buf.getvalue()


def embedder_module(encoder: Encoder) -> NormalizedEmbedder:
    """The runtime graph of one encoder branch (uint8 crops -> unit-norm embeddings)."""
    return NormalizedEmbedder(encoder).eval()


def head_module(head: CHHead) -> HeadProbability:
    """The runtime graph of the classifier head (sigmoid inside)."""
    return HeadProbability(head).eval()


def export_encoder(encoder: Encoder) -> bytes:
    """ONNX bytes of ``encoder`` with preprocessing and normalisation: "crops" -> "embedding"."""
    s = encoder.size
    dummy = torch.zeros((2, s, s, 3), dtype=torch.uint8)
    return _export(embedder_module(encoder), (dummy,), ["crops"], ["embedding"])


def export_head(head: CHHead) -> bytes:
    """ONNX bytes of the classifier head: "obs", "cand" (N,E) -> "p_misaligned" (N,)."""
    e = head.embedding_dim
    dummy = torch.nn.functional.normalize(torch.ones((2, e)), dim=1)
    return _export(head_module(head), (dummy, dummy), ["obs", "cand"], ["p_misaligned"])


def make_session(model: bytes, threads: int = 2, level: str = "all") -> ort.InferenceSession:
    """An onnxruntime CPU session over ONNX bytes, with the runtime's options."""
    return ort.InferenceSession(
        model, sess_options=session_options(threads, level), providers=["CPUExecutionProvider"]
    )


def parity_error(
    session: ort.InferenceSession, module: nn.Module, inputs: Mapping[str, np.ndarray]
) -> float:
    """Max abs difference between onnxruntime and torch outputs on the same ``inputs``."""
    got = session.run(None, dict(inputs))[0]
    with torch.no_grad():
        want = module(*(torch.from_numpy(np.ascontiguousarray(v)) for v in inputs.values()))
    want = want.detach().cpu().numpy()
    if got.shape != want.shape:
        return float("inf")
    return float(np.abs(got.astype(np.float64) - want.astype(np.float64)).max())


def check_parity(
    name: str,
    session: ort.InferenceSession,
    module: nn.Module,
    inputs: Mapping[str, np.ndarray],
    tol: float = PARITY_TOL,
) -> float:
    """Raise BundleError if onnxruntime and torch differ by more than ``tol``; returns the error."""
    err = parity_error(session, module, inputs)
    if not err <= tol:
        raise BundleError(
            f"{name}: onnxruntime differs from torch by {err:.3g} > {tol:g} on real crops; "
            "bundle not written"
        )
    return err
