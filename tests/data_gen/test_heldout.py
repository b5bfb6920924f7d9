"""The held-out scene family: walls, occluders and lighting outside what training draws."""

from __future__ import annotations

import numpy as np

from chpf.bop import BopDataset
from chpf.objects import BUILTIN_OBJECTS
from data_gen import cli, heldout
from data_gen.config import default_config


def test_heldout_scenes_use_their_occluders_walls_and_light(tmp_path):
    out = tmp_path / "bop"
    args = ["--objects", "box", "--out", str(out), "--occlusion", "heavy", "--seed", "1"]
    args += ["--num-scenes", "3", "--frames", "4", "--width", "160", "--height", "120"]
    args += ["--set", "sequences.focal=150", "--set", "sequences.family=heldout"]
    assert cli.main(["sequences", *args, "--no-progress"]) == 0
    ds = BopDataset(out)
    occluders = set(range(heldout.FIRST_OCCLUDER_ID, heldout.FIRST_OCCLUDER_ID + 4))
    assert occluders <= set(ds.models_info())  # every shape a scene may use has a model
    used = set()
    for sid in ds.scene_ids("test"):
        ids = {p.obj_id for p in ds.scene("test", sid).gt[1]}
        assert 2 in ids and not ids & {4}  # the box, and no built-in drill occluder
        used |= ids & occluders
        assert len(ids & occluders) == 1  # one held-out occluder per scene
    assert used  # drawn per scene
    for o in heldout.occluder_objects():
        assert o.obj_id not in BUILTIN_OBJECTS.values()
        assert 0.25 < o.diameter < 0.5  # about the size of the box (0.32 m) it passes


def test_heldout_lighting_is_outside_the_training_ranges():
    obs = default_config()["obs_pool"]
    lo, hi = obs["light_intensity_range"]
    amb_lo, _ = obs["ambient_range"]
    rng = np.random.default_rng(0)
    for _ in range(200):
        light = heldout.lighting(rng)
        assert not lo <= light.intensity <= hi
        assert light.ambient < amb_lo
        assert np.isclose(np.linalg.norm(light.direction), 1.0)
        assert light.tint.min() < 0.85  # a cast beyond training's +-10 % channel gains
    assert default_config()["color"]["channel_gain"] <= 0.1


def test_wall_textures_are_seeded_and_of_every_kind():
    a = heldout.wall_texture(np.random.default_rng(5), 128)
    b = heldout.wall_texture(np.random.default_rng(5), 128)
    assert a.shape == (128, 128, 3) and a.dtype == np.uint8 and np.array_equal(a, b)
    rng = np.random.default_rng(0)
    kinds = {heldout.WALL_KINDS[int(np.random.default_rng(s).integers(0, 4))] for s in range(200)}
    assert kinds == set(heldout.WALL_KINDS)
    assert heldout.wall_texture(rng, 64).std() > 5  # not a flat colour
