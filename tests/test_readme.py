"""The README's Python API example runs as written (it is what users copy), and its demo table is
what `chpf-track --demo` prints."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from training.precision import cpu_flags

ROOT = Path(__file__).resolve().parents[1]


def test_readme_python_api_example_runs():
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Python API") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 10 and all("alpha=" in line for line in lines)


def _auc_rows(lines: list[str]) -> list[list[str]]:
    """The rows of an ADD/ADD-S AUC table (method, frames, missing, ADD AUC, ADD-S AUC)."""
    start = next(i for i, line in enumerate(lines) if "ADD-S AUC" in line)
    rows = []
    for line in lines[start + 1 :]:
        cells = line.split()
        if len(cells) >= 5 and cells[1].isdigit():
            rows.append(cells[:5])
        elif rows:
            break
    return rows


def test_readme_demo_table_is_what_the_demo_prints(tmp_path, capsys):
    """``chpf-track --demo --no-plot`` (shipped bundle, shipped occluded sequence, seed 0)
    prints the README's table, fps aside (8 s in the suite here, 11 s of CPU)."""
    from chpf.track_cli import main

    assert main(["--demo", "--no-plot", "--no-progress", "--out", str(tmp_path / "out")]) == 0
    printed = _auc_rows(capsys.readouterr().out.splitlines())
    text = (ROOT / "README.md").read_text()
    tables = r"```text\n.*?```.*?```text\n.*?```"
    section = re.search(r"`chpf-track --demo --no-plot`.*?" + tables, text, re.S)
    blocks = re.findall(r"```text\n(.*?)```", section.group(0), re.S)
    # the first table is what CPUs with AVX-512 print, the second AVX2-only ones (README)
    block = blocks[0] if "avx512f" in cpu_flags() else blocks[1]
    readme = _auc_rows(block.splitlines())
    assert [r[0] for r in readme] == ["chpf", "chrbpf", "srl", "poserbpf"]
    assert printed == readme
