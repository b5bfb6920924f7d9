"""report.md in the bundle folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def _j(p: Path) -> Any:
    return json.loads(p.read_text()) if p.is_file() else None


def _flat(d: Any, prefix: str = "") -> list[tuple[str, Any]]:
    if isinstance(d, dict):
        out = []
        for k, v in d.items():
            out += _flat(v, f"{prefix}{k}.")
        return out
    if isinstance(d, (int, float, str)):
        return [(prefix[:-1], d)]
    return []


def write_report(out: Path, work: Path, argv: list[str], settings: dict, plan_md: str,
                 stage_md: str) -> Path:  # fmt: skip
    lines = [
        "# chpf-make-bundle report",
        "",
        "## Command",
        "",
        "```",
        "chpf-make-bundle " + " ".join(argv),
        "```",
        "",
        "## Settings",
        "",
        "```json",
        json.dumps(settings, indent=2, sort_keys=True),
        "```",
        "",
        "## Plan",
        "",
        plan_md,
        "",
        "## Stages (wall time)",
        "",
        stage_md,
        "",
    ]
    base = settings.get("base", {})
    if base.get("preset") == "tiny" or base.get("budget_s", 1e9) < 1800:
        lines += [
            "A short budget: fewer renders, samples and training steps than the shipped",
            "recipe (90 minutes); expect a larger retrieval error and lower AUCs.",
            "",
        ]
    for name, title in (
        ("eval_ae", "Autoencoder retrieval (held-out ae crops, no jitter)"),
        ("eval_pairs", "Classifier, training family (pairs)"),
        ("eval_pairs_test", "Classifier, held-out family (pairs_test)"),
    ):
        res = _j(work / f"{name}.json")
        if res is None:
            continue
        lines += [f"## {title}", "", "| figure | value |", "| --- | --- |"]
        for k, v in _flat(res):
            if isinstance(v, float):
                v = f"{v:.4g}"
            lines.append(f"| {k} | {v} |")
        lines.append("")
    if (out / "contact_sheet.png").is_file():
        lines += ["## Samples", "", "![contact sheet](contact_sheet.png)", ""]
    trk = work / "track_stdout.txt"
    if trk.is_file():
        lines += [
            "## Tracking the generated test sequence",
            "",
            "```",
            trk.read_text().strip(),
            "```",
            "",
        ]
    for png in sorted(out.glob("track_*.png")):
        lines += [f"![{png.stem}]({png.name})", ""]
    path = out / "report.md"
    tmp = path.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines))
    tmp.replace(path)
    return path
