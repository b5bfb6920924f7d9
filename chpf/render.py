"""Offscreen rendering of object models with OpenCV intrinsics (pyrender, headless EGL/OSMesa).

Conventions:

- Poses are object-to-camera ``R`` (3, 3), ``t`` (3,) in the OpenCV camera frame (x right,
  y down, z forward), metres. They are turned into OpenGL's camera frame (y up, looking down
  -z) with ``diag(1, -1, -1)``; the camera node stays at the identity.
- ``K`` is used exactly in the OpenCV convention (pixel centres at integer coordinates): a
  point projecting to (u, v) is drawn in pixel (round(u), round(v)). pyrender's
  ``IntrinsicsCamera`` puts pixel centres at half-integers, so it gets ``cx + 0.5, cy + 0.5``.
- Colour is rendered with 4x multisampling (anti-aliased edges) by default; depth and masks
  then come from a separate single-sample segmentation pass, so they are sampled exactly at
  pixel centres (pyrender would otherwise return the depth of multisample 0, up to 0.4 px off).
  ``antialias=False`` renders colour and depth in one single-sample pass (2-3x faster).
  Single- and multi-sample framebuffers are kept side by side (pyrender's framebuffer setup
  is replaced for this), so passes switch between them without reallocating.
  Visible masks come from object ids of the segmentation pass; full (unoccluded) masks of
  objects whose projected boxes overlap another object's need one extra pass each.
  Depth is the z coordinate in metres (0 = background).
- Shading (a small shader replacing pyrender's PBR one, which is 2-3x slower on llvmpipe):
  in linear colour, ``albedo * (ambient + intensity / pi * max(n . l, 0))``, then sRGB gamma
  (1/2.2) -- the Lambertian part of pyrender's model. Vertex colours and textures are sRGB.
  Normals are per corner: faces meeting at less than ``CREASE_DEG`` are smoothed, sharper
  edges stay sharp. Back faces are culled (closed meshes are assumed).
- One pyrender scene per Renderer; each trimesh is converted and uploaded once (cache keyed
  by identity, checked against ``hash(mesh)``, dropped when the mesh is garbage-collected).
"""

from __future__ import annotations

import atexit
import os
import re
import sys
import types
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from chpf.errors import RenderError
from chpf.gl_platform import select_gl_platform
from chpf.objects import ObjectModel, texture_image

CREASE_DEG = 35.0
DEFAULT_COLOUR = (180, 180, 180)
_GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
_MAX_NORMAL_PAIRS = 30_000_000

_pyrender: Any = None


def _import_pyrender() -> Any:
    """Select the GL platform, then import pyrender (once); RenderError in one line naming the
    ``chpf[render]`` extra when it is not installed."""
    global _pyrender
    if _pyrender is None:
        select_gl_platform()
        try:
            import pyrender
        except ImportError as err:
            raise RenderError(
                f"rendering needs pyrender, which is not installed ({err}): "
                "pip install 'chpf[render]'"
            ) from None
        except Exception as err:
            raise RenderError(f"cannot import pyrender: {type(err).__name__}: {err}") from None
        _pyrender = pyrender
    return _pyrender


@dataclass
class RenderOutput:
    """Result of ``Renderer.render`` for n objects.

    rgb (H, W, 3) uint8 (black background; zeros if rgb was not requested), depth (H, W)
    float32 metres (0 = background), masks (n, H, W) bool full (as if alone), visible_masks
    (n, H, W) bool (the object is the nearest surface), alpha (H, W) uint8 coverage of the
    anti-aliased colour pass (rgb is premultiplied: composite as rgb + bg * (1 - alpha/255)),
    None if rgb was not requested.
    """

    rgb: np.ndarray
    depth: np.ndarray
    masks: np.ndarray
    visible_masks: np.ndarray
    alpha: np.ndarray | None = None


# ----------------------------------------------------------------------------- shaders

_VERT = """#version 330 core
layout(location = 0) in vec3 position;
#ifdef NORMAL_LOC
layout(location = NORMAL_LOC) in vec3 normal;
#endif
#ifdef TEXCOORD_0_LOC
layout(location = TEXCOORD_0_LOC) in vec2 texcoord_0;
#endif
#ifdef COLOR_0_LOC
layout(location = COLOR_0_LOC) in vec4 color_0;
#endif
layout(location = INST_M_LOC) in mat4 inst_m;
uniform mat4 M;
uniform mat4 V;
uniform mat4 P;
#ifdef NORMAL_LOC
out vec3 frag_normal;
#endif
#ifdef TEXCOORD_0_LOC
out vec2 uv_0;
#endif
#ifdef COLOR_0_LOC
out vec4 color_multiplier;
#endif
void main()
{
    mat4 MI = M * inst_m;
    gl_Position = P * V * MI * vec4(position, 1.0);
#ifdef NORMAL_LOC
    frag_normal = mat3(MI) * normal;
#endif
#ifdef TEXCOORD_0_LOC
    uv_0 = texcoord_0;
#endif
#ifdef COLOR_0_LOC
    color_multiplier = color_0;
#endif
}
"""

_FRAG = """#version 330 core
#ifdef NORMAL_LOC
in vec3 frag_normal;
#endif
#ifdef TEXCOORD_0_LOC
in vec2 uv_0;
#endif
#ifdef COLOR_0_LOC
in vec4 color_multiplier;
#endif
struct Material {
    vec4 base_color_factor;
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
};
struct DirectionalLight {
    vec3 direction;
    vec3 color;
    float intensity;
};
uniform Material material;
uniform DirectionalLight directional_lights[4];
uniform int n_directional_lights;
uniform vec3 ambient_light;
out vec4 frag_color;
void main()
{
    vec4 base = material.base_color_factor;
#ifdef HAS_BASE_COLOR_TEX
    base = base * texture(material.base_color_texture, uv_0);
#endif
#ifdef COLOR_0_LOC
    base = base * color_multiplier;
#endif
    vec3 albedo = pow(base.rgb, vec3(2.2));
    vec3 light = ambient_light;
#ifdef NORMAL_LOC
    vec3 n = normalize(frag_normal);
    if (!gl_FrontFacing) n = -n;
    for (int i = 0; i < n_directional_lights; i++) {
        float nl = max(dot(n, -directional_lights[i].direction), 0.0);
        light += (0.3183099 * nl * directional_lights[i].intensity) * directional_lights[i].color;
    }
#endif
    frag_color = clamp(vec4(pow(albedo * light, vec3(1.0 / 2.2)), base.a), 0.0, 1.0);
}
"""


def _install_shaders(offscreen: Any) -> bool:
    """Make pyrender use the shaders above for lit colour passes; False if not possible."""
    from pyrender.shader_program import ShaderProgram, ShaderProgramCache

    class _SourceProgram(ShaderProgram):
        def _load(self, source: str) -> str:
            def ifdef(m: re.Match) -> str:
                return "#if 1" if m.group(1) in self.defines else "#if 0"

            text = re.sub(r"#ifdef\s+([a-zA-Z_][a-zA-Z_0-9]*)\s*$", ifdef, source, flags=re.M)
            for name, value in self.defines.items():
                text = text.replace(name, str(value))
            return text

    class _Cache(ShaderProgramCache):
        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
            if (vertex_shader, fragment_shader, geometry_shader) != (
                "mesh.vert",
                "mesh.frag",
                None,
            ):
                return super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)
            import OpenGL.contextdata

            defines = dict(defines or {})
            key = (OpenGL.contextdata.getContext(), "chpf", tuple(sorted(defines.items())))
            if key not in self._program_cache:
                self._program_cache[key] = _SourceProgram(_VERT, _FRAG, defines=defines)
            return self._program_cache[key]

    inner = getattr(offscreen, "_renderer", None)
    if inner is None or not hasattr(inner, "_program_cache"):
        return False
    inner._program_cache = _Cache()
    return True


_FB_ATTRS = ("_main_fb", "_main_cb", "_main_db", "_main_fb_ms", "_main_cb_ms", "_main_db_ms")
_MAX_FRAMEBUFFERS = 4


def _install_framebuffer_switch(offscreen: Any) -> bool:
    """Let pyrender's main framebuffer be multisampled (4x) or single-sampled on demand.

    Replaces the inner renderer's ``_configure_main_framebuffer``: the buffers are pyrender's,
    made with ``inner._chpf_samples`` samples (0 = single-sample: exact pixel-centre colour and
    depth, and much cheaper clears and resolves). Framebuffers are kept per (width, height,
    samples) -- at most ``_MAX_FRAMEBUFFERS`` -- so alternating passes do not reallocate.
    False if pyrender's internals differ (then pyrender's 4x framebuffer is always used).
    """
    inner = getattr(offscreen, "_renderer", None)
    needed = (*_FB_ATTRS, "_main_fb_dims", "viewport_width", "viewport_height")
    if inner is None or not all(hasattr(inner, a) for a in needed):
        return False
    from OpenGL import GL

    def framebuffer(w: int, h: int, samples: int) -> tuple:
        """(fb, colour rb, depth rb); multisampled when ``samples`` > 0."""
        cb, db = GL.glGenRenderbuffers(2)
        for rb, fmt in ((cb, GL.GL_RGBA), (db, GL.GL_DEPTH_COMPONENT24)):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rb)
            if samples > 0:
                GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, samples, fmt, w, h)
            else:
                GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, fmt, w, h)
        fb = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, fb)
        for attachment, rb in ((GL.GL_COLOR_ATTACHMENT0, cb), (GL.GL_DEPTH_ATTACHMENT, db)):
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, attachment, GL.GL_RENDERBUFFER, rb)
        return fb, cb, db

    def create(w: int, h: int, samples: int) -> tuple:
        return framebuffer(w, h, 0) + framebuffer(w, h, samples)

    def delete(ids: tuple) -> None:
        fb, cb, db, fb_ms, cb_ms, db_ms = ids
        GL.glDeleteFramebuffers(2, [fb, fb_ms])
        GL.glDeleteRenderbuffers(4, [cb, db, cb_ms, db_ms])

    def configure(self: Any) -> None:
        key = (int(self.viewport_width), int(self.viewport_height), int(self._chpf_samples))
        if self._main_fb is not None and key == self._chpf_fb_key:
            return
        if self._main_fb is not None and self._chpf_fb_key is not None:  # park the current one
            self._chpf_fbs[self._chpf_fb_key] = tuple(getattr(self, a) for a in _FB_ATTRS)
        elif self._main_fb is not None:  # pyrender's own (unknown samples): free it
            self._delete_main_framebuffer()
        ids = self._chpf_fbs.pop(key, None)
        if ids is None:
            ids = create(*key)
        while len(self._chpf_fbs) >= _MAX_FRAMEBUFFERS:
            delete(self._chpf_fbs.pop(next(iter(self._chpf_fbs))))
        for a, v in zip(_FB_ATTRS, ids, strict=True):
            setattr(self, a, v)
        self._main_fb_dims = key[:2]
        self._chpf_fb_key = key

    inner._chpf_samples = 4
    inner._chpf_fbs = {}
    inner._chpf_fb_key = None
    inner._configure_main_framebuffer = types.MethodType(configure, inner)
    return True


# ----------------------------------------------------------------------------- meshes


def corner_normals(
    vertices: np.ndarray, faces: np.ndarray, crease_deg: float = CREASE_DEG
) -> np.ndarray:
    """(F, 3, 3) unit normals per face corner: area-weighted mean of the normals of the faces
    sharing the corner's position whose normal is within ``crease_deg`` of the face's own."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1, keepdims=True)
    fn = np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)
    area = norm[:, 0]
    _, pos_id = np.unique(v, axis=0, return_inverse=True)
    cpos = pos_id.reshape(-1)[f].ravel()
    cface = np.repeat(np.arange(len(f)), 3)
    order = np.argsort(cpos, kind="stable")
    spos = cpos[order]
    starts = np.flatnonzero(np.r_[True, spos[1:] != spos[:-1]])
    sizes = np.diff(np.r_[starts, len(spos)])
    group = np.repeat(np.arange(len(starts)), sizes)  # group of each sorted corner
    d = sizes[group]
    total = int(d.sum())
    if total > _MAX_NORMAL_PAIRS:  # pathological fans: plain per-face normals
        return np.repeat(fn[:, None, :], 3, axis=1)
    ci = np.repeat(np.arange(len(spos)), d)
    offs = np.arange(total) - np.repeat(np.cumsum(d) - d, d)
    cj = np.repeat(starts[group], d) + offs
    fi, fj = cface[order[ci]], cface[order[cj]]
    cos = (fn[fi] * fn[fj]).sum(1)
    w = area[fj] * (cos >= np.cos(np.deg2rad(crease_deg)))
    acc = np.stack(
        [np.bincount(ci, weights=w * fn[fj, k], minlength=len(spos)) for k in range(3)], 1
    )
    out = np.empty_like(acc)
    out[order] = acc
    n = np.linalg.norm(out, axis=1, keepdims=True)
    own = fn[cface]
    out = np.where(n > 1e-12, out / np.where(n > 0, n, 1.0), own)
    return out.reshape(-1, 3, 3)


def _pyrender_mesh(mesh: trimesh.Trimesh) -> Any:
    """A pyrender.Mesh with per-corner normals and colours (vertex, face or texture)."""
    pr = _import_pyrender()
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    nrm = corner_normals(v, f).reshape(-1, 3)
    cvert = f.ravel()
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    image = texture_image(mesh) if kind == "texture" else None
    uv = getattr(visual, "uv", None) if image is not None else None
    if image is not None and (uv is None or len(uv) != len(v)):
        image = None
    colours = None
    if image is None:
        if kind == "vertex":
            colours = np.asarray(visual.vertex_colors, dtype=np.uint8)[cvert]
        elif kind == "face":
            colours = np.repeat(np.asarray(visual.face_colors, dtype=np.uint8), 3, axis=0)
        elif kind == "texture":
            try:
                colours = np.asarray(visual.to_color().vertex_colors, dtype=np.uint8)[cvert]
            except Exception:
                colours = None
        if colours is None:
            colours = np.tile(np.array([*DEFAULT_COLOUR, 255], np.uint8), (len(cvert), 1))
        colours = (
            colours[:, :4]
            if colours.shape[1] >= 4
            else np.concatenate([colours[:, :3], np.full((len(colours), 1), 255, np.uint8)], axis=1)
        )
    key_parts = [cvert[:, None].astype(np.int64), np.round(nrm * 1e5).astype(np.int64)]
    if colours is not None:
        key_parts.append(colours.astype(np.int64))
    _, first, inverse = np.unique(
        np.concatenate(key_parts, axis=1), axis=0, return_index=True, return_inverse=True
    )
    material_kw: dict[str, Any] = {}
    if image is not None:
        material_kw["baseColorTexture"] = pr.Texture(
            source=np.ascontiguousarray(image),
            source_channels="RGBA" if image.shape[2] == 4 else "RGB",
        )
    material = pr.MetallicRoughnessMaterial(
        baseColorFactor=[1.0, 1.0, 1.0, 1.0],
        metallicFactor=0.0,
        roughnessFactor=1.0,
        alphaMode="OPAQUE",
        doubleSided=False,
        **material_kw,
    )
    prim = pr.Primitive(
        positions=v[cvert[first]].astype(np.float32),
        normals=nrm[first].astype(np.float32),
        texcoord_0=None if image is None else np.asarray(uv, np.float32)[cvert[first]],
        color_0=None if colours is None else colours[first].astype(np.float32) / 255.0,
        indices=inverse.reshape(-1, 3).astype(np.uint32),
        material=material,
    )
    return pr.Mesh(primitives=[prim])


class _Entry:
    """Cached pyrender mesh of one trimesh, and its scene nodes."""

    def __init__(self, mesh: trimesh.Trimesh, pmesh: Any, node: Any) -> None:
        self.ref = weakref.ref(mesh)
        self.hash = hash(mesh)
        self.pmesh = pmesh
        self.nodes = [node]
        self.radius = float(np.linalg.norm(mesh.vertices, axis=1).max())
        unit = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
        lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
        self.corners = lo + unit * (hi - lo)  # (8, 3) bounding-box corners, object frame


def _light_pose(direction_cv: np.ndarray) -> np.ndarray:
    """Pose of a pyrender DirectionalLight shining along ``direction_cv`` (OpenCV camera frame)."""
    d = np.asarray(direction_cv, dtype=np.float64).reshape(3)
    n = np.linalg.norm(d)
    if not np.isfinite(n) or n == 0:
        raise ValueError("light_direction must be a finite non-zero 3-vector")
    z = -(_GL_FROM_CV[:3, :3] @ (d / n))  # pyrender lights shine along -z of their node
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, y, z
    return T


# Every open Renderer, closed at exit while the interpreter is still whole: GL objects freed
# later, by finalizers during shutdown, make PyOpenGL log "Python is likely shutting down" (seen
# with textured meshes).
_OPEN: weakref.WeakSet[Renderer] = weakref.WeakSet()


@atexit.register
def _close_open_renderers() -> None:
    for renderer in list(_OPEN):
        renderer.close()


class Renderer:
    """Offscreen renderer of ``(ObjectModel, R, t)`` lists with OpenCV intrinsics.

    Wraps one pyrender.OffscreenRenderer (one GL context) and one scene that is reused: meshes
    are converted and uploaded once per trimesh object (cached by identity, dropped when the
    mesh is garbage-collected) and only node poses, camera and light change between renders.
    Not thread-safe; use one Renderer per thread/process, created inside the process that uses
    it (GL contexts do not survive ``fork``).
    """

    def __init__(self, width: int, height: int) -> None:
        if int(width) <= 0 or int(height) <= 0:
            raise ValueError(f"Renderer size must be positive, got {width}x{height}")
        self.width, self.height = int(width), int(height)
        pr = _import_pyrender()
        try:
            self._r = pr.OffscreenRenderer(self.width, self.height)
        except Exception as err:
            msg = " ".join(str(err).split()) or type(err).__name__
            raise RenderError(
                f"cannot create an OpenGL context (PYOPENGL_PLATFORM="
                f"{os.environ.get('PYOPENGL_PLATFORM')}): {msg}; install libegl1 libegl-mesa0 "
                "libgl1-mesa-dri (EGL) or libosmesa6 (OSMesa)"
            ) from None
        self.custom_shaders = _install_shaders(self._r)
        self.msaa_switch = _install_framebuffer_switch(self._r)
        self._pr = pr
        self._scene = pr.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[0.3, 0.3, 0.3])
        self._cam = pr.IntrinsicsCamera(1.0, 1.0, 0.0, 0.0, znear=0.01, zfar=10.0)
        self._scene.add(self._cam, pose=np.eye(4))
        self._light = pr.DirectionalLight(color=np.ones(3), intensity=3.0)
        self._light_node = self._scene.add(self._light, pose=np.eye(4))
        self._entries: dict[int, _Entry] = {}
        _OPEN.add(self)

    # -- context management
    def close(self) -> None:
        """Free the GL context (idempotent).

        With EGL, only this renderer's context is destroyed: pyrender's own ``delete`` calls
        ``eglTerminate`` on the display shared by every EGL context of the process, which would
        break all other live renderers.
        """
        r = getattr(self, "_r", None)
        if r is None:
            return
        self._r = None
        self._entries = {}
        plat = getattr(r, "_platform", None)
        if plat is not None and type(plat).__name__ == "EGLPlatform":
            from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent

            plat.make_current()
            r._renderer.delete()
            display, context = plat._egl_display, plat._egl_context
            eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
            if context is not None:
                eglDestroyContext(display, context)
            plat._egl_context = None
            plat._egl_display = None
            r._renderer = None
            r._platform = None
        else:
            r.delete()

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if sys.is_finalizing():  # GL calls during interpreter shutdown may crash
            return
        try:
            self.close()
        except Exception:
            pass

    # -- scene bookkeeping
    def _purge(self) -> None:
        for key, e in list(self._entries.items()):
            if e.ref() is None:
                for node in e.nodes:
                    self._scene.remove_node(node)
                del self._entries[key]

    def _entry(self, mesh: trimesh.Trimesh) -> _Entry:
        e = self._entries.get(id(mesh))
        if e is not None and (e.ref() is not mesh or e.hash != hash(mesh)):
            for node in e.nodes:
                self._scene.remove_node(node)
            del self._entries[id(mesh)]
            e = None
        if e is None:
            pmesh = _pyrender_mesh(mesh)
            node = self._scene.add(pmesh, pose=np.eye(4))
            e = _Entry(mesh, pmesh, node)
            self._entries[id(mesh)] = e
        return e

    # -- rendering
    def render(
        self,
        objects: list[tuple[ObjectModel, np.ndarray, np.ndarray]],
        K: np.ndarray,
        light_intensity: float = 3.0,
        ambient: float = 0.3,
        light_direction: np.ndarray | None = None,
        rgb: bool = True,
        size: tuple[int, int] | None = None,
        antialias: bool = True,
    ) -> RenderOutput:
        """Render ``objects`` = [(obj, R (3,3), t (3,) metres)] with OpenCV intrinsics K (3,3).

        ``light_intensity``: directional light (a surface facing it gets intensity/pi times its
        albedo, linear colour); ``ambient``: ambient light (same units); ``light_direction``
        (3,) in the OpenCV camera frame, the direction the light travels (default (0, 0, 1):
        from the camera into the scene). ``rgb=False`` skips the colour pass (depth and masks
        only). ``size`` = (width, height) overrides the renderer's size for this call.
        ``antialias``: 4x multisampled colour (then depth and masks come from an extra
        single-sample pass); False renders colour and depth in one exact single-sample pass
        (aliased edges, 2-3x faster). Depth and masks are exact either way.
        """
        if self._r is None:
            raise RenderError("Renderer is closed")
        width, height = (self.width, self.height) if size is None else (int(size[0]), int(size[1]))
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be a finite (3, 3) matrix, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 or abs(K[1, 0]) > 1e-9:
            raise ValueError("K with skew is not supported (K[0, 1] and K[1, 0] must be 0)")
        n = len(objects)
        empty = RenderOutput(
            rgb=np.zeros((height, width, 3), np.uint8),
            depth=np.zeros((height, width), np.float32),
            masks=np.zeros((n, height, width), bool),
            visible_masks=np.zeros((n, height, width), bool),
            alpha=np.zeros((height, width), np.uint8) if rgb else None,
        )
        if n == 0:
            return empty
        self._purge()
        pr = self._pr
        # place the objects
        used: dict[int, int] = {}
        nodes, zmin, zmax, boxes = [], np.inf, -np.inf, []
        for obj, R, t in objects:
            R = np.asarray(R, dtype=np.float64).reshape(3, 3)
            t = np.asarray(t, dtype=np.float64).reshape(3)
            e = self._entry(obj.mesh)
            k = used.get(id(e), 0)
            used[id(e)] = k + 1
            if k == len(e.nodes):
                e.nodes.append(self._scene.add(e.pmesh, pose=np.eye(4)))
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R, t
            self._scene.set_pose(e.nodes[k], _GL_FROM_CV @ T)
            nodes.append(e.nodes[k])
            zmin, zmax = min(zmin, t[2] - e.radius), max(zmax, t[2] + e.radius)
            pc = e.corners @ R.T + t
            if np.all(pc[:, 2] > 1e-9):
                uv = pc[:, :2] / pc[:, 2:] * np.diag(K)[:2] + K[:2, 2]
                boxes.append((uv.min(0) - 1.0, uv.max(0) + 1.0))
            else:
                boxes.append(None)
        if zmax <= 0:
            return empty
        for e in self._entries.values():
            k = used.get(id(e), 0)
            e.pmesh.is_visible = k > 0
            while len(e.nodes) > max(k, 1):
                self._scene.remove_node(e.nodes.pop())
        # camera, light
        znear = max(1e-3, 0.9 * zmin) if zmin > 0 else 1e-3
        zfar = max(1.1 * zmax, 2.0 * znear)
        self._cam.fx, self._cam.fy = K[0, 0], K[1, 1]
        self._cam.cx, self._cam.cy = K[0, 2] + 0.5, K[1, 2] + 0.5
        self._cam.znear, self._cam.zfar = znear, zfar
        self._light.intensity = float(light_intensity)
        self._scene.set_pose(
            self._light_node,
            _light_pose((0.0, 0.0, 1.0) if light_direction is None else light_direction),
        )
        self._scene.ambient_light = np.full(3, float(ambient))
        self._r.viewport_width, self._r.viewport_height = width, height
        single = not antialias and self.msaa_switch
        seg_flag = pr.RenderFlags.SEG

        def render_pass(samples: int, flags: int, seg_map: dict | None = None) -> Any:
            if self.msaa_switch:
                self._r._renderer._chpf_samples = samples
            return self._r.render(self._scene, flags=flags, seg_node_map=seg_map)

        try:
            out_rgb, alpha, depth, visible = empty.rgb, None, None, None
            if rgb:
                colour, d = render_pass(0 if single else 4, pr.RenderFlags.RGBA)
                out_rgb = np.ascontiguousarray(colour[:, :, :3])
                alpha = np.ascontiguousarray(colour[:, :, 3])
                if single:  # single-sample: exact pixel-centre depth from the same pass
                    depth = np.ascontiguousarray(d, dtype=np.float32)
                    if n == 1:
                        visible = (depth > 0)[None]
            if visible is None:  # object ids and exact depth: single-sample segmentation pass
                ids = {
                    node: ((i + 1) & 255, ((i + 1) >> 8) & 255, 0) for i, node in enumerate(nodes)
                }
                seg, d = render_pass(0, seg_flag, ids)
                seg_id = seg[:, :, 0].astype(np.int32) | (seg[:, :, 1].astype(np.int32) << 8)
                if depth is None:
                    depth = np.ascontiguousarray(d, dtype=np.float32)
                visible = seg_id[None] == np.arange(1, n + 1)[:, None, None]
                visible &= depth[None] > 0
            masks = visible.copy()
            for i, node in enumerate(nodes):
                if n > 1 and _overlaps(boxes, i):  # full mask of an object that may be occluded
                    _, d_i = render_pass(0, seg_flag, {node: (255, 255, 255)})
                    masks[i] = d_i > 0
        except RenderError:
            raise
        except Exception as err:
            msg = " ".join(str(err).split()) or type(err).__name__
            raise RenderError(f"rendering failed: {type(err).__name__}: {msg}") from None
        visible &= masks
        return RenderOutput(
            rgb=out_rgb, depth=depth, masks=masks, visible_masks=visible, alpha=alpha
        )


def _overlaps(boxes: list[Any], i: int) -> bool:
    """True if object i's projected box may overlap another object's (None = unknown)."""
    if boxes[i] is None:
        return True
    lo, hi = boxes[i]
    for j, b in enumerate(boxes):
        if j == i:
            continue
        if b is None:
            return True
        if np.all(lo <= b[1]) and np.all(b[0] <= hi):
            return True
    return False
