"""Contact sheets (PNG) to look at generated data: pairs, ae samples, sequence frames."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from chpf import bop
from chpf.atomic import atomic_write_bytes
from chpf.errors import DatasetError
from data_gen.shards import MANIFEST, ShardDataset

GREEN = (40, 200, 60)
RED = (230, 50, 40)
YELLOW = (250, 220, 0)
WHITE = (255, 255, 255)
OBJ_COLOURS = [(40, 220, 60), (60, 140, 255), (255, 120, 40), (220, 60, 220), (0, 220, 220)]


def _label(img: np.ndarray, text: str, colour: tuple, height: int = 16) -> np.ndarray:
    """``img`` with a dark strip on top holding ``text``."""
    strip = np.full((height, img.shape[1], 3), 30, np.uint8)
    cv2.putText(
        strip, text, (3, height - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.38, colour, 1, cv2.LINE_AA
    )
    return np.concatenate([strip, img], 0)


def _grid(cells: list[np.ndarray], cols: int, pad: int = 4) -> np.ndarray:
    """Tile equally sized cells into a grid with padding."""
    h, w = cells[0].shape[:2]
    rows = (len(cells) + cols - 1) // cols
    sheet = np.full((rows * (h + pad) + pad, cols * (w + pad) + pad, 3), 70, np.uint8)
    for k, c in enumerate(cells):
        r, q = divmod(k, cols)
        y, x = pad + r * (h + pad), pad + q * (w + pad)
        sheet[y : y + h, x : x + w] = c
    return sheet


def _up(img: np.ndarray, side: int) -> np.ndarray:
    return cv2.resize(img, (side, side), interpolation=cv2.INTER_NEAREST)


def _save_png(path: Path, rgb: np.ndarray) -> Path:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise DatasetError(f"{path}: cannot encode PNG")
    atomic_write_bytes(path, buf.tobytes())
    return path


def _pick(ds: ShardDataset, n: int, key: str | None = None) -> list[dict]:
    """First samples of the first shard; for pairs half positives, half negatives."""
    arrays = ds.load_shard(0)
    if key is None:
        idx = list(range(min(n, len(arrays["visib_fract"]))))
    else:
        lab = np.asarray(arrays[key])
        pos, neg = np.flatnonzero(lab == 1), np.flatnonzero(lab == 0)
        half = n // 2
        idx = [int(i) for pair in zip(pos[:half], neg[:half], strict=False) for i in pair]
    return [{k: np.asarray(v[i]) for k, v in arrays.items()} for i in idx]


def pairs_sheet(ds: ShardDataset, n: int) -> np.ndarray:
    """Cells 'observed | candidate' labelled POS/NEG, angle and visible fraction."""
    side = max(96, ds.crop_size)
    cells = []
    for s in _pick(ds, n, "aligned"):
        pos = bool(s["aligned"])
        img = np.concatenate([_up(s["obs_rgb"], side), _up(s["cand_rgb"], side)], 1)
        txt = f"{'POS' if pos else 'NEG'} {s['angle_deg']:.0f}deg vis {s['visib_fract']:.2f}"
        cells.append(_label(img, txt, GREEN if pos else RED))
    return _grid(cells, 4)


def ae_sheet(ds: ShardDataset, n: int) -> np.ndarray:
    """Cells 'input | target (mask outlined)' with the visible fraction."""
    side = max(96, ds.crop_size)
    cells = []
    for s in _pick(ds, n):
        tgt = _up(s["target_rgb"], side)
        m = _up(s["target_mask"].astype(np.uint8), side)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        tgt = tgt.copy()
        cv2.drawContours(tgt, contours, -1, YELLOW, 1)
        img = np.concatenate([_up(s["input_rgb"], side), tgt], 1)
        cells.append(_label(img, f"input | target  vis {s['visib_fract']:.2f}", WHITE))
    return _grid(cells, 4)


def sequence_sheet(scene_dir: Path, n: int, detections: Path | None = None) -> np.ndarray:
    """Evenly spaced frames (half size) with every object's visible mask outlined (target in
    green), the simulated detection box (yellow) and the target's visible fraction."""
    from chpf.bop import BopScene, read_detections

    scene = BopScene(scene_dir)
    ims = scene.image_ids()
    if not ims:
        raise DatasetError(f"{scene_dir}: no images")
    pick = sorted({ims[round(i)] for i in np.linspace(0, len(ims) - 1, min(n, len(ims)))})
    dets = read_detections(detections) if detections and detections.is_file() else {}
    cells = []
    for im in pick:
        rgb = scene.rgb(im).copy()
        gts = scene.gt.get(im, [])
        for g, _gt in enumerate(gts):
            m = scene.mask_visib(im, g).astype(np.uint8)
            contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(rgb, contours, -1, OBJ_COLOURS[g % len(OBJ_COLOURS)], 2)
        if gts:
            box = dets.get((scene.scene_id, im, gts[0].obj_id))
            if box is not None:
                x, y, w, h = (round(v) for v in box)
                cv2.rectangle(rgb, (x, y), (x + w, y + h), YELLOW, 2)
        vis = scene.gt_info.get(im, [])
        txt = f"im {im}" + (f"  target vis {vis[0].visib_fract:.2f}" if vis else "")
        if gts and (scene.scene_id, im, gts[0].obj_id) not in dets and dets:
            txt += "  (no det)"
        small = cv2.resize(
            rgb, (rgb.shape[1] // 2, rgb.shape[0] // 2), interpolation=cv2.INTER_AREA
        )
        cells.append(_label(small, txt, WHITE))
    return _grid(cells, 4)


def contact_sheet(
    path: str | Path, out: str | Path, n: int = 24, scene_id: int | None = None
) -> Path:
    """Write a contact sheet of a pairs/ae folder, a BOP root (first/selected scene of the
    test split) or a scene folder to ``out`` (PNG)."""
    path, out = Path(path), Path(out)
    if (path / MANIFEST).is_file():
        ds = ShardDataset(path, allow_partial=True)
        if ds.num_shards == 0:
            raise DatasetError(f"{path}: no complete shard yet")
        sheet = pairs_sheet(ds, n) if ds.kind == "pairs" else ae_sheet(ds, n)
        return _save_png(out, sheet)
    if (path / bop.SCENE_GT).is_file() or (path / bop.SCENE_CAMERA).is_file():
        root = path.parent.parent
        return _save_png(out, sequence_sheet(path, n, root / bop.DETECTIONS_SIM))
    info = path / bop.SEQUENCES_INFO
    split = json.loads(info.read_text())["split"] if info.is_file() else "test"
    scenes = (
        sorted(p for p in (path / split).glob("[0-9]*") if p.is_dir())
        if (path / split).is_dir()
        else []
    )
    if scene_id is not None:
        scenes = [p for p in scenes if int(p.name) == scene_id]
    if not scenes:
        raise DatasetError(f"{path}: not a pairs/ae folder, BOP root or scene folder")
    return _save_png(out, sequence_sheet(scenes[0], n, path / bop.DETECTIONS_SIM))
