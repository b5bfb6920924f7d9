"""data_gen.mesh_checks: refusals (one line, MeshError, exit 2 from chpf-gen-data) and warnings,
on small trimesh meshes written to tmp_path; the built-in objects pass."""

import json
import warnings

import numpy as np
import pytest
import trimesh

from chpf.errors import MeshError
from chpf.objects import BUILTIN_OBJECTS, builtin_object
from data_gen.mesh_checks import MeshWarning, check_mesh, check_object
from tests.helpers import console_error


def _coloured(mesh: trimesh.Trimesh, seed: int = 0) -> trimesh.Trimesh:
    """Random face colours: no symmetry maps the colours onto themselves."""
    rng = np.random.default_rng(seed)
    cols = rng.integers(0, 256, size=(len(mesh.faces), 4), dtype=np.uint8)
    cols[:, 3] = 255
    mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=cols)
    return mesh


def _write(mesh: trimesh.Trimesh, path) -> str:
    mesh.export(path)
    return str(path)


def _caught(fn, *args, **kwargs) -> list[str]:
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        fn(*args, **kwargs)
    return [str(w.message) for w in got if issubclass(w.category, MeshWarning)]


@pytest.mark.parametrize("name", list(BUILTIN_OBJECTS))
def test_builtin_objects_pass_without_warnings(name):
    obj = builtin_object(name)
    assert _caught(check_object, obj, name) == []


def test_good_mesh_passes(tmp_path):
    path = _write(_coloured(trimesh.creation.box((0.1, 0.06, 0.2))), tmp_path / "b.ply")
    assert _caught(check_mesh, path) == []


def test_wrong_unit_is_refused_naming_the_unit_that_fits(tmp_path):
    path = _write(_coloured(trimesh.creation.box((150.0, 60.0, 20.0))), tmp_path / "big.ply")
    with pytest.raises(MeshError, match=r"big\.ply: diameter .*probably in mm \(--unit mm") as err:
        check_mesh(path, "m")
    assert "\n" not in str(err.value)
    check_mesh(path, "mm")  # 0.16 m: fits


def test_degenerate_mesh_is_refused(tmp_path):
    good = _coloured(trimesh.creation.box((0.1, 0.06, 0.2)))
    v = np.concatenate([good.vertices, [[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]]])
    n = len(good.vertices)
    flat = np.array([[n, n + 1, n]] * 40)  # 40 zero-area faces against 12 real ones
    mesh = trimesh.Trimesh(v, np.concatenate([good.faces, flat]), process=False)
    path = _write(mesh, tmp_path / "flat.ply")
    with pytest.raises(MeshError, match=r"flat\.ply: degenerate mesh: 40 of 52 faces"):
        check_mesh(path)


def test_mesh_with_holes_is_refused(tmp_path):
    box = _coloured(trimesh.creation.box((0.1, 0.06, 0.2)))
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)  # one side missing
    path = _write(open_box, tmp_path / "open.ply")
    with pytest.raises(MeshError, match=r"open\.ply: mesh would render with holes: 4 open"):
        check_mesh(path)


def test_no_faces_is_refused(tmp_path):
    path = tmp_path / "points.ply"
    trimesh.PointCloud(np.random.default_rng(0).random((10, 3)) * 0.1).export(path)
    with pytest.raises(MeshError, match=r"points\.ply: mesh has no faces"):
        check_mesh(path)


def test_no_colour_warns(tmp_path):
    mesh = trimesh.creation.box((0.1, 0.06, 0.2))
    mesh.vertices[0] += 0.001  # breaks the box's symmetries: only the colour warning
    path = _write(trimesh.Trimesh(mesh.vertices, mesh.faces), tmp_path / "grey.ply")
    got = _caught(check_mesh, path)
    assert any("no colour or texture" in m for m in got), got


def test_undeclared_symmetry_warns_declared_does_not(tmp_path):
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=48)
    cyl.visual = trimesh.visual.ColorVisuals(cyl, face_colors=[200, 30, 30, 255])
    path = _write(cyl, tmp_path / "obj_000005.ply")
    got = _caught(check_mesh, path)
    assert any("symmetric under a 180 deg rotation" in m for m in got), got
    # declared in models_info.json beside it (BOP layout): a continuous symmetry about z and
    # the flip about x -- no warning any more
    from data_gen.mesh_checks import checked_object

    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    info = {
        "5": {
            "diameter": 116.6,
            "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}],
            "symmetries_discrete": [flip.ravel().tolist()],
        }
    }
    (tmp_path / "models_info.json").write_text(json.dumps(info))
    obj = None

    def run():
        nonlocal obj
        obj = checked_object(path)

    assert not [m for m in _caught(run) if "symmetric" in m]
    assert obj.symmetries_continuous == []  # as get_object gives a mesh file: same everywhere


def test_gen_data_exits_2_with_one_line(tmp_path, capsys, monkeypatch):
    from data_gen.cli import cli

    path = _write(_coloured(trimesh.creation.box((150.0, 60.0, 20.0))), tmp_path / "mm.ply")
    err = console_error(cli, capsys, monkeypatch, "pool", "--object", path, "--unit", "m")
    assert "mm.ply" in err and "--unit mm" in err, err
    box = _coloured(trimesh.creation.box((0.1, 0.06, 0.2)))
    holes = _write(trimesh.Trimesh(box.vertices, box.faces[2:], process=False), tmp_path / "h.ply")
    out = tmp_path / "ae"
    err = console_error(cli, capsys, monkeypatch, "ae", "--object", holes, "--out", out, "--n", 4)
    assert "h.ply: mesh would render with holes" in err, err


def test_a_mesh_off_its_origin_is_cropped_whole(tmp_path):
    """A mesh whose origin is at its base (as CAD parts and pybullet's duck are): the object
    the data commands use is centred, so its crops (centred on the origin) show all of it;
    before, a duck's head fell outside its own codebook crops."""
    from chpf.crops import CropSpec, render_crops
    from chpf.geometry import RotationGrid
    from data_gen.mesh_checks import checked_object

    mesh = _coloured(trimesh.creation.box((0.1, 0.06, 0.2)))
    mesh.apply_translation((0.0, 0.0, 0.1))  # origin at the bottom face
    obj = checked_object(_write(mesh, tmp_path / "part.ply"))
    spec = CropSpec.for_object(obj.diameter, 64)
    mask = render_crops(None, obj, RotationGrid.uniform(12).rotations, spec, rgb=False).mask
    border = mask[:, 0].any() or mask[:, -1].any() or mask[:, :, 0].any() or mask[:, :, -1].any()
    assert mask.any(axis=(1, 2)).all() and not border
    np.testing.assert_allclose(obj.file_offset, (0.0, 0.0, 0.1), atol=1e-9)
