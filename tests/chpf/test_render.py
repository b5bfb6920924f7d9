"""Tests of chpf.render (exact OpenCV pixel convention, depth, masks, colours) and gl_platform."""

from __future__ import annotations

import gc
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from chpf import gl_platform
from chpf.errors import RenderError
from chpf.objects import builtin_object, make_object
from chpf.render import Renderer, RenderOutput, corner_normals

W, H = 160, 120
K = np.array([[200.0, 0.0, 80.3], [0.0, 210.0, 60.7], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def renderer():
    r = Renderer(W, H)
    yield r
    r.close()


def coloured_box(extents=(0.1, 0.08, 0.05), colour=(200, 40, 30)) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=extents)
    mesh.visual.vertex_colors = np.tile(np.array([*colour, 255], np.uint8), (len(mesh.vertices), 1))
    return mesh


@pytest.fixture(scope="module")
def box():
    return make_object(coloured_box(), "box")


def project(X: np.ndarray, K: np.ndarray) -> np.ndarray:
    p = X @ K.T
    return p[:, :2] / p[:, 2:]


@pytest.mark.parametrize("antialias", [True, False])
def test_mask_edges_follow_opencv_pixel_centres(renderer, box, antialias):
    # box facing the camera, straddling the optical axis: only its front face is visible;
    # subpixel edges in u and v: pixel (i, j) is inside iff its centre (i, j) is
    t = np.array([0.013, -0.007, 0.5])
    out = renderer.render([(box, np.eye(3), t)], K, antialias=antialias)
    zf = t[2] - 0.025
    u0, u1 = K[0, 0] * (t[0] - 0.05) / zf + K[0, 2], K[0, 0] * (t[0] + 0.05) / zf + K[0, 2]
    v0, v1 = K[1, 1] * (t[1] - 0.04) / zf + K[1, 2], K[1, 1] * (t[1] + 0.04) / zf + K[1, 2]
    assert min(abs(x - round(x)) for x in (u0, u1, v0, v1)) > 0.05  # no ties at pixel centres
    mask = out.masks[0]
    cols, rows = np.flatnonzero(mask.any(0)), np.flatnonzero(mask.any(1))
    assert (cols[0], cols[-1]) == (int(np.ceil(u0)), int(np.floor(u1)))
    assert (rows[0], rows[-1]) == (int(np.ceil(v0)), int(np.floor(v1)))
    # a full rectangle, and depth is 0 exactly outside it
    assert mask.sum() == len(cols) * len(rows)
    np.testing.assert_array_equal(out.depth > 0, mask)
    np.testing.assert_allclose(out.depth[mask], zf, atol=1e-3)
    np.testing.assert_array_equal(out.visible_masks[0], mask)


def test_depth_of_tilted_face_is_analytic(renderer):
    # large box rotated about y: its front face is a tilted plane; depth at each pixel centre
    # must be the ray-plane intersection (1 mm)
    obj = make_object(coloured_box((0.2, 0.2, 0.02)), "plate")
    R = Rotation.from_euler("y", 35, degrees=True).as_matrix()
    t = np.array([0.01, 0.0, 0.45])
    out = renderer.render([(obj, R, t)], K)
    n = R @ np.array([0.0, 0.0, -1.0])  # front face normal (towards the camera)
    p0 = t + R @ np.array([0.0, 0.0, -0.01])
    jj, ii = np.nonzero(out.masks[0])
    rays = np.stack([(ii - K[0, 2]) / K[0, 0], (jj - K[1, 2]) / K[1, 1], np.ones(len(ii))], 1)
    z = (n @ p0) / (rays @ n)
    # stay away from the silhouette, where side faces may be seen
    inner = (np.abs(ii - ii.mean()) < 0.6 * np.ptp(ii) / 2) & (
        np.abs(jj - jj.mean()) < 0.3 * np.ptp(jj)
    )
    assert inner.sum() > 200
    np.testing.assert_allclose(out.depth[jj[inner], ii[inner]], z[inner], atol=1e-3)


def test_vertices_project_into_mask_and_centroid(renderer):
    # convex object: every vertex projects inside the silhouette (1 px tolerance at the
    # border) and the silhouette lies within the vertices' projected box
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    obj = make_object(sphere, "sphere")
    t = np.array([0.04, 0.03, 0.6])
    R = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix()
    out = renderer.render([(obj, R, t)], K)
    mask = out.masks[0]
    uv = project(sphere.vertices @ R.T + t, K)
    pix = np.round(uv).astype(int)
    grown = mask.copy()
    grown[1:] |= mask[:-1]
    grown[:-1] |= mask[1:]
    grown[:, 1:] |= grown[:, :-1].copy()
    grown[:, :-1] |= grown[:, 1:].copy()
    assert grown[pix[:, 1], pix[:, 0]].all()
    jj, ii = np.nonzero(mask)
    assert ii.min() >= np.floor(uv[:, 0].min()) and ii.max() <= np.ceil(uv[:, 0].max())
    assert jj.min() >= np.floor(uv[:, 1].min()) and jj.max() <= np.ceil(uv[:, 1].max())
    centre = project(t[None], K)[0]
    assert abs(ii.mean() - centre[0]) < 1.0 and abs(jj.mean() - centre[1]) < 1.0


def test_occlusion_visible_subset_of_full(renderer, box):
    front = make_object(coloured_box((0.05, 0.05, 0.05), (20, 200, 40)), "front")
    objects = [
        (box, np.eye(3), np.array([0.0, 0.0, 0.6])),
        (front, np.eye(3), np.array([0.02, 0.01, 0.4])),
    ]
    out = renderer.render(objects, K)
    full, vis = out.masks, out.visible_masks
    assert vis[0].sum() < full[0].sum()  # strict subset
    assert not (vis[0] & ~full[0]).any()
    np.testing.assert_array_equal(vis[1], full[1])  # the front object is not occluded
    assert not (vis[0] & vis[1]).any()
    np.testing.assert_array_equal(vis[0] | vis[1], out.depth > 0)
    np.testing.assert_allclose(out.depth[vis[1]], 0.4 - 0.025, atol=1e-3)
    np.testing.assert_allclose(out.depth[vis[0]], 0.6 - 0.025, atol=1e-3)
    # full mask of the occluded box equals its mask rendered alone
    alone = renderer.render(objects[:1], K)
    np.testing.assert_array_equal(full[0], alone.masks[0])
    # colours: each visible region has its object's colour
    assert out.rgb[vis[1]][:, 1].mean() > 150 and out.rgb[vis[0]][:, 0].mean() > 150


def test_same_object_twice_and_separate_objects(renderer, box):
    objects = [
        (box, np.eye(3), np.array([-0.08, 0.0, 0.7])),
        (box, np.eye(3), np.array([0.08, 0.0, 0.7])),
    ]
    out = renderer.render(objects, K)
    assert out.masks.shape == (2, H, W)
    assert out.masks[0].sum() > 100 and out.masks[1].sum() > 100
    assert not (out.masks[0] & out.masks[1]).any()
    np.testing.assert_array_equal(out.masks, out.visible_masks)
    # later single-object render is unaffected by the extra node
    single = renderer.render(objects[:1], K)
    np.testing.assert_array_equal(single.masks[0], out.masks[0])
    assert not single.masks[0][:, W // 2 + 5 :].any()


def test_no_objects_and_object_behind_camera(renderer, box):
    out = renderer.render([], K)
    assert isinstance(out, RenderOutput)
    assert out.rgb.shape == (H, W, 3) and out.rgb.dtype == np.uint8 and not out.rgb.any()
    assert out.depth.shape == (H, W) and out.depth.dtype == np.float32 and not out.depth.any()
    assert out.masks.shape == (0, H, W) and out.visible_masks.shape == (0, H, W)
    behind = renderer.render([(box, np.eye(3), np.array([0.0, 0.0, -0.5]))], K)
    assert behind.masks.shape == (1, H, W) and not behind.masks.any() and not behind.depth.any()
    out_of_view = renderer.render([(box, np.eye(3), np.array([5.0, 0.0, 0.5]))], K)
    assert not out_of_view.masks.any()


def test_vertex_colours_and_lighting(renderer, box):
    t = np.array([0.0, 0.0, 0.5])
    flat = renderer.render([(box, np.eye(3), t)], K, light_intensity=0.0, ambient=1.0)
    inside = flat.masks[0]
    # unit ambient, no directional light: the sRGB vertex colour comes back
    np.testing.assert_allclose(flat.rgb[inside].mean(0), [200, 40, 30], atol=2.5)
    dim = renderer.render([(box, np.eye(3), t)], K, light_intensity=0.0, ambient=0.2)
    lit = renderer.render([(box, np.eye(3), t)], K, light_intensity=2.0, ambient=0.2)
    side = renderer.render(
        [(box, np.eye(3), t)], K, light_intensity=2.0, ambient=0.2, light_direction=(1.0, 0.0, 0.2)
    )
    assert dim.rgb[inside, 0].mean() < lit.rgb[inside, 0].mean()
    assert side.rgb[inside, 0].mean() < lit.rgb[inside, 0].mean()  # grazing light is dimmer
    # anti-aliased colour: coverage in alpha, full inside, zero far outside
    assert (lit.alpha[inside] > 0).all() and lit.alpha[0, 0] == 0
    no_rgb = renderer.render([(box, np.eye(3), t)], K, rgb=False)
    assert not no_rgb.rgb.any() and no_rgb.alpha is None
    np.testing.assert_array_equal(no_rgb.masks, lit.masks)


def test_builtin_colours_are_rendered(renderer):
    mug = builtin_object("mug")
    # Rx(90) shows the object's -y side to the camera; Rz(90) first turns its -x side there
    R = Rotation.from_euler("XZ", [90, 90], degrees=True).as_matrix()
    out = renderer.render([(mug, R, np.array([0.0, 0.0, 0.35]))], K)
    px = out.rgb[out.masks[0]].astype(int)
    assert len(np.unique(px // 16, axis=0)) > 5
    assert ((px[:, 0] > 120) & (px[:, 1] < 80) & (px[:, 2] < 80)).sum() > 20  # the red print


def write_textured_ply(folder) -> None:
    """A 10 cm cube in mm as BOP writes models, ``obj_000001.ply`` + ``tex.png`` in ``folder``:
    its UVs all fall in the texture's bottom half, which is blue (the top half is green)."""
    from PIL import Image

    mesh = trimesh.creation.box(extents=(100.0, 100.0, 100.0))
    mesh.unmerge_vertices()
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2)) * 0.45  # v < 0.5: bottom
    image = np.zeros((64, 64, 3), np.uint8)
    image[:32] = (0, 200, 0)
    image[32:] = (0, 0, 200)
    Image.fromarray(image).save(folder / "tex.png")
    header = [
        "ply", "format ascii 1.0", "comment TextureFile tex.png",
        f"element vertex {len(mesh.vertices)}", "property float x", "property float y",
        "property float z", "property float texture_u", "property float texture_v",
        f"element face {len(mesh.faces)}", "property list uchar int vertex_indices", "end_header",
    ]  # fmt: skip
    body = [f"{x} {y} {z} {u} {v}" for (x, y, z), (u, v) in zip(mesh.vertices, uv, strict=True)]
    body += [f"3 {a} {b} {c}" for a, b, c in mesh.faces]
    (folder / "obj_000001.ply").write_text("\n".join(header + body) + "\n")


def test_textured_bop_ply_renders_its_texture(renderer, tmp_path):
    from chpf.objects import load_mesh

    write_textured_ply(tmp_path)
    obj = load_mesh(tmp_path / "obj_000001.ply", unit="mm")
    out = renderer.render(
        [(obj, np.eye(3), np.array([0.0, 0.0, 0.5]))], K, light_intensity=0.0, ambient=1.0
    )
    np.testing.assert_allclose(out.rgb[out.masks[0]].mean(0), [0, 0, 200], atol=3)


def test_a_renderer_left_open_exits_quietly_with_a_textured_mesh(tmp_path):
    """A process that ends with a textured mesh in an open Renderer (as render workers do, through
    chpf.crops' shared renderer) prints nothing: PyOpenGL used to log "Python is likely shutting
    down" from finalizers."""
    write_textured_ply(tmp_path)
    code = (
        "import numpy as np; from chpf.objects import load_mesh\n"
        "from chpf.crops import CropSpec, _shared_renderer, render_crops\n"
        f"obj = load_mesh({str(tmp_path / 'obj_000001.ply')!r}, unit='mm')\n"
        "render_crops(_shared_renderer(64), obj, np.eye(3)[None], CropSpec.for_object(0.17))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""


def test_size_override_and_cache_release(renderer, box):
    out = renderer.render([(box, np.eye(3), np.array([0.0, 0.0, 0.5]))], K, size=(40, 30))
    assert out.rgb.shape == (30, 40, 3) and out.masks.shape == (1, 30, 40)
    tmp = make_object(coloured_box((0.03, 0.03, 0.03)), "tmp")
    renderer.render([(tmp, np.eye(3), np.array([0.0, 0.0, 0.5]))], K)
    n_before = len(renderer._entries)
    del tmp
    gc.collect()
    renderer.render([(box, np.eye(3), np.array([0.0, 0.0, 0.5]))], K)
    assert len(renderer._entries) < n_before


def test_corner_normals_keep_creases_and_smooth_curves():
    mesh = trimesh.creation.box(extents=(1, 1, 1))
    n = corner_normals(mesh.vertices, mesh.faces)
    np.testing.assert_allclose(n, np.repeat(mesh.face_normals[:, None], 3, 1), atol=1e-9)
    sph = trimesh.creation.icosphere(subdivisions=2)
    n = corner_normals(sph.vertices, sph.faces)
    radial = sph.vertices[sph.faces] / np.linalg.norm(
        sph.vertices[sph.faces], axis=2, keepdims=True
    )
    assert (np.sum(n * radial, axis=2) > 0.99).all()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_select_gl_platform(monkeypatch):
    monkeypatch.setenv("PYOPENGL_PLATFORM", "osmesa")
    assert gl_platform.select_gl_platform() == "osmesa"
    monkeypatch.delenv("PYOPENGL_PLATFORM")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.setattr(gl_platform, "egl_available", lambda: True)
    monkeypatch.setattr(gl_platform, "osmesa_available", lambda: True)
    assert gl_platform.select_gl_platform() == "egl"
    monkeypatch.delenv("PYOPENGL_PLATFORM")
    monkeypatch.setattr(gl_platform, "egl_available", lambda: False)
    assert gl_platform.select_gl_platform() == "osmesa"
    monkeypatch.delenv("PYOPENGL_PLATFORM")
    monkeypatch.setattr(gl_platform, "osmesa_available", lambda: False)
    with pytest.raises(RenderError, match=r"libegl1.*libosmesa6"):
        gl_platform.select_gl_platform()
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(gl_platform, "egl_available", lambda: True)
    assert gl_platform.select_gl_platform() == "egl"


def test_context_failure_is_a_render_error(monkeypatch):
    import chpf.render as render_mod

    pr = render_mod._import_pyrender()

    def broken(*args, **kwargs):
        raise RuntimeError("no EGL device\nsecond line")

    monkeypatch.setattr(pr, "OffscreenRenderer", broken)
    with pytest.raises(RenderError, match="cannot create an OpenGL context") as err:
        Renderer(8, 8)
    assert "\n" not in str(err.value) and "libegl1" in str(err.value)
