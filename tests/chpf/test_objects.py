"""Tests of chpf.objects: loading, model points, diameter, built-in objects, fingerprints."""

from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from chpf.errors import MeshError
from chpf.objects import (
    BUILTIN_OBJECTS,
    ObjectModel,
    bop_obj_id,
    builtin_object,
    get_object,
    load_mesh,
    make_object,
    mesh_diameter,
    object_fingerprint,
)

EXTENTS = (0.1, 0.2, 0.3)
BOX_DIAMETER = float(np.sqrt(0.1**2 + 0.2**2 + 0.3**2))


def box_mesh(scale: float = 1.0) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=np.array(EXTENTS) * scale)
    colours = np.zeros((len(mesh.vertices), 4), np.uint8)
    colours[:, 0] = np.arange(len(mesh.vertices)) * 30
    colours[:, 3] = 255
    mesh.visual.vertex_colors = colours
    return mesh


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
@pytest.mark.parametrize("unit", ["m", "mm"])
def test_load_mesh_formats_and_units(tmp_path, suffix, unit):
    scale = 1000.0 if unit == "mm" else 1.0
    path = tmp_path / f"model{suffix}"
    box_mesh(scale).export(path)
    obj = load_mesh(path, unit=unit, obj_id=7)
    assert isinstance(obj, ObjectModel)
    assert obj.name == "model" and obj.obj_id == 7
    assert len(obj.mesh.faces) == 12
    np.testing.assert_allclose(obj.mesh.extents, EXTENTS, atol=1e-6)
    assert obj.diameter == pytest.approx(BOX_DIAMETER, abs=1e-6)
    assert obj.points.shape == (2000, 3)
    assert np.all(np.abs(obj.points) <= np.array(EXTENTS) / 2 + 1e-6)  # float32 files
    if suffix == ".ply":  # vertex colours survive
        assert len(np.unique(obj.mesh.visual.vertex_colors[:, 0])) > 1


def test_a_mesh_named_as_bop_names_models_takes_its_obj_id_from_the_name(tmp_path):
    assert bop_obj_id("models/obj_000005.ply") == 5
    assert bop_obj_id("obj_000012_textured.obj") == 12
    assert bop_obj_id("duck.ply") is None and bop_obj_id("my_obj_000005.ply") is None
    path = tmp_path / "obj_000005.ply"
    box_mesh().export(path)
    assert load_mesh(path).obj_id == 5 and get_object(str(path)).obj_id == 5
    assert load_mesh(path, obj_id=3).obj_id == 3
    other = tmp_path / "duck.ply"
    box_mesh().export(other)
    assert load_mesh(other).obj_id == 0


def test_load_scene_is_concatenated(tmp_path):
    a = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    b = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    b.apply_translation((0.3, 0.0, 0.0))
    path = tmp_path / "two.obj"
    trimesh.Scene([a, b]).export(path)
    obj = load_mesh(path)
    assert len(obj.mesh.faces) == 24
    np.testing.assert_allclose(
        obj.mesh.bounds, [[-0.05, -0.05, -0.05], [0.35, 0.05, 0.05]], atol=1e-6
    )


def test_load_mesh_errors(tmp_path):
    with pytest.raises(MeshError, match=r"missing\.ply.*not found"):
        load_mesh(tmp_path / "missing.ply")
    noise = np.random.default_rng(0).integers(0, 256, 500, dtype=np.uint8).tobytes()
    for suffix in (".ply", ".stl"):
        garbage = tmp_path / f"garbage{suffix}"
        garbage.write_bytes(noise)
        with pytest.raises(MeshError, match=re.escape(f"garbage{suffix}")) as err:
            load_mesh(garbage)
        assert "\n" not in str(err.value)
    bad_obj = tmp_path / "bad.obj"
    bad_obj.write_text("this is not\na mesh at all\n")
    with pytest.raises(MeshError, match=r"bad\.obj"):
        load_mesh(bad_obj)
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(np.random.default_rng(0).random((20, 3))).export(cloud)
    with pytest.raises(MeshError, match=r"cloud\.ply.*no faces"):
        load_mesh(cloud)
    with pytest.raises(MeshError, match="unsupported"):
        (tmp_path / "model.xyz").write_text("1 2 3\n")
        load_mesh(tmp_path / "model.xyz")


def test_diameter_and_points():
    assert mesh_diameter(box_mesh().vertices) == pytest.approx(BOX_DIAMETER)
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [1, 2, 0]], float)  # no 3D hull
    assert mesh_diameter(flat) == pytest.approx(np.sqrt(5))
    a = make_object(box_mesh(), "a")
    b = make_object(box_mesh(), "b", num_points=500)
    np.testing.assert_array_equal(a.points[:500].shape, b.points.shape)
    np.testing.assert_array_equal(make_object(box_mesh(), "c").points, a.points)  # seeded
    # points lie on the surface of the box
    half = np.array(EXTENTS) / 2
    on_face = np.isclose(np.abs(a.points), half, atol=1e-9).any(axis=1)
    assert on_face.all()


@pytest.mark.parametrize("name", list(BUILTIN_OBJECTS))
def test_builtin_objects(name):
    obj = builtin_object(name)
    assert obj.name == name and obj.obj_id == BUILTIN_OBJECTS[name]
    assert 100 < len(obj.mesh.faces) < 5000
    lo, hi = obj.mesh.bounds
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-9)  # origin at the bbox centre
    assert 0.05 < obj.diameter < 0.4
    colours = obj.mesh.visual.vertex_colors[:, :3]
    assert len(np.unique(colours, axis=0)) >= 5  # printed patterns, not a flat colour
    assert obj.symmetries_discrete == []
    again = builtin_object(name)
    assert object_fingerprint(again) == object_fingerprint(obj)  # deterministic
    assert again.mesh is not obj.mesh
    np.testing.assert_array_equal(again.points, obj.points)


def test_builtin_sizes_and_symmetries():
    box = builtin_object("box")
    np.testing.assert_allclose(box.mesh.extents, [0.19, 0.06, 0.25], atol=1e-9)
    can = builtin_object("can")
    np.testing.assert_allclose(can.mesh.extents, [0.066, 0.066, 0.10], atol=1e-3)
    assert len(can.symmetries_continuous) == 1
    np.testing.assert_allclose(can.symmetries_continuous[0]["axis"], [0, 0, 1])
    np.testing.assert_allclose(can.symmetries_continuous[0]["offset"], [0, 0, 0])
    for name in ("mug", "box", "drill"):
        assert builtin_object(name).symmetries_continuous == []
    drill = builtin_object("drill")
    assert drill.mesh.extents.max() > 0.2


def _coloured_points(obj: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(obj.mesh.vertices), np.asarray(obj.mesh.visual.vertex_colors[:, :3], int)


def test_can_appearance_is_symmetric_about_z_only():
    """Rotating the can about z (by its 64-segment step) maps coloured vertices onto coloured
    vertices; a half turn about x (top <-> bottom) does not."""
    from scipy.spatial import cKDTree

    v, c = _coloured_points(builtin_object("can"))
    tree = cKDTree(np.concatenate([v, c / 1000.0], axis=1))

    def mismatch(R: np.ndarray) -> float:
        d, _ = tree.query(np.concatenate([v @ R.T, c / 1000.0], axis=1))
        return float(np.mean(d > 1e-6))

    assert mismatch(Rotation.from_euler("z", 5 * 360 / 64, degrees=True).as_matrix()) == 0.0
    assert mismatch(Rotation.from_euler("x", 180, degrees=True).as_matrix()) > 0.3


@pytest.mark.parametrize("name", ["mug", "box", "drill"])
def test_asymmetric_objects_change_under_half_turns(name):
    """No half turn about a principal axis maps the coloured surface onto itself."""
    from scipy.spatial import cKDTree

    v, c = _coloured_points(builtin_object(name))
    tree = cKDTree(np.concatenate([v, c / 1000.0], axis=1))
    for axis in "xyz":
        R = Rotation.from_euler(axis, 180, degrees=True).as_matrix()
        d, _ = tree.query(np.concatenate([v @ R.T, c / 1000.0], axis=1))
        assert np.mean(d > 1e-6) > 0.05, axis


def test_get_object_and_fingerprint(tmp_path):
    assert get_object("mug").obj_id == 1
    path = tmp_path / "m.ply"
    box_mesh(1000.0).export(path)
    assert get_object(str(path), unit="mm").diameter == pytest.approx(BOX_DIAMETER, abs=1e-6)
    with pytest.raises(MeshError, match="teapot"):
        get_object("teapot")
    a = make_object(box_mesh(), "a")
    b = make_object(box_mesh(), "b")
    assert object_fingerprint(a) == object_fingerprint(b)
    b.mesh.visual.vertex_colors = np.full((8, 4), 255, np.uint8)
    assert object_fingerprint(a) != object_fingerprint(b)
    assert len(object_fingerprint(a)) == 40
    with pytest.raises(MeshError):
        builtin_object("teapot")


def test_implausible_sizes_are_refused_naming_the_unit_that_fits(tmp_path):
    """Diameters outside 1 cm - 2 m are refused with the unit that would fit (the 0.37 m box
    written in mm and read as metres is 374 m), unless allow_size."""
    mm, cm, m = tmp_path / "mm.ply", tmp_path / "cm.ply", tmp_path / "m.ply"
    box_mesh(1000.0).export(mm)
    box_mesh(100.0).export(cm)
    box_mesh().export(m)
    cases = ((mm, "m", "mm"), (cm, "m", "cm"), (m, "mm", "m"), (mm, "cm", "mm"))
    for path, unit, fits in cases:
        with pytest.raises(MeshError) as err:
            get_object(str(path), unit=unit)
        msg = str(err.value)
        assert msg.startswith(f"{path}: diameter ") and "outside 1 cm - 2 m" in msg, msg
        assert f"--unit {fits}" in msg and "--allow-size" in msg, msg
        scale = {"mm": 1000.0, "cm": 100.0, "m": 1.0}
        got = get_object(str(path), unit=unit, allow_size=True).diameter
        assert got == pytest.approx(BOX_DIAMETER * scale[fits] / scale[unit])
    assert get_object(str(cm), unit="cm").diameter == pytest.approx(BOX_DIAMETER)
    tiny = tmp_path / "tiny.ply"
    box_mesh(0.001).export(tiny)  # 0.37 mm in metres: no unit makes it 1 cm - 2 m
    with pytest.raises(MeshError, match=r"outside 1 cm - 2 m: no unit"):
        get_object(str(tiny), unit="mm")


def test_centred_moves_the_origin_to_the_box_centre_and_keeps_the_file_frame():
    """A mesh whose origin is off its centre (a CAD part at its base): centred() moves the
    origin to the bounding box's centre, moves points and symmetries with it, records where it
    lies in the file (file_offset) and the file's fingerprint; a centred model is itself."""
    c = np.array([0.04, -0.03, 0.12])
    mesh = box_mesh()
    mesh.apply_translation(c)
    half_turn = np.eye(4)  # the box's half-turn about z, in the file's frame (about c's axis)
    half_turn[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    half_turn[:3, 3] = [2 * c[0], 2 * c[1], 0.0]
    axis = {"axis": np.array([0.0, 0.0, 1.0]), "offset": c.copy()}
    obj = make_object(mesh, "part", symmetries_discrete=[half_turn], symmetries_continuous=[axis])
    centred = obj.centred()
    v = np.asarray(centred.mesh.vertices)
    np.testing.assert_allclose((v.min(0) + v.max(0)) / 2, 0.0, atol=1e-12)
    np.testing.assert_allclose(centred.file_offset, c)
    np.testing.assert_allclose(centred.points + c, obj.points)
    np.testing.assert_allclose(np.asarray(obj.mesh.vertices), c + v)  # the file's mesh as it was
    T = centred.symmetries_discrete[0]
    np.testing.assert_allclose(T[:3, 3], 0.0, atol=1e-12)  # a half-turn about the centre
    np.testing.assert_allclose(centred.symmetries_continuous[0]["offset"], 0.0, atol=1e-12)
    assert centred.diameter == obj.diameter
    assert centred.file_fingerprint == object_fingerprint(obj)
    assert object_fingerprint(centred) != object_fingerprint(obj)  # its crops differ
    assert centred.centred() is centred
    box = builtin_object("box")
    assert box.centred() is box
