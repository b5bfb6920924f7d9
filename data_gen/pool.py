"""Render pools, built once per object and cached on disk; samples are composed from them.

Three pools, each a folder ``CACHE/{kind}-{object}-{key}/`` of ``.npy`` arrays plus
``meta.json``; ``key`` hashes the object fingerprint, the CropSpec and the pool settings, so a
changed mesh or setting builds a new pool and an unchanged one is reused (also by export):

* codebook pool: the object alone at each ``RotationGrid.uniform(k)`` orientation in the
  codebook convention (``chpf.crops.render_crops``): rgb, depth (float32 m), mask.
* observation pool: the object at random off-centre poses in a virtual camera, rendered only in
  a window around its projection (RGB under several lights, depth, mask), plus its clean
  codebook-convention render at the same allocentric orientation (autoencoder target).
* occluder pool: other built-in objects at random orientations in their own codebook
  convention (rgb, mask), pasted as occluders and clutter.

Window geometry: the window is the crop the tracker would cut at the true translation ``t``
with a ``margin`` times larger side: ``crop_affines(t, K, CropSpec(P, D_r, f_r))`` with
``P = ceil(margin * S)`` maps window pixels to image pixels (stored as ``win_affine``); the
window is rendered directly with intrinsics ``K_win`` derived from that affine, so any crop
``crop_affines(t', K, spec)`` of the full frame is the window warped by
``win_affine^-1 o crop_affine`` (see ``crop_to_window_affines``).

Cache folder: ``--cache-dir``, else ``$CHPF_CACHE/pools``, else ``~/.cache/chpf/pools``.
Pools are streamed to disk chunk by chunk (memory-mapped ``.npy`` arrays in a part folder,
resumable, renamed into place when complete: ``data_gen.pool_store``) and read back as read-only
memory maps whose pages the generator gives back after each shard, so that neither building
nor composing holds a pool in memory.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing as mp
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from chpf.crops import CropBatch, CropSpec, crop_affines
from chpf.geometry import RotationGrid, egocentric_to_allocentric, random_rotations
from data_gen.pool_store import PoolBuild, load_arrays, load_or_build

POOL_VERSION = 1
CHUNK = 64  # renders per progress step / per worker task


def default_cache_dir() -> Path:
    """``$CHPF_CACHE/pools`` if CHPF_CACHE is set, else ``~/.cache/chpf/pools``."""
    root = os.environ.get("CHPF_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "chpf") / "pools"


def _key(parts: dict) -> str:
    return hashlib.sha1(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:16]


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:40]


def _pool_path(cache_dir: str | Path | None, kind: str, name: str, parts: dict) -> Path:
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return root / f"{kind}-{_safe(name)}-{_key({'kind': kind, 'v': POOL_VERSION, **parts})}"


def _require_arrays(path: str | Path, names: list[str], mmap: bool, what: str) -> dict:
    """The arrays ``names`` of an existing pool folder; FileNotFoundError naming ``what``."""
    arrays = load_arrays(Path(path), names, mmap)
    if arrays is None:
        raise FileNotFoundError(f"{path}: no {what}")
    return arrays


def _chunks(n: int, size: int = CHUNK) -> list[tuple[int, int]]:
    return [(a, min(a + size, n)) for a in range(0, n, size)]


class TaskRunner:
    """Maps a function over tasks in order, in-process (workers <= 1) or in a lazily started
    pool of ``workers`` spawned processes that is shared by every pool build using it."""

    def __init__(self, workers: int = 1) -> None:
        self.workers = int(workers)
        self._pool = None

    def imap(self, fn, tasks: list):
        if self.workers <= 1 or len(tasks) <= 1:
            return map(fn, tasks)
        if self._pool is None:
            self._pool = mp.get_context("spawn").Pool(self.workers)
        return self._pool.imap(fn, tasks)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool.join()
            self._pool = None

    def __enter__(self) -> TaskRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        if exc[0] is not None and self._pool is not None:
            self._pool.terminate()
        self.close()


@contextmanager
def _task_runner(runner: TaskRunner | None, workers: int) -> Iterator[TaskRunner]:
    """``runner`` if given, else a TaskRunner of ``workers`` closed on exit."""
    if runner is not None:
        yield runner
        return
    with TaskRunner(workers) as own:
        yield own


def _iter_chunks(
    fn, tasks: list, runner: TaskRunner, desc: str, progress: bool, total: int, initial: int = 0
) -> Iterator:
    """Yield ``fn(task) -> (n_done, result)``'s results in task order, with a progress bar of
    ``total`` renders that starts at ``initial`` (a resumed build)."""
    bar = tqdm(
        total=total, initial=initial, desc=desc, unit="render", disable=not progress or None,
        leave=False,
    )  # fmt: skip
    try:
        for n, r in runner.imap(fn, tasks):
            bar.update(n)
            yield r
    finally:
        bar.close()


def _remaining(ranges: list[tuple[int, int]]) -> int:
    return sum(b - a for a, b in ranges)


# Per-process renderer cache for pool building (one GL context per size).
_RENDERERS: dict[tuple[int, int], Any] = {}


def _renderer(w: int, h: int):
    from chpf.render import Renderer  # imported lazily: generating from cached pools needs no GL

    if (w, h) not in _RENDERERS:
        _RENDERERS[(w, h)] = Renderer(w, h)
    return _RENDERERS[(w, h)]


# Per-process object cache: the renderer caches GL meshes by mesh identity, so every task of
# the same object must use the same (first unpickled) instance.
_OBJECTS: dict[str, Any] = {}


def _same_object(obj) -> Any:
    from chpf.objects import object_fingerprint

    return _OBJECTS.setdefault(object_fingerprint(obj), obj)


def _crops_task(task: tuple) -> tuple[int, dict[str, np.ndarray]]:
    """Render (obj, R (n,3,3), spec) in the codebook convention: rgb, depth (f32 m), mask."""
    from chpf.crops import render_crops

    obj, R, spec = task
    obj = _same_object(obj)
    cb = render_crops(_renderer(spec.size, spec.size), obj, R, spec)
    arrays = {"rgb": cb.rgb, "depth": np.asarray(cb.depth, np.float32), "mask": cb.mask}
    return len(R), {k: np.asarray(v) for k, v in arrays.items()}


# ----------------------------------------------------------------------------- codebook pool


def codebook_pool_path(obj, spec: CropSpec, k: int, cache_dir: str | Path | None = None) -> Path:
    """Cache folder of the codebook pool of (obj, spec, k)."""
    from chpf.objects import object_fingerprint

    parts = {"object": object_fingerprint(obj), "crop": spec.to_dict(), "k": int(k)}
    return _pool_path(cache_dir, "codebook", obj.name, parts)


def codebook_pool(
    obj,
    spec: CropSpec,
    k: int,
    cache_dir: str | Path | None = None,
    *,
    workers: int = 1,
    progress: bool = True,
    mmap: bool = False,
    runner: TaskRunner | None = None,
) -> tuple[RotationGrid, CropBatch]:
    """(RotationGrid.uniform(k), CropBatch (k,S,S) rgb/depth/mask) of ``obj`` in the codebook
    convention (object at (0,0,D_r), K = spec.K), rendered once and cached under ``cache_dir``
    (None: ``default_cache_dir()``). ``mmap``: return read-only memory maps. ``workers``:
    render processes when the pool must be built (or pass a shared ``runner``)."""
    grid = RotationGrid.uniform(int(k))

    meta = {"kind": "codebook", "object": obj.name, "crop": spec.to_dict(), "k": int(k)}
    desc = f"codebook pool {obj.name} k={k}"

    def build(r: TaskRunner) -> PoolBuild:
        def render(ranges: list[tuple[int, int]]) -> Iterator[dict[str, np.ndarray]]:
            tasks = [(obj, grid.rotations[a:b], spec) for a, b in ranges]
            done = int(k) - _remaining(ranges)
            return _iter_chunks(_crops_task, tasks, r, desc, progress, int(k), done)

        return PoolBuild(int(k), _chunks(int(k)), render, meta)

    path = codebook_pool_path(obj, spec, k, cache_dir)
    with _task_runner(runner, workers) as r:
        arrays = load_or_build(path, ["rgb", "depth", "mask"], mmap, lambda: build(r))
    return grid, CropBatch(rgb=arrays["rgb"], depth=arrays["depth"], mask=arrays["mask"])


def load_codebook_pool(path: str | Path, mmap: bool = True) -> CropBatch:
    """The CropBatch of an existing codebook pool folder (no object needed)."""
    arrays = _require_arrays(path, ["rgb", "depth", "mask"], mmap, "codebook pool")
    return CropBatch(rgb=arrays["rgb"], depth=arrays["depth"], mask=arrays["mask"])


# ----------------------------------------------------------------------------- observation pool


@dataclass
class ObsPool:
    """Observation pool arrays (n entries, L lights, window P, crop S).

    R_ego (n,3,3), t (n,3) m, K (n,3,3) virtual full-frame camera, win_affine (n,2,3) window
    pixel -> image pixel, rgb (n,L,P,P,3) u8, depth (n,P,P) f16 m, mask (n,P,P) bool,
    alpha (n,P,P) u8 anti-aliased coverage (rgb is premultiplied by it: composite as
    ``rgb + bg * (1 - alpha/255)``), R_allo (n,3,3), clean_rgb (n,S,S,3) u8 and clean_mask
    (n,S,S) bool (codebook convention, the autoencoder target).
    """

    R_ego: np.ndarray
    t: np.ndarray
    K: np.ndarray
    win_affine: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    alpha: np.ndarray
    R_allo: np.ndarray
    clean_rgb: np.ndarray
    clean_mask: np.ndarray
    path: Path | None = None

    FIELDS = (
        "R_ego", "t", "K", "win_affine", "rgb", "depth", "mask", "alpha", "R_allo",
        "clean_rgb", "clean_mask",
    )  # fmt: skip

    def __len__(self) -> int:
        return int(self.t.shape[0])


def window_size(spec: CropSpec, margin: float) -> int:
    """Window side P = ceil(margin * S) pixels."""
    return math.ceil(margin * spec.size - 1e-9)


def window_spec(spec: CropSpec, margin: float) -> CropSpec:
    """CropSpec of the window: same D_r and f_r as ``spec``, side ``window_size``."""
    return CropSpec(
        size=window_size(spec, margin), render_distance=spec.render_distance, focal=spec.focal
    )


def window_intrinsics(K: np.ndarray, win_affine: np.ndarray) -> np.ndarray:
    """K_win (3,3) that renders exactly the window whose pixel -> image affine is ``win_affine``
    (u = a i + b, v = c j + d) for a full-frame camera ``K``."""
    a, b = win_affine[0, 0], win_affine[0, 2]
    c, d = win_affine[1, 1], win_affine[1, 2]
    return np.array(
        [[K[0, 0] / a, K[0, 1] / a, (K[0, 2] - b) / a], [0.0, K[1, 1] / c, (K[1, 2] - d) / c],
         [0.0, 0.0, 1.0]]
    )  # fmt: skip


def crop_to_window_affines(
    t_est: np.ndarray, K: np.ndarray, win_affine: np.ndarray, spec: CropSpec
) -> np.ndarray:
    """(N,2,3) crop pixel -> window pixel affines: the crop the tracker would cut at t_est (N,3)
    from the full frame of camera K (N,3,3), expressed in window pixels (win_affine (N,2,3))."""
    n = len(t_est)
    A = np.empty((n, 2, 3))
    for i in range(n):
        A[i] = crop_affines(t_est[i : i + 1], K[i], spec)[0]
    W3 = np.zeros((n, 3, 3))
    W3[:, :2] = win_affine
    W3[:, 2, 2] = 1.0
    A3 = np.zeros((n, 3, 3))
    A3[:, :2] = A
    A3[:, 2, 2] = 1.0
    return (np.linalg.inv(W3) @ A3)[:, :2]


def sample_obs_poses(obj_diameter: float, cfg: dict, n: int, rng: np.random.Generator) -> dict:
    """Random poses and cameras of the observation pool (``cfg``: the obs_pool section).

    Haar orientation; fx = fy uniform in focal_range, principal point at the image centre;
    z uniform in z_range (at least min_z_diameters diameters); projection uniform over the
    image, keeping the object's bounding circle inside when possible.
    """
    W, H = cfg["image_width"], cfg["image_height"]
    f = rng.uniform(*cfg["focal_range"], n)
    z = np.maximum(rng.uniform(*cfg["z_range"], n), cfg["min_z_diameters"] * obj_diameter)
    r = f * 0.5 * obj_diameter / z
    cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    ux = np.clip((W - 1) / 2.0 - r, 0, None)
    vy = np.clip((H - 1) / 2.0 - r, 0, None)
    u = cx + rng.uniform(-1, 1, n) * ux
    v = cy + rng.uniform(-1, 1, n) * vy
    t = np.stack([(u - cx) * z / f, (v - cy) * z / f, z], axis=1)
    K = np.zeros((n, 3, 3))
    K[:, 0, 0] = f
    K[:, 1, 1] = f
    K[:, 0, 2] = cx
    K[:, 1, 2] = cy
    K[:, 2, 2] = 1.0
    L = cfg["lights_per_entry"]
    light_dir = np.concatenate([rng.normal(0.0, 0.6, (n, L, 2)), np.ones((n, L, 1))], axis=2)
    return {
        "R_ego": random_rotations(n, rng),
        "t": t,
        "K": K,
        "light": rng.uniform(*cfg["light_intensity_range"], (n, L)),
        "ambient": rng.uniform(*cfg["ambient_range"], (n, L)),
        "light_dir": light_dir / np.linalg.norm(light_dir, axis=2, keepdims=True),
    }


def _obs_task(task: tuple) -> tuple[int, dict[str, np.ndarray]]:
    from chpf.crops import render_crops

    obj, spec, margin, poses = task
    obj = _same_object(obj)
    wspec = window_spec(spec, margin)
    P = wspec.size
    n = len(poses["t"])
    L = poses["light"].shape[1]
    win_affine = np.empty((n, 2, 3))
    rgb = np.empty((n, L, P, P, 3), np.uint8)
    depth = np.empty((n, P, P), np.float16)
    mask = np.empty((n, P, P), bool)
    alpha = np.empty((n, P, P), np.uint8)
    ren = _renderer(P, P)
    for i in range(n):
        R, t, K = poses["R_ego"][i], poses["t"][i], poses["K"][i]
        win_affine[i] = crop_affines(t[None], K, wspec)[0]
        Kw = window_intrinsics(K, win_affine[i])
        for j in range(L):
            out = ren.render(
                [(obj, R, t)],
                Kw,
                light_intensity=float(poses["light"][i, j]),
                ambient=float(poses["ambient"][i, j]),
                light_direction=poses["light_dir"][i, j],
            )
            rgb[i, j] = out.rgb
            if j == 0:
                depth[i] = out.depth.astype(np.float16)
                mask[i] = out.masks[0]
                alpha[i] = out.alpha
    R_allo = egocentric_to_allocentric(poses["R_ego"], poses["t"])
    clean = render_crops(_renderer(spec.size, spec.size), obj, R_allo, spec)
    return n, {
        "win_affine": win_affine,
        "rgb": rgb,
        "depth": depth,
        "mask": mask,
        "alpha": alpha,
        "R_allo": R_allo,
        "clean_rgb": np.asarray(clean.rgb),
        "clean_mask": np.asarray(clean.mask),
    }


def obs_pool_path(obj, spec: CropSpec, cfg: dict, cache_dir: str | Path | None = None) -> Path:
    """Cache folder of the observation pool of (obj, spec, obs_pool settings ``cfg``)."""
    from chpf.objects import object_fingerprint

    parts = {"object": object_fingerprint(obj), "crop": spec.to_dict(), "settings": cfg}
    return _pool_path(cache_dir, "obs", obj.name, parts)


def obs_pool(
    obj,
    spec: CropSpec,
    cfg: dict,
    cache_dir: str | Path | None = None,
    *,
    workers: int = 1,
    progress: bool = True,
    mmap: bool = True,
    runner: TaskRunner | None = None,
) -> ObsPool:
    """The observation pool of ``obj`` (``cfg``: the obs_pool config section), cached."""

    n = int(cfg["num_entries"])
    meta = {
        "kind": "obs",
        "object": obj.name,
        "crop": spec.to_dict(),
        "settings": cfg,
        "window_size": window_size(spec, cfg["margin"]),
    }

    def build(r: TaskRunner) -> PoolBuild:
        poses = sample_obs_poses(obj.diameter, cfg, n, np.random.default_rng([cfg["seed"], 1001]))

        def render(ranges: list[tuple[int, int]]) -> Iterator[dict[str, np.ndarray]]:
            tasks = [
                (obj, spec, cfg["margin"], {k: v[a:b] for k, v in poses.items()}) for a, b in ranges
            ]
            desc = f"obs pool {obj.name}"
            return _iter_chunks(_obs_task, tasks, r, desc, progress, n, n - _remaining(ranges))

        fixed = {k: poses[k] for k in ("R_ego", "t", "K")}
        return PoolBuild(n, _chunks(n, 32), render, meta, fixed)

    path = obs_pool_path(obj, spec, cfg, cache_dir)
    with _task_runner(runner, workers) as r:
        arrays = load_or_build(path, list(ObsPool.FIELDS), mmap, lambda: build(r))
    return ObsPool(**{k: arrays[k] for k in ObsPool.FIELDS}, path=path)


def load_obs_pool(path: str | Path, mmap: bool = True) -> ObsPool:
    """The ObsPool of an existing observation pool folder (no object needed)."""
    arrays = _require_arrays(path, list(ObsPool.FIELDS), mmap, "observation pool")
    return ObsPool(**{k: arrays[k] for k in ObsPool.FIELDS}, path=Path(path))


# ----------------------------------------------------------------------------- occluder pool


@dataclass
class OccluderPool:
    """Other objects' crops for occluders/clutter: rgb (n,S,S,3) u8, mask (n,S,S) bool."""

    rgb: np.ndarray
    mask: np.ndarray

    def __len__(self) -> int:
        return int(self.rgb.shape[0])


def _empty_occluder_pool(size: int) -> OccluderPool:
    return OccluderPool(np.zeros((0, size, size, 3), np.uint8), np.zeros((0, size, size), bool))


def _occluder_parts(objects: list, size: int, cfg: dict) -> dict:
    """What the occluder pool of ``objects`` depends on (cache key and meta.json)."""
    from chpf.objects import object_fingerprint

    return {
        "objects": [object_fingerprint(o) for o in objects],
        "size": int(size),
        "n": int(cfg["num_entries"]),
        "seed": int(cfg["seed"]),
    }


def occluder_objects(names: list[str], exclude_fingerprint: str | None) -> list:
    """Built-in objects named in ``names`` except the one with ``exclude_fingerprint``."""
    from chpf.objects import builtin_object, object_fingerprint

    objs = [builtin_object(n) for n in names]
    return [o for o in objs if object_fingerprint(o) != exclude_fingerprint]


def occluder_pool(
    objects: list,
    size: int,
    cfg: dict,
    cache_dir: str | Path | None = None,
    *,
    workers: int = 1,
    progress: bool = True,
    mmap: bool = True,
    runner: TaskRunner | None = None,
) -> OccluderPool:
    """Crops (side ``size``) of ``objects`` at random orientations (``cfg``: occluder_pool
    section; entries split evenly over the objects), cached. Empty pool if no objects."""
    if not objects:
        return _empty_occluder_pool(size)

    n = int(cfg["num_entries"])
    meta = {"kind": "occluders", **_occluder_parts(objects, size, cfg)}
    meta["names"] = [o.name for o in objects]

    def build(r: TaskRunner) -> PoolBuild:
        rng = np.random.default_rng([cfg["seed"], 2002])
        counts = [n // len(objects) + (i < n % len(objects)) for i in range(len(objects))]
        rots = [random_rotations(c, rng) if c else np.zeros((0, 3, 3)) for c in counts]
        # chunks never span two objects: (object index, first entry of the object, a, b)
        spans, a0 = [], 0
        for i, c in enumerate(counts):
            spans += [(i, a0, a0 + a, a0 + b) for a, b in _chunks(c)]
            a0 += c
        of_chunk = {(a, b): (i, first) for i, first, a, b in spans}

        def render(ranges: list[tuple[int, int]]) -> Iterator[dict[str, np.ndarray]]:
            tasks = []
            for a, b in ranges:
                i, first = of_chunk[(a, b)]
                o = objects[i]
                spec = CropSpec.for_object(o.diameter, size)
                tasks.append((o, rots[i][a - first : b - first], spec))
            desc = f"occluder pool {'+'.join(o.name for o in objects)}"
            crops = _iter_chunks(_crops_task, tasks, r, desc, progress, n, n - _remaining(ranges))
            return ({"rgb": c["rgb"], "mask": c["mask"]} for c in crops)

        return PoolBuild(n, [(a, b) for _, _, a, b in spans], render, meta)

    path = occluder_pool_path(objects, size, cfg, cache_dir)
    with _task_runner(runner, workers) as r:
        arrays = load_or_build(path, ["rgb", "mask"], mmap, lambda: build(r))
    return OccluderPool(arrays["rgb"], arrays["mask"])


def occluder_pool_path(
    objects: list, size: int, cfg: dict, cache_dir: str | Path | None = None
) -> Path | None:
    """Cache folder of the occluder pool of ``objects`` (None if there are none)."""
    if not objects:
        return None
    parts = _occluder_parts(objects, size, cfg)
    return _pool_path(cache_dir, "occluders", "+".join(o.name for o in objects), parts)


def load_occluder_pool(path: str | Path | None, size: int, mmap: bool = True) -> OccluderPool:
    """The OccluderPool of an existing folder; an empty pool for None."""
    if path is None:
        return _empty_occluder_pool(size)
    arrays = _require_arrays(path, ["rgb", "mask"], mmap, "occluder pool")
    return OccluderPool(arrays["rgb"], arrays["mask"])
