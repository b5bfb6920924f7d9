"""Bench suites: what to build and run, as a typed config (chpf.config_schema).

A suite is a YAML file of the sections below; ``default``, ``dev``, ``dev2``, ``dev3`` and
``quick`` ship in ``bench/suites/``. Unknown keys, wrong types and out-of-range values are
refused in one line naming the file and the key. The resolved suite (after command-line
overrides) is recorded in the output folder as ``suite.json``: a rerun, a shard and a merge
must agree with it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from chpf.config_schema import Section, load, setting, to_dict
from chpf.errors import ConfigError
from chpf.hashing import sha256_bytes
from chpf.tracking.methods import method_names

SUITES_DIR = Path(__file__).resolve().parent / "suites"
OCCLUSION_LEVELS = ("none", "partial", "heavy")
Occlusion = Literal["none", "partial", "heavy"]
Modality = Literal["rgb", "rgbd"]


@dataclass
class SequenceSuite(Section):
    """The test sequences (data_gen.sequences, family held out by default).

    occlusion: levels; scenes_per_level: scenes per level and object; frames: per scene (30
    fps); width, height, focal: the camera (pixels); target_rot_speed_deg: typical rotation
    speed (deg/s; 90 = 3 deg/frame); target_speed: m/s; distractors: static built-ins;
    family: heldout | training (data_gen.heldout); seed: of the scenes.
    """

    occlusion: list[Occlusion] = field(default_factory=lambda: list(OCCLUSION_LEVELS))
    scenes_per_level: int = setting(4, ge=1, le=1000)
    frames: int = setting(60, ge=2, le=100000)
    width: int = setting(320, ge=32, le=8192)
    height: int = setting(240, ge=32, le=8192)
    focal: float = setting(300.0, ge=10.0, le=20000.0)
    target_rot_speed_deg: float = setting(90.0, ge=0.0, le=720.0)
    target_speed: float = setting(0.08, ge=0.0, le=10.0)
    distractors: int = setting(1, ge=0, le=3)
    family: Literal["training", "heldout"] = "heldout"
    seed: int = setting(1000, ge=0, le=2**31 - 1)


@dataclass
class TrackingSuite(Section):
    """n_particles: of every method (the same N for all); config: a tracking YAML shared by all
    methods (same likelihood, same phi_cand; None: the defaults)."""

    n_particles: int = setting(50, ge=1, le=100000)
    config: str | None = None


@dataclass
class ReportSuite(Section):
    """bootstrap: resamples of the 95 % confidence intervals; overlay_frames: frames shown
    with every method's outline; curve_sequences: sequences whose error and alpha over time
    are plotted (the most occluded first)."""

    bootstrap: int = setting(1000, ge=10, le=100000)
    overlay_frames: int = setting(3, ge=0, le=20)
    curve_sequences: int = setting(2, ge=0, le=50)


@dataclass
class Suite(Section):
    """A bench suite. bundles: bundle folders, "shipped" = every bundle shipped with chpf, or
    a shipped bundle's name (box, mug);
    meshes: mesh files (metres unless mesh_unit) of bundle objects that are not built in,
    matched by fingerprint; methods: registered methods, "paper" = the paper's
    (chpf.tracking.methods); modalities; seeds (filter seeds per sequence)."""

    name: str = "custom"
    bundles: list[str] = field(default_factory=lambda: ["shipped"])
    meshes: list[str] = field(default_factory=list)
    mesh_unit: Literal["m", "mm"] = "m"
    methods: list[str] = field(default_factory=lambda: ["paper"])
    modalities: list[Modality] = field(default_factory=lambda: ["rgb", "rgbd"])
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    sequences: SequenceSuite = field(default_factory=SequenceSuite)
    tracking: TrackingSuite = field(default_factory=TrackingSuite)
    report: ReportSuite = field(default_factory=ReportSuite)


def suite_path(name_or_file: str) -> Path:
    """A shipped suite's YAML by name, or the given file."""
    shipped = SUITES_DIR / f"{name_or_file}.yaml"
    if shipped.is_file() and "/" not in name_or_file:
        return shipped
    p = Path(name_or_file)
    if not p.is_file():
        names = ", ".join(sorted(q.stem for q in SUITES_DIR.glob("*.yaml")))
        raise ConfigError(f"{name_or_file}: no such suite file (shipped suites: {names})")
    return p


def resolve_methods(names: list[str]) -> list[str]:
    """'paper' -> the paper's registered methods; every other name must be registered."""
    out: list[str] = []
    for n in names:
        if n == "paper":
            out += method_names(paper_only=True)
        elif n in method_names():
            out.append(n)
        else:
            raise ConfigError(
                f"methods: unknown {n!r} (registered: {', '.join(method_names())}, or paper)"
            )
    return list(dict.fromkeys(out))


def load_suite(name_or_file: str, overrides: dict[str, Any] | None = None) -> Suite:
    """The suite of a shipped name or a YAML file, updated by ``overrides`` (command-line
    options as a dict of keys); ConfigError in one line."""
    suite = load(Suite, path=suite_path(name_or_file), data=overrides or {}, where="options")
    suite.methods = resolve_methods(suite.methods)
    for key in ("bundles", "methods", "modalities", "seeds"):
        if not getattr(suite, key):
            raise ConfigError(f"{name_or_file}: {key} is empty")
    if not suite.sequences.occlusion:
        raise ConfigError(f"{name_or_file}: sequences.occlusion is empty")
    return suite


def suite_record(suite: Suite) -> dict[str, Any]:
    """What a folder's results were made with (JSON-ready), and its identity ``suite_hash``."""
    data = to_dict(suite)
    return {**data, "suite_hash": sha256_bytes(json.dumps(data, sort_keys=True).encode())[:16]}
