"""The suite's test sequences: built once per content, reused from a cache.

Per bundle object and occlusion level one BOP root (``chpf-gen-data sequences``: the target,
distractors, an occluder, the simulated detector's boxes in ``detections_sim.json``) of
``scenes_per_level`` scenes. A root's folder name holds the sha256 of everything it is made of
(the object's fingerprint, the generator settings, the seed and the generator's format version),
so a changed setting builds a new root and an unchanged one is reused as it is.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from bench.suite import Suite
from chpf.bundle import Bundle
from chpf.errors import BundleError
from chpf.hashing import sha256_bytes
from chpf.objects import BUILTIN_OBJECTS, get_object, object_fingerprint
from chpf.outdir import lock_output_path
from chpf.tracking.demo import bundles_dir, shipped_bundles

SEQUENCES_FILE = "sequences.json"
"""The output folder's list of sequences (what the jobs and the report read)."""


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/chpf/bench`` (``~/.cache/chpf/bench``)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "chpf" / "bench"


@dataclass(frozen=True)
class BundleRef:
    """A bundle of the suite: its folder and its object (name, BOP id, the source to render:
    a built-in name or a mesh file)."""

    path: str
    name: str
    obj_id: int
    source: str


@dataclass(frozen=True)
class Sequence:
    """One scene of one root: the unit over which confidence intervals resample."""

    bundle: str  # BundleRef.path
    obj: str
    obj_id: int
    level: str
    root: str
    scene_id: int

    @property
    def key(self) -> str:
        return f"{self.obj}-{self.level}-{self.scene_id:02d}"


def resolve_bundles(suite: Suite) -> list[BundleRef]:
    """The suite's bundles, each loaded once (BundleError in one line if one fails) and matched
    with the object to render (a built-in with the bundle's fingerprint or one of ``meshes``)."""
    paths: list[Path] = []
    shipped = shipped_bundles()
    for b in suite.bundles:
        if b == "shipped":
            paths += list(shipped.values())
        elif b in shipped and not Path(b).exists():  # a shipped bundle by name: box, mug
            paths.append(shipped[b])
        else:
            paths.append(Path(b))
    refs = []
    meshes = {}
    for m in suite.meshes:
        obj = get_object(m, unit=suite.mesh_unit)
        meshes[object_fingerprint(obj)] = m
    if not paths:
        raise BundleError(f"{bundles_dir()}: no shipped bundle; pass --bundles BUNDLE_DIR")
    for p in dict.fromkeys(paths):
        info = Bundle.load(p, threads=1).obj_info
        source = None
        if info.name in BUILTIN_OBJECTS:
            if object_fingerprint(get_object(info.name)) == info.fingerprint:
                source = info.name
        source = meshes.get(info.fingerprint, source)
        if source is None:
            raise BundleError(
                f"{p}: its object {info.name!r} is not built in; list its mesh under the "
                "suite's meshes (matched by fingerprint)"
            )
        refs.append(BundleRef(str(p), info.name, int(info.obj_id), source))
    return refs


def generator_config(suite: Suite, level: str) -> dict[str, Any]:
    """chpf-gen-data's config of one level's root."""
    from data_gen.config import default_config

    cfg = default_config()
    s = suite.sequences
    cfg["sequences"].update(
        num_scenes=s.scenes_per_level,
        frames=s.frames,
        occlusion=level,
        width=s.width,
        height=s.height,
        focal=s.focal,
        target_rot_speed_deg=s.target_rot_speed_deg,
        target_speed=s.target_speed,
        default_distractors=s.distractors,
        family=s.family,
    )
    return cfg


def root_dir(cache: Path, ref: BundleRef, suite: Suite, level: str, unit: str) -> Path:
    """The cache folder of one root, named by the hash of its content."""
    from data_gen.sequences import FORMAT_VERSION

    cfg = generator_config(suite, level)
    fingerprint = object_fingerprint(get_object(ref.source, unit=unit))
    content = {
        "format_version": FORMAT_VERSION,
        "object": fingerprint,
        "obj_id": ref.obj_id,
        "config": {k: cfg[k] for k in ("sequences", "detector", "depth")},
        "seed": suite.sequences.seed,
    }
    digest = sha256_bytes(json.dumps(content, sort_keys=True).encode())[:16]
    return cache / f"{ref.name}-{level}-{digest}"


def _build(task: tuple[str, Path, dict, int, str]) -> str:
    """Build (or complete) one root; returns its path."""
    from data_gen.sequences import generate_sequences

    source, root, cfg, seed, unit = task
    with lock_output_path(root, "chpf-bench sequences"):
        generate_sequences([source], root, cfg, seed, unit=unit, progress=False)
    return str(root)


def _complete(root: Path) -> bool:
    from chpf.bop import SEQUENCES_INFO

    path = root / SEQUENCES_INFO
    return path.is_file() and "scenes" in json.loads(path.read_text(encoding="utf-8"))


def build_sequences(
    suite: Suite, refs: list[BundleRef], cache: Path, workers: int = 1, log=print
) -> list[Sequence]:
    """Every sequence of the suite, building the roots that are not cached yet (in
    ``workers`` processes); ``log`` gets one line per root."""
    unit = suite.mesh_unit
    tasks, seqs = [], []
    for ref in refs:
        for level in suite.sequences.occlusion:
            root = root_dir(cache, ref, suite, level, unit)
            if not _complete(root):
                cfg = generator_config(suite, level)
                tasks.append((ref.source, root, cfg, suite.sequences.seed, unit))
            seqs += [
                Sequence(ref.path, ref.name, ref.obj_id, level, str(root), s)
                for s in range(1, suite.sequences.scenes_per_level + 1)
            ]
    if tasks:
        n = suite.sequences.scenes_per_level * suite.sequences.frames
        log(f"building {len(tasks)} sequence root(s) of {n} frames in {cache}")
        if workers > 1 and len(tasks) > 1:
            ctx = get_context("spawn")
            with ProcessPoolExecutor(min(workers, len(tasks)), mp_context=ctx) as pool:
                list(pool.map(_build, tasks))
        else:
            for t in tasks:
                _build(t)
    return seqs


def sequences_to_json(seqs: list[Sequence]) -> list[dict[str, Any]]:
    return [asdict(s) for s in seqs]


def sequences_from_json(data: list[dict[str, Any]]) -> list[Sequence]:
    return [Sequence(**d) for d in data]
