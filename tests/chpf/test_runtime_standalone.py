"""The runtime package ``chpf`` stands alone: it imports none of the training side, and it
tracks without pyrender / OpenGL (rendering is the ``chpf[render]`` extra)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import chpf

CHPF = Path(chpf.__file__).resolve().parent
FORBIDDEN = {"data_gen", "training", "export", "torch", "torchvision", "lightning", "onnx"}
RENDER_ONLY = {"pyrender", "OpenGL"}
"""Imported only by chpf.render (and chpf.gl_platform, which selects the platform)."""


def _imported_roots(path: Path) -> set[str]:
    """Top-level package names of every import in a module, at any depth (lazy ones too)."""
    roots: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            roots.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
    return roots


def test_no_chpf_module_imports_the_training_side_or_rendering_outside_render():
    modules = sorted(CHPF.rglob("*.py"))
    assert len(modules) > 30
    bad = {str(p.relative_to(CHPF)): _imported_roots(p) & FORBIDDEN for p in modules}
    assert {k: v for k, v in bad.items() if v} == {}
    gl = {str(p.relative_to(CHPF)) for p in modules if _imported_roots(p) & RENDER_ONLY}
    assert gl <= {"render.py", "gl_platform.py"}, gl


BLOCKED_RUN = r"""
import importlib.abc, sys

BLOCKED = {"pyrender", "OpenGL", "torch", "data_gen", "training", "export"}

class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"No module named {name!r} (blocked by the test)")
        return None

sys.meta_path.insert(0, Blocker())
import chpf.bop, chpf.bundle, chpf.eval_cli, chpf.metrics, chpf.track_cli, chpf.tracking
from chpf.errors import RenderError
from chpf.track_cli import main

code = main(["--demo", "--method", "chpf", "--out", sys.argv[1], "--no-plot", "--no-progress"])
assert code == 0, code
assert not {m.split(".")[0] for m in sys.modules} & BLOCKED
from chpf.render import Renderer
try:
    Renderer(64, 64)
except RenderError as err:
    print("render:", err)
"""


def test_runtime_tracks_the_demo_with_pyrender_and_opengl_blocked(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-c", BLOCKED_RUN, str(tmp_path / "demo")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    table = (tmp_path / "demo" / "auc_table.txt").read_text()
    row = next(line.split() for line in table.splitlines() if line.startswith("chpf "))
    assert row[1:3] == ["60", "0"] and float(row[4]) > 20.0
    render = [line for line in proc.stdout.splitlines() if line.startswith("render:")]
    assert len(render) == 1 and "pip install 'chpf[render]'" in render[0]
