"""Synthetic evaluation sequences in the BOP layout, plus a simulated detector's boxes.

Each scene: a target object (the first of ``--objects``) moving and rotating smoothly in front
of a textured wall, static distractors (the other objects), an occluder (a built-in object)
that passes between the camera and the target at the chosen level, and a smoothly wandering
camera that keeps looking at the scene. Occlusion levels: ``none``: no occluder; ``partial``:
the occluder crosses at 0.8 of the target's depth, its path offset (calibrated by rendering
masks) so that at least about half of the target stays visible; ``heavy``: it crosses at 0.6
of the depth, hiding about 90% of the target at the worst moment. The occluder is the built-in
box (the drill if the target is the box); it passes ``occluder_passes`` times, back and forth
along one line. Frames are rendered with ``chpf.render.Renderer`` (full frames), written with the
``chpf.bop`` writers: rgb, depth (with simulated sensor noise), mask, mask_visib, scene_camera
(with the camera's world pose), scene_gt (target first, then distractors, then the occluder),
scene_gt_info (achieved visible fractions); models/ holds models_info.json (with symmetries)
and obj_XXXXXX.ply in millimetres. ``DIR/detections_sim.json`` holds the boxes of a
``SimulatedDetector``; ``DIR/sequences_info.json`` records the settings and, per scene, the
target's visible-fraction statistics.

``sequences.family``: ``training`` (the walls, occluder and light described above, drawn as the
training data draws them) or ``heldout`` (walls, occluder shapes and lighting that the training
generator never draws, one occluder shape per scene: ``data_gen.heldout``), for benchmarks
that measure generalisation.

Scenes are independent (own random streams from (seed, scene id)), written one by one; a
rerun skips complete scenes (resume), and a folder made with other settings is refused unless
``overwrite``.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from chpf import bop
from chpf.atomic import atomic_write_bytes, atomic_write_text
from chpf.detections import SimulatedDetector
from chpf.errors import ConfigError, DatasetError
from chpf.geometry import axis_angle_to_matrix, random_rotations
from data_gen import augment, heldout

FPS = 30.0
FORMAT_VERSION = 1
# occluder depth as a fraction of the target's, and the target's visible fraction aimed at
# when the occluder is closest to the line of sight (first pass; achieved values are recorded)
OCCLUSION_LEVELS = {"partial": (0.8, 0.5), "heavy": (0.6, 0.1)}


@dataclass
class SceneObject:
    """An object instance of the scenes: model, BOP id and role."""

    obj: object  # chpf.objects.ObjectModel
    obj_id: int
    role: str  # target | distractor | occluder


# ----------------------------------------------------------------------------- scene objects


def resolve_objects(
    names: list[str], unit: str, cfg: dict, allow_size: bool = False
) -> list[SceneObject]:
    """Target (names[0]), distractors (names[1:]) and, if occlusion is on, an occluder.
    Meshes of implausible size are refused unless ``allow_size`` (``chpf.objects.check_size``)."""
    from chpf.objects import BUILTIN_OBJECTS, get_object

    objs = [get_object(n, unit=unit, allow_size=allow_size) for n in names]
    if len(objs) == 1:  # only the target: built-in distractors
        from chpf.objects import builtin_object

        others = [b for b in BUILTIN_OBJECTS if b != names[0] and b != objs[0].name]
        objs += [builtin_object(b) for b in others[: cfg["sequences"]["default_distractors"]]]
    used = {o.obj_id for o in objs if o.obj_id > 0}
    next_id = max([*BUILTIN_OBJECTS.values(), *used]) + 1
    scene: list[SceneObject] = []
    for i, o in enumerate(objs):
        oid = o.obj_id
        if oid <= 0:
            oid, next_id = next_id, next_id + 1
        scene.append(SceneObject(o, oid, "target" if i == 0 else "distractor"))
    if any(s.obj_id == scene[0].obj_id for s in scene[1:]):
        raise ConfigError(f"--objects: distractors must differ from the target {names[0]!r}")
    if cfg["sequences"]["occlusion"] != "none" and cfg["sequences"]["occluder_passes"] > 0:
        from chpf.objects import builtin_object

        if cfg["sequences"]["family"] == "heldout":  # one per scene: see scene_objects
            occ = heldout.occluder_objects()[0]
        else:
            name = "box" if scene[0].obj.name != "box" or scene[0].obj_id != 2 else "drill"
            occ = builtin_object(name)
        scene.append(SceneObject(occ, occ.obj_id, "occluder"))
    return scene


def scene_objects(
    scene_objs: list[SceneObject], cfg: dict, rng: np.random.Generator
) -> list[SceneObject]:
    """The objects of one scene: those of the root, with a held-out occluder drawn by ``rng``
    (family heldout)."""
    if cfg["sequences"]["family"] != "heldout" or scene_objs[-1].role != "occluder":
        return scene_objs
    occ = heldout.occluder_for_scene(rng)
    return [*scene_objs[:-1], SceneObject(occ, occ.obj_id, "occluder")]


def write_models(root: Path, scene_objs: list[SceneObject]) -> None:
    """models/models_info.json (with symmetries) and models/obj_XXXXXX.ply (mm)."""
    infos = {}
    done = set()
    if scene_objs[-1].obj.name.startswith("heldout_"):  # any of them may occlude a scene
        scene_objs = scene_objs[:-1] + [
            SceneObject(o, o.obj_id, "occluder") for o in heldout.occluder_objects()
        ]
    for s in scene_objs:
        if s.obj_id in done:
            continue
        done.add(s.obj_id)
        info = bop.model_info_from_object(s.obj)
        info.obj_id = s.obj_id
        infos[s.obj_id] = info
        mesh = s.obj.mesh.copy()
        if getattr(mesh.visual, "kind", None) == "texture":
            mesh.visual = mesh.visual.to_color()
        mesh.apply_scale(1000.0)
        data = mesh.export(file_type="ply", encoding="binary")
        atomic_write_bytes(bop.model_path(root, s.obj_id), data)
    bop.write_models_info(bop.models_dir(root) / bop.MODELS_INFO, dict(sorted(infos.items())))


# ----------------------------------------------------------------------------- trajectories


def _look_at(cam: np.ndarray, target: np.ndarray) -> np.ndarray:
    """R_w2c (3,3) of an OpenCV camera at ``cam`` looking at ``target`` (world y down)."""
    z = target - cam
    z = z / np.linalg.norm(z)
    x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def scene_trajectories(scene_objs: list[SceneObject], cfg: dict, rng: np.random.Generator) -> dict:
    """World poses per frame of every object, camera poses, the wall plane and lights.

    Returns dict with R_w (F,n,3,3), p_w (F,n,3), R_w2c (F,3,3), t_w2c (F,3), wall_z, light.
    """
    sc = cfg["sequences"]
    F, W, H, f = sc["frames"], sc["width"], sc["height"], sc["focal"]
    t = np.arange(F) / FPS
    n = len(scene_objs)
    target = scene_objs[0].obj
    z0 = float(rng.uniform(*sc["z_range"]))
    z0 = max(z0, 2.0 * target.diameter)
    c = np.array([0.0, 0.0, z0])
    half_w, half_h = z0 * (W / 2) / f, z0 * (H / 2) / f
    A = np.array([0.3 * half_w, 0.3 * half_h, 0.12 * z0])
    # target: two sinusoids per axis, typical speed ~ target_speed
    p_t = np.repeat(c[None], F, 0)
    for _ in range(2):
        omega = sc["target_speed"] / max(np.linalg.norm(A), 1e-6) * rng.uniform(0.6, 1.4, 3)
        phase = rng.uniform(0, 2 * np.pi, 3)
        p_t = p_t + 0.5 * A * (np.sin(omega * t[:, None] + phase) - np.sin(phase))
    # target rotation: integrate a smoothly turning angular velocity
    R_t = np.empty((F, 3, 3))
    R_t[0] = random_rotations(1, rng)[0]
    base = rng.standard_normal(3)
    base /= np.linalg.norm(base)
    wob_f, wob_p = rng.uniform(0.3, 1.2, 3), rng.uniform(0, 2 * np.pi, 3)
    speed = np.radians(sc["target_rot_speed_deg"])
    for k in range(1, F):
        u = base + 0.8 * np.sin(wob_f * t[k] + wob_p)
        u /= np.linalg.norm(u)
        R_t[k] = axis_angle_to_matrix(u * speed / FPS) @ R_t[k - 1]
    R_w = np.repeat(np.eye(3)[None, None], F, 0).repeat(n, 1)
    p_w = np.zeros((F, n, 3))
    R_w[:, 0], p_w[:, 0] = R_t, p_t
    # camera: smooth wandering, looking at a point following the target a little
    cam_f, cam_p = rng.uniform(0.4, 1.2, 3), rng.uniform(0, 2 * np.pi, 3)
    cam = sc["camera_motion"] * (np.sin(cam_f * t[:, None] + cam_p) - np.sin(cam_p))
    look = c + 0.3 * (p_t - c)
    R_w2c = np.stack([_look_at(cam[k], look[k]) for k in range(F)])
    t_w2c = -np.einsum("kij,kj->ki", R_w2c, cam)
    # distractors: static, around the target's motion envelope
    reach = np.linalg.norm(A[:2])
    m = sum(1 for s in scene_objs if s.role == "distractor")
    ang0 = rng.uniform(0, 2 * np.pi)
    di = 0
    for i, s in enumerate(scene_objs):
        if s.role != "distractor":
            continue
        a = ang0 + 2 * np.pi * di / max(m, 1) + rng.uniform(-0.3, 0.3)
        r_i = s.obj.diameter / 2
        r = reach + 0.5 * target.diameter + r_i + rng.uniform(0.02, 0.08)
        p = c + np.array([r * np.cos(a), r * np.sin(a), rng.uniform(-0.05, 0.15)])
        # keep it in the picture; if that brings it near the target's path, put it behind
        lim = 0.9 * np.array([half_w, half_h]) * p[2] / z0 - r_i
        clamped = np.clip(p[:2], -lim, lim)
        if np.any(clamped != p[:2]):
            p[:2] = clamped
            p[2] = z0 + A[2] + 0.5 * target.diameter + r_i + 0.05
            lim = 0.9 * np.array([half_w, half_h]) * p[2] / z0 - r_i
            p[:2] = np.clip(p[:2], -lim, lim)
        R_w[:, i] = random_rotations(1, rng)[0]
        p_w[:, i] = p
        di += 1
    # occluder passes (in camera-relative terms, converted to world); its closest approach
    # (offset ``miss`` off the line of sight) is calibrated in render_scene
    occ_info = None
    occ = [i for i, s in enumerate(scene_objs) if s.role == "occluder"]
    if occ:
        i = occ[0]
        lam, peak_visib = OCCLUSION_LEVELS[sc["occlusion"]]
        reach = lam * target.diameter / 2 + scene_objs[i].obj.diameter / 2
        passes = sc["occluder_passes"]
        R_o0 = random_rotations(1, rng)[0]
        spin = rng.standard_normal(3)
        spin *= np.radians(20.0) / np.linalg.norm(spin) / FPS
        centres = (np.arange(passes) + 1) * F / (passes + 1)
        half = max(2.0, min(F / (2 * passes), 45.0))  # frames from entering to the centre
        j = np.argmin(np.abs(centres[None] - np.arange(F)[:, None]), axis=1)
        # back and forth along one line: pass j ends where pass j+1 starts (no jumps)
        s_lin = (-1.0) ** j * np.clip((np.arange(F) - centres[j]) / half, -1.0, 1.0)
        a = rng.uniform(0, 2 * np.pi)
        for k in range(F):
            R_w[k, i] = axis_angle_to_matrix(spin * k) @ R_o0
        occ_info = {
            "index": i,
            "lam": lam,
            "peak_visib": peak_visib,
            "reach": reach,
            "s_lin": s_lin,
            "e_dir": np.array([np.cos(a), np.sin(a), 0.0]),
            "e_perp": np.array([-np.sin(a), np.cos(a), 0.0]),
            "peak_frame": int(np.clip(round(centres[0]), 0, F - 1)),
            "half": half,
        }
        traj_tmp = {"p_w": p_w, "R_w2c": R_w2c, "t_w2c": t_w2c, "occluder": occ_info}
        set_occluder_offset(traj_tmp, reach)  # placeholder path until calibrated
    # wall behind everything
    zmax = max(float(p_w[:, :, 2].max()), z0) + max(s.obj.diameter for s in scene_objs)
    wall_z = zmax + float(rng.uniform(0.2, 0.6))
    light_dir = np.array([rng.normal(0, 0.5), rng.normal(0, 0.5), 1.0])
    return {
        "R_w": R_w,
        "p_w": p_w,
        "R_w2c": R_w2c,
        "t_w2c": t_w2c,
        "occluder": occ_info,
        "wall_z": wall_z,
        "light_intensity": sc["light_intensity"] * float(rng.uniform(0.7, 1.3)),
        "light_dir": light_dir / np.linalg.norm(light_dir),
        "wall_gain": float(rng.uniform(0.6, 1.0)),
    }


def set_occluder_offset(traj: dict, miss: float) -> None:
    """Set the occluder's world path for a closest approach ``miss`` (metres, at its depth)."""
    occ = traj["occluder"]
    i, p_w = occ["index"], traj["p_w"]
    R_w2c, t_w2c = traj["R_w2c"], traj["t_w2c"]
    tc = np.einsum("kij,kj->ki", R_w2c, p_w[:, 0]) + t_w2c  # target in the camera frame
    oc = occ["lam"] * tc + occ["s_lin"][:, None] * (1.3 * occ["reach"]) * occ["e_dir"]
    oc = oc + miss * occ["e_perp"]
    p_w[:, i] = np.einsum("kji,kj->ki", R_w2c, oc - t_w2c)


def calibrate_occluder(traj: dict, scene_objs: list[SceneObject], K: np.ndarray, renderer) -> float:
    """Choose the occluder's closest approach so that the target's smallest visible fraction
    during the first pass is about the level's ``peak_visib`` (bisection on mask-only renders
    of a few frames around the pass's centre); sets the path and returns the offset (metres)."""
    occ = traj["occluder"]
    i = occ["index"]
    F = len(traj["R_w2c"])
    frames = np.unique(
        np.clip(
            np.round(occ["peak_frame"] + np.linspace(-0.5, 0.5, 7) * occ["half"]), 0, F - 1
        ).astype(int)
    )

    def visib(miss: float) -> float:
        set_occluder_offset(traj, miss)
        worst = 1.0
        for k in frames:
            R_w2c, t_w2c = traj["R_w2c"][k], traj["t_w2c"][k]
            objs = [
                (scene_objs[g].obj, R_w2c @ traj["R_w"][k, g], R_w2c @ traj["p_w"][k, g] + t_w2c)
                for g in (0, i)
            ]
            out = renderer.render(objs, K, rgb=False)
            n_all = out.masks[0].sum()
            if n_all:
                worst = min(worst, float(out.visible_masks[0].sum() / n_all))
        return worst

    target = occ["peak_visib"]
    lo, hi = 0.0, 1.2 * occ["reach"]
    if visib(lo) >= target:
        miss = lo
    else:
        for _ in range(7):
            mid = 0.5 * (lo + hi)
            if visib(mid) < target:
                lo = mid
            else:
                hi = mid
        miss = hi
    set_occluder_offset(traj, miss)
    return miss


class Wall:
    """A textured plane z = wall_z (world) behind the scene: colour by homography, exact depth."""

    def __init__(
        self, texture: np.ndarray, wall_z: float, K: np.ndarray, W: int, H: int, gain: float
    ) -> None:
        self.tex = np.clip(texture.astype(np.float32) * gain, 0, 255).astype(np.uint8)
        self.z = wall_z
        self.K = K
        self.W, self.H = W, H
        half_w = wall_z * (W / 2) / K[0, 0] * 2.0
        self.side = 2 * max(half_w, wall_z * (H / 2) / K[1, 1] * 2.0)
        self.texel = self.side / texture.shape[0]
        self.origin = np.array([-self.side / 2, -self.side / 2, wall_z])
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        self.rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T  # (H,W,3), z=1

    def render(self, R_w2c: np.ndarray, t_w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rgb (H,W,3) u8, depth (H,W) f32 m) of the wall seen by camera (R_w2c, t_w2c)."""
        o_c = R_w2c @ self.origin + t_w2c
        Hm = self.K @ np.stack([R_w2c[:, 0] * self.texel, R_w2c[:, 1] * self.texel, o_c], 1)
        rgb = cv2.warpPerspective(
            self.tex, Hm, (self.W, self.H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )
        n_c = R_w2c[:, 2]
        depth = (n_c @ o_c) / (self.rays @ n_c)
        return rgb, depth.astype(np.float32)


# ----------------------------------------------------------------------------- writing


def _info_dict(
    names: list[str], scene_objs: list[SceneObject], cfg: dict, seed: int, split: str
) -> dict:
    from chpf.objects import object_fingerprint

    return {
        "kind": "sequences",
        "format_version": FORMAT_VERSION,
        "seed": int(seed),
        "split": split,
        "objects": [
            {
                "name": s.obj.name,
                "obj_id": s.obj_id,
                "role": s.role,
                "fingerprint": object_fingerprint(s.obj),
            }
            for s in scene_objs
        ],
        "config": {k: cfg[k] for k in ("sequences", "detector", "depth")},
    }


def _prepare(root: Path, info: dict, overwrite: bool) -> None:
    path = root / bop.SEQUENCES_INFO
    if path.is_file():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            old = {}
        old_cmp = {k: v for k, v in old.items() if k != "scenes"}
        if old_cmp != info:
            if not overwrite:
                raise DatasetError(
                    f"{root}: holds sequences made with other settings; use --overwrite to "
                    "replace them"
                )
            split = old.get("split", info["split"])
            for s in old.get("scenes", []):
                shutil.rmtree(bop.scene_dir(root, split, int(s["scene_id"])), ignore_errors=True)
            for p in (root / split).glob("[0-9]" * 6) if (root / split).is_dir() else []:
                shutil.rmtree(p, ignore_errors=True)
            (root / bop.DETECTIONS_SIM).unlink(missing_ok=True)
            for p in bop.models_dir(root).glob("obj_*.ply"):
                p.unlink()
    elif root.exists() and any(root.iterdir()) and not overwrite:
        raise DatasetError(
            f"{root}: folder is not empty and has no {bop.SEQUENCES_INFO}; use --overwrite"
        )


def render_scene(
    root: Path,
    split: str,
    scene_id: int,
    scene_objs: list[SceneObject],
    cfg: dict,
    seed: int,
    renderer,
    bar=None,
) -> tuple[list[dict], dict]:
    """Render and write one scene; returns (detections, summary)."""
    sc = cfg["sequences"]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 3, int(scene_id)]))
    det_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 4, int(scene_id)]))
    noise_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 5, int(scene_id)]))
    family_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 6, int(scene_id)]))
    scene_objs = scene_objects(scene_objs, cfg, family_rng)
    detector = SimulatedDetector(cfg["detector"], det_rng)
    W, H, f = sc["width"], sc["height"], sc["focal"]
    K = np.array([[f, 0.0, (W - 1) / 2.0], [0.0, f, (H - 1) / 2.0], [0.0, 0.0, 1.0]])
    traj = scene_trajectories(scene_objs, cfg, rng)
    if traj["occluder"] is not None:
        calibrate_occluder(traj, scene_objs, K, renderer)
    light = None
    if sc["family"] == "heldout":
        tex = heldout.wall_texture(family_rng, 1024)
        light = heldout.lighting(family_rng)
    else:
        tex = augment.procedural_textures(1, 1024, rng)[0]
    wall = Wall(tex, traj["wall_z"], K, W, H, traj["wall_gain"])
    sdir = bop.scene_dir(root, split, scene_id)
    ext = "." + sc["rgb_ext"]
    cameras, gts, infos, dets, visib = {}, {}, {}, [], []
    for k in range(sc["frames"]):
        im = k + 1
        R_w2c, t_w2c = traj["R_w2c"][k], traj["t_w2c"][k]
        poses = []
        for i, s in enumerate(scene_objs):
            R = R_w2c @ traj["R_w"][k, i]
            t = R_w2c @ traj["p_w"][k, i] + t_w2c
            poses.append(bop.GtPose(obj_id=s.obj_id, R=R, t=t))
        out = renderer.render(
            [(s.obj, p.R, p.t) for s, p in zip(scene_objs, poses, strict=True)],
            K,
            light_intensity=traj["light_intensity"] if light is None else light.intensity,
            ambient=sc["ambient"] if light is None else light.ambient,
            light_direction=traj["light_dir"] if light is None else light.direction,
        )
        wall_rgb, wall_depth = wall.render(R_w2c, t_w2c)
        inv = (255 - out.alpha).astype(np.uint16)[..., None]
        rgb = np.minimum(out.rgb + (wall_rgb * inv + 127) // 255, 255).astype(np.uint8)
        if light is not None:
            rgb = light.apply_tint(rgb)
        depth = np.where(out.depth > 0, out.depth, wall_depth).astype(np.float32)
        if sc["depth_noise"]:
            depth = augment.depth_noise(depth, noise_rng, cfg["depth"])
        bop.write_rgb(bop.rgb_path(sdir, im, ext), rgb)
        bop.write_depth(bop.depth_path(sdir, im), depth, sc["depth_scale"])
        frame_info = []
        for g in range(len(scene_objs)):
            bop.write_mask(bop.mask_visib_path(sdir, im, g, "mask"), out.masks[g])
            bop.write_mask(bop.mask_visib_path(sdir, im, g), out.visible_masks[g])
            frame_info.append(bop.gt_info_from_masks(out.masks[g], out.visible_masks[g], depth))
        for g, s in enumerate(scene_objs):
            d = detector.detect(scene_id, im, s.obj_id, frame_info[g], W, H)
            if d is not None:
                dets.append(d)
        cameras[im] = bop.CameraInfo(
            K=K, depth_scale=sc["depth_scale"], R_w2c=R_w2c, t_w2c=t_w2c, width=W, height=H
        )
        gts[im] = poses
        infos[im] = frame_info
        visib.append(frame_info[0].visib_fract)
        if bar is not None:
            bar.update(1)
    bop.write_scene_camera(sdir / bop.SCENE_CAMERA, cameras)
    bop.write_scene_gt(sdir / bop.SCENE_GT, gts)
    bop.write_scene_gt_info(sdir / bop.SCENE_GT_INFO, infos)
    v = np.asarray(visib)
    summary = {
        "scene_id": int(scene_id),
        "frames": int(sc["frames"]),
        "target_obj_id": int(scene_objs[0].obj_id),
        "target_visib_fract": {
            "min": round(float(v.min()), 4),
            "mean": round(float(v.mean()), 4),
            "frames_below_0.5": int((v < 0.5).sum()),
        },
        "detections": len(dets),
    }
    # the per-scene detections file is written last: it marks the scene complete
    bop.write_detections(sdir / bop.DETECTIONS_SIM, dets)
    return dets, summary


def generate_sequences(
    names: list[str],
    out: str | Path,
    cfg: dict,
    seed: int,
    split: str = "test",
    unit: str = "m",
    overwrite: bool = False,
    progress: bool = True,
    allow_size: bool = False,
) -> dict:
    """Write ``cfg['sequences']['num_scenes']`` scenes to the BOP root ``out``; returns the
    sequences_info dict (also written to ``out/sequences_info.json``). ``allow_size``: accept
    meshes outside 1 cm - 2 m."""
    from chpf.render import Renderer

    root = Path(out)
    if root.exists() and not root.is_dir():
        raise DatasetError(f"{root}: exists and is not a folder")
    sc = cfg["sequences"]
    scene_objs = resolve_objects(names, unit, cfg, allow_size)
    info = _info_dict(names, scene_objs, cfg, seed, split)
    _prepare(root, info, overwrite)
    root.mkdir(parents=True, exist_ok=True)
    write_models(root, scene_objs)
    atomic_write_text(root / bop.SEQUENCES_INFO, json.dumps(info, indent=1) + "\n")
    scene_ids = list(range(1, sc["num_scenes"] + 1))
    todo = [
        s for s in scene_ids if not (bop.scene_dir(root, split, s) / bop.DETECTIONS_SIM).is_file()
    ]
    bar = tqdm(
        total=len(todo) * sc["frames"], desc="sequences", unit="frame", disable=not progress or None
    )
    renderer = Renderer(sc["width"], sc["height"]) if todo else None
    try:
        for s in todo:
            shutil.rmtree(bop.scene_dir(root, split, s), ignore_errors=True)  # partial leftovers
            render_scene(root, split, s, scene_objs, cfg, seed, renderer, bar)
    finally:
        bar.close()
        if renderer is not None:
            renderer.close()
    # merge detections and summaries (cheap: read back per scene)
    all_dets, summaries = [], []
    for s in scene_ids:
        sdir = bop.scene_dir(root, split, s)
        dets = json.loads((sdir / bop.DETECTIONS_SIM).read_text(encoding="utf-8"))
        all_dets += dets
        gt_info = bop.read_scene_gt_info(sdir / bop.SCENE_GT_INFO)
        v = np.array([gt_info[i][0].visib_fract for i in sorted(gt_info)])
        summaries.append(
            {
                "scene_id": s,
                "frames": len(v),
                "target_obj_id": scene_objs[0].obj_id,
                "target_visib_fract": {
                    "min": round(float(v.min()), 4),
                    "mean": round(float(v.mean()), 4),
                    "frames_below_0.5": int((v < 0.5).sum()),
                },
                "detections_of_target": sum(
                    1 for d in dets if d["category_id"] == scene_objs[0].obj_id
                ),
            }
        )
    bop.write_detections(root / bop.DETECTIONS_SIM, all_dets)
    info["scenes"] = summaries
    atomic_write_text(root / bop.SEQUENCES_INFO, json.dumps(info, indent=1) + "\n")
    return info
