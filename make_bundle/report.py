"""report.md in the bundle folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from training.metrics import band_label


def _j(p: Path) -> Any:
    return json.loads(p.read_text()) if p.is_file() else None


# the keys of training.evaluate's band rows: visible fraction, the crop's scale error
BAND_KEYS = ("visib", "scale_off")


def _flat(d: Any, prefix: str = "") -> list[tuple[str, Any]]:
    if isinstance(d, dict):
        out = []
        for k, v in d.items():
            out += _flat(v, f"{prefix}{k}.")
        return out
    first = d[0] if isinstance(d, list) and d and isinstance(d[0], dict) else {}
    key = next((k for k in BAND_KEYS if k in first), None)
    if key and all(isinstance(x, dict) and key in x for x in d):
        out = []  # bands (training.evaluate): one row per band and figure
        for band in d:
            label = band_label(*band[key])
            out += _flat({k: v for k, v in band.items() if k != key}, f"{prefix}{label}.")
        return out
    if isinstance(d, (int, float, str)):
        return [(prefix[:-1], d)]
    return []


def budget_cost(settings: dict, workers: int) -> list[str]:
    """Markdown lines: the stages that a budget below the default made smaller than the default
    budget's plan on the same measured rates would (nothing for the default or a preset)."""
    from make_bundle.measure import Rates
    from make_bundle.plan import DEFAULT_BUDGET_S, Plan, make_plan

    base, measured = settings.get("base", {}), settings.get("measured")
    if base.get("preset") is not None or base.get("budget_s", 0) >= DEFAULT_BUDGET_S:
        return []
    ref = make_plan(DEFAULT_BUDGET_S, None, Rates(**measured) if measured else None, workers)
    mine, theirs = Plan(**settings["plan"]).sizes(), ref.sizes()
    rows = [f"| {k} | {v} | {theirs[k]} |" for k, v in mine.items() if v != theirs[k]]
    return [
        f"## What the {base['budget_s'] / 60:.0f}-minute budget cost",
        "",
        f"Against the default budget ({DEFAULT_BUDGET_S // 60} min) on the same measured "
        "rates, these stages were made smaller; expect a larger retrieval error and lower "
        'AUCs than the default budget\'s bundle (README, "chpf-make-bundle").',
        "",
        "| stage | this budget | default budget |",
        "| --- | --- | --- |",
        *rows,
        "",
    ]


def object_lines(manifest: dict | None) -> list[str]:
    """Markdown lines: the bundle's object, and the point it is tracked about (its mesh's
    bounding-box centre, chpf.objects.ObjectModel.centred) in the mesh file's frame; nothing
    without a bundle manifest."""
    obj = (manifest or {}).get("object")
    if not obj:
        return []
    x, y, z = (1000.0 * v for v in obj.get("file_offset", (0.0, 0.0, 0.0)))
    return [
        "## Object",
        "",
        "| figure | value |",
        "| --- | --- |",
        f"| name, obj_id | {obj['name']}, {obj['obj_id']} |",
        f"| diameter | {1000.0 * obj['diameter']:.1f} mm |",
        f"| crops centred on (the bounding box's centre, in the mesh file's frame; poses are "
        f"reported in that frame) | ({x:.1f}, {y:.1f}, {z:.1f}) mm |",
        "",
    ]


def write_report(out: Path, work: Path, argv: list[str], settings: dict, plan_md: str,
                 stage_md: str, workers: int) -> Path:  # fmt: skip
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
    lines += object_lines(_j(out / "manifest.json"))
    lines += budget_cost(settings, workers)
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
