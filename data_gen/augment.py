"""Image augmentations (numpy/cv2 only, all driven by a ``numpy.random.Generator``).

Backgrounds (procedural textures and a user image folder), random-shape occluders and their
placement at a controlled covered fraction, colour jitter, noise, blur, and depth noise/holes.
"""

from __future__ import annotations

import functools
import io
from pathlib import Path

import cv2
import numpy as np

from chpf.atomic import atomic_write_bytes
from chpf.errors import ConfigError

TEXTURE_VERSION = 1  # bump when the texture generator changes (invalidates cached banks)
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


# ----------------------------------------------------------------------------- textures


def _palette(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n,3) float32 random colours in [0, 255], biased away from pure greys."""
    base = rng.uniform(0, 255, size=(n, 3))
    return base.astype(np.float32)


def _fractal_noise(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size,size) float32 in [0,1]: sum of upsampled random grids (value noise)."""
    out = np.zeros((size, size), np.float32)
    amp, total = 1.0, 0.0
    cells = int(rng.integers(2, 6))
    while cells <= size:
        small = rng.random((cells, cells), dtype=np.float32)
        out += amp * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= float(rng.uniform(0.4, 0.7))
        cells *= 2
    out /= total
    lo, hi = out.min(), out.max()
    return (out - lo) / max(hi - lo, 1e-6)


def _colourise(v: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Map a [0,1] field (H,W) to RGB through a random 2-4 colour ramp."""
    k = int(rng.integers(2, 5))
    cols = _palette(rng, k)
    x = v * (k - 1)
    i = np.clip(x.astype(np.int32), 0, k - 2)
    f = (x - i)[..., None]
    return cols[i] * (1 - f) + cols[i + 1] * f


def _texture(rng: np.random.Generator, size: int) -> np.ndarray:
    """One (size,size,3) uint8 procedural texture of a random family."""
    kind = int(rng.integers(0, 6))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    if kind == 0:  # fractal noise
        img = _colourise(_fractal_noise(rng, size), rng)
    elif kind == 1:  # stripes / checks, rotated
        a = rng.uniform(0, np.pi)
        f = rng.uniform(3, 30)
        u = np.cos(a) * xx + np.sin(a) * yy
        v = -np.sin(a) * xx + np.cos(a) * yy
        if rng.random() < 0.5:
            field = (np.sin(2 * np.pi * f * u) > 0).astype(np.float32)
        else:
            field = ((np.floor(f * u) + np.floor(f * v)) % 2).astype(np.float32)
        img = _colourise(field, rng)
    elif kind == 2:  # marble / wood: sine warped by noise
        n = _fractal_noise(rng, size)
        f = rng.uniform(2, 12)
        field = 0.5 + 0.5 * np.sin(2 * np.pi * (f * xx + rng.uniform(2, 8) * n))
        img = _colourise(field, rng)
    elif kind == 3:  # clutter of random shapes
        img = np.empty((size, size, 3), np.float32)
        img[:] = _palette(rng, 1)[0]
        for _ in range(int(rng.integers(10, 60))):
            c = tuple(float(x) for x in _palette(rng, 1)[0])
            p = tuple(int(x) for x in rng.integers(0, size, 2))
            r = int(rng.integers(2, max(3, size // 6)))
            shape = rng.integers(0, 3)
            if shape == 0:
                cv2.circle(img, p, r, c, -1)
            elif shape == 1:
                q = tuple(int(x) for x in rng.integers(0, size, 2))
                cv2.rectangle(img, p, q, c, -1)
            else:
                q = tuple(int(x) for x in rng.integers(0, size, 2))
                cv2.line(img, p, q, c, int(rng.integers(1, 6)))
    elif kind == 4:  # gradient + fine noise
        c0, c1 = _palette(rng, 2)
        a = rng.uniform(0, 2 * np.pi)
        t = np.cos(a) * xx + np.sin(a) * yy
        t = (t - t.min()) / max(float(t.max() - t.min()), 1e-6)
        img = c0 * (1 - t[..., None]) + c1 * t[..., None]
        img += rng.normal(0, rng.uniform(2, 20), size=img.shape).astype(np.float32)
    else:  # blotches: thresholded noise, two colours + noise texture
        n = _fractal_noise(rng, size)
        mask = (n > rng.uniform(0.3, 0.7)).astype(np.float32)[..., None]
        c0, c1 = _palette(rng, 2)
        img = c0 * (1 - mask) + c1 * mask
        img *= (0.8 + 0.4 * _fractal_noise(rng, size))[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def procedural_textures(n: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """(n,size,size,3) uint8 procedural textures (noise, stripes, checks, marble, shapes...)."""
    return np.stack([_texture(rng, size) for _ in range(n)])


def load_image_folder(folder: str | Path, max_images: int, side: int) -> np.ndarray:
    """Images of ``folder`` (sorted, up to ``max_images``), centre-cropped square, resized to
    ``side``: (n,side,side,3) uint8 RGB. ``ConfigError`` if the folder holds no readable image."""
    d = Path(folder).expanduser()
    if not d.is_dir():
        raise ConfigError(f"{d}: background image folder not found")
    files = sorted(p for p in d.rglob("*") if p.suffix.lower() in IMAGE_EXTS)[:max_images]
    out = []
    for p in files:
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None:
            continue
        h, w = img.shape[:2]
        m = min(h, w)
        img = img[(h - m) // 2 : (h - m) // 2 + m, (w - m) // 2 : (w - m) // 2 + m]
        img = cv2.resize(img, (side, side), interpolation=cv2.INTER_AREA)
        out.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    if not out:
        raise ConfigError(f"{d}: no readable images ({', '.join(IMAGE_EXTS)}) in folder")
    return np.stack(out)


def plain_patch(rng: np.random.Generator, size: int, top: int = 256) -> np.ndarray:
    """(size,size,3) uint8 filled with one random colour, channels drawn in [0, top)."""
    img = np.empty((size, size, 3), np.uint8)
    img[:] = rng.integers(0, top, 3).astype(np.uint8)
    return img


class Backgrounds:
    """Random background patches: procedural textures, optional user images, plain colours."""

    def __init__(
        self,
        textures: np.ndarray,
        images: np.ndarray | None = None,
        image_share: float = 0.5,
        plain_share: float = 0.05,
    ) -> None:
        self.textures = textures
        self.images = images
        self.image_share = image_share if images is not None else 0.0
        self.plain_share = plain_share
        self._pyramids = {id(textures): _pyramid(textures)}
        if images is not None:
            self._pyramids[id(images)] = _pyramid(images)

    @classmethod
    def from_config(cls, bg_cfg: dict, cache_dir: str | Path | None = None) -> Backgrounds:
        """Build from the ``background`` config section (textures are seeded by its ``seed``
        and, with ``cache_dir``, stored there once and memory-mapped afterwards)."""
        return _backgrounds_cached(
            int(bg_cfg["num_textures"]),
            int(bg_cfg["texture_size"]),
            int(bg_cfg["seed"]),
            bg_cfg["image_dir"],
            int(bg_cfg["max_images"]),
            float(bg_cfg["image_share"]),
            float(bg_cfg["plain_share"]),
            None if cache_dir is None else str(cache_dir),
        )

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """(size,size,3) uint8: a random square crop (side between size/2 and the source's side,
        resampled from a pyramid level at most 2x larger), flip and 90-degree turn of a source."""
        r = rng.random()
        if r < self.plain_share:
            return plain_patch(rng, size)
        src_set = self.images if rng.random() < self.image_share else self.textures
        i = int(rng.integers(0, len(src_set)))
        n = src_set.shape[1]
        side = int(rng.integers(min(size, n) // 2 + 1, n + 1)) if n > size // 2 else n
        y, x = (int(v) for v in rng.integers(0, n - side + 1, 2))
        levels = self._pyramids[id(src_set)]
        lev = 0
        while side >> lev > 2 * size and lev + 1 < len(levels):
            lev += 1
        side_l, y, x = max(side >> lev, 1), y >> lev, x >> lev
        patch = levels[lev][i, y : y + side_l, x : x + side_l]
        if side_l != size:
            patch = cv2.resize(patch, (size, size), interpolation=cv2.INTER_LINEAR)
        k = int(rng.integers(0, 8))
        if k & 1:
            patch = patch[:, ::-1]
        if k & 2:
            patch = patch[::-1]
        if k & 4:
            patch = patch.transpose(1, 0, 2)
        return np.array(patch, order="C")  # always a fresh, writable copy


def _pyramid(images: np.ndarray, min_side: int = 32) -> list[np.ndarray]:
    """[images, half size, quarter size, ...] (area-averaged) down to ``min_side``."""
    levels = [images]
    while levels[-1].shape[1] // 2 >= min_side:
        prev = levels[-1]
        h = prev.shape[1] // 2
        levels.append(
            np.stack([cv2.resize(im, (h, h), interpolation=cv2.INTER_AREA) for im in prev])
        )
    return levels


def textures_cached(n: int, size: int, seed: int, cache_dir: str | Path | None) -> np.ndarray:
    """``procedural_textures(n, size)`` of seed ``seed``, cached as
    ``cache_dir/textures-{n}-{size}-{seed}.npy`` (written atomically, memory-mapped)."""
    if cache_dir is None:
        return procedural_textures(n, size, np.random.default_rng([seed, 7391]))
    path = Path(cache_dir) / f"textures-v{TEXTURE_VERSION}-{n}-{size}-{seed}.npy"
    if path.is_file():
        try:
            return np.load(path, mmap_mode="r")
        except (OSError, ValueError):
            pass
    tex = procedural_textures(n, size, np.random.default_rng([seed, 7391]))
    buf = io.BytesIO()
    np.save(buf, tex)
    atomic_write_bytes(path, buf.getvalue())
    return tex


@functools.lru_cache(maxsize=4)
def _backgrounds_cached(
    n: int,
    size: int,
    seed: int,
    image_dir: str | None,
    max_images: int,
    share: float,
    plain: float,
    cache_dir: str | None,
) -> Backgrounds:
    tex = textures_cached(n, size, seed, cache_dir)
    imgs = load_image_folder(image_dir, max_images, size * 2) if image_dir else None
    return Backgrounds(tex, imgs, share, plain)


# ----------------------------------------------------------------------------- occluders


def random_shape(
    rng: np.random.Generator, size: int, textures: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A random occluder shape in a (size,size) canvas: (rgb uint8 (size,size,3), mask bool).

    Ellipse, polygon, rectangle (possibly rotated) or a thick stroke, filled with a plain colour
    or a texture patch.
    """
    m = np.zeros((size, size), np.uint8)
    c = size / 2.0
    kind = int(rng.integers(0, 4))
    if kind == 0:
        axes = (int(rng.uniform(0.25, 0.5) * size), int(rng.uniform(0.15, 0.5) * size))
        cv2.ellipse(m, (int(c), int(c)), axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    elif kind == 1:
        k = int(rng.integers(3, 9))
        ang = np.sort(rng.uniform(0, 2 * np.pi, k))
        rad = rng.uniform(0.2, 0.5, k) * size
        pts = np.stack([c + rad * np.cos(ang), c + rad * np.sin(ang)], -1).astype(np.int32)
        cv2.fillPoly(m, [pts], 1)
    elif kind == 2:
        w, h = rng.uniform(0.2, 0.5, 2) * size
        box = cv2.boxPoints(((c, c), (2 * w, 2 * h), float(rng.uniform(0, 180))))
        cv2.fillPoly(m, [box.astype(np.int32)], 1)
    else:
        a = rng.uniform(0, np.pi)
        d = np.array([np.cos(a), np.sin(a)]) * size * 0.45
        p, q = (c - d).astype(int), (c + d).astype(int)
        cv2.line(
            m,
            tuple(int(v) for v in p),
            tuple(int(v) for v in q),
            1,
            int(rng.uniform(0.15, 0.45) * size),
        )
    if textures is not None and rng.random() < 0.5:
        t = textures[int(rng.integers(0, len(textures)))]
        rgb = cv2.resize(t, (size, size), interpolation=cv2.INTER_AREA)
    else:
        rgb = np.empty((size, size, 3), np.uint8)
        rgb[:] = rng.integers(0, 256, 3).astype(np.uint8)
        if rng.random() < 0.5:  # simple shading
            g = np.linspace(rng.uniform(0.6, 1.0), rng.uniform(0.6, 1.0), size, dtype=np.float32)
            rgb = np.clip(rgb * g[:, None, None], 0, 255).astype(np.uint8)
    return rgb, m.astype(bool)


def _overlap_slices(
    shape: tuple[int, int], occ_shape: tuple[int, int], y0: int, x0: int
) -> tuple[tuple[slice, slice], tuple[slice, slice]] | None:
    """Slices (image, occluder) where an occluder with top-left (y0,x0) overlaps the image."""
    H, W = shape
    h, w = occ_shape
    ya, yb = max(y0, 0), min(y0 + h, H)
    xa, xb = max(x0, 0), min(x0 + w, W)
    if ya >= yb or xa >= xb:
        return None
    return (slice(ya, yb), slice(xa, xb)), (slice(ya - y0, yb - y0), slice(xa - x0, xb - x0))


def covered_pixels(obj_mask: np.ndarray, occ_mask: np.ndarray, y0: int, x0: int) -> int:
    """Number of object pixels covered by the occluder mask placed with top-left (y0, x0)."""
    sl = _overlap_slices(obj_mask.shape, occ_mask.shape, y0, x0)
    if sl is None:
        return 0
    return int(np.count_nonzero(obj_mask[sl[0]] & occ_mask[sl[1]]))


def place_occluder(
    obj_mask: np.ndarray, occ_mask: np.ndarray, target: float, rng: np.random.Generator
) -> tuple[int, int]:
    """Top-left (y0, x0) for ``occ_mask`` so it covers about ``target`` of ``obj_mask``.

    The occluder slides in from a random direction towards the object's centroid; a bisection
    on the slide distance matches the covered fraction (exact value: count the masks after).
    """
    ys, xs = np.nonzero(obj_mask)
    area = len(ys)
    h, w = occ_mask.shape
    if area == 0:
        return int(rng.integers(-h // 2, obj_mask.shape[0] - h // 2)), 0
    cy, cx = ys.mean(), xs.mean()
    r_obj = np.sqrt(((ys - cy) ** 2 + (xs - cx) ** 2).max())
    r_far = r_obj + np.hypot(h, w) + 1
    oys, oxs = np.nonzero(occ_mask)
    my, mx = (oys.mean(), oxs.mean()) if len(oys) else (h / 2, w / 2)  # occluder centroid
    a = rng.uniform(0, 2 * np.pi)
    dy, dx = np.sin(a), np.cos(a)
    # aim at a point near the centroid, so that full coverage is not always central
    oy, ox = rng.normal(0, 0.15 * r_obj, 2)

    def top_left(s: float) -> tuple[int, int]:
        return round(cy + oy + dy * s - my), round(cx + ox + dx * s - mx)

    lo, hi = 0.0, float(r_far)  # coverage(lo) high, coverage(hi) = 0
    want = target * area
    if covered_pixels(obj_mask, occ_mask, *top_left(lo)) <= want:
        return top_left(lo)
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if covered_pixels(obj_mask, occ_mask, *top_left(mid)) > want:
            lo = mid
        else:
            hi = mid
        if hi - lo < 0.5:
            break
    c_lo = covered_pixels(obj_mask, occ_mask, *top_left(lo))
    c_hi = covered_pixels(obj_mask, occ_mask, *top_left(hi))
    return top_left(lo if abs(c_lo - want) < abs(c_hi - want) else hi)


def paste(
    img: np.ndarray,
    rgb: np.ndarray,
    mask: np.ndarray,
    y0: int,
    x0: int,
    covered: np.ndarray | None = None,
) -> None:
    """In place: copy ``rgb`` where ``mask`` into ``img`` at top-left (y0,x0); also set
    ``covered`` (H,W bool) there if given."""
    sl = _overlap_slices(img.shape[:2], mask.shape, y0, x0)
    if sl is None:
        return
    m = mask[sl[1]]
    img[sl[0]][m] = rgb[sl[1]][m]
    if covered is not None:
        covered[sl[0]] |= m


# ----------------------------------------------------------------------------- photometric


def color_transform(rng: np.random.Generator, cfg: dict, mean_rgb: np.ndarray) -> np.ndarray:
    """(3,4) affine colour transform: per-channel gain x brightness, saturation, contrast.

    ``cfg``: the ``color`` section (each amount a relative +- range); ``mean_rgb`` (3,): the
    image's mean colour (contrast scales around the mean grey level). Apply with
    ``cv2.transform`` (saturating uint8).
    """
    b, c, s, g = (float(cfg[k]) for k in ("brightness", "contrast", "saturation", "channel_gain"))
    gains = (1 + rng.uniform(-b, b)) * (1 + rng.uniform(-g, g, 3))
    sat = 1 + rng.uniform(-s, s)
    con = 1 + rng.uniform(-c, c)
    M = (sat * np.eye(3) + (1 - sat) / 3.0) @ np.diag(gains)
    grey_mean = float((M @ np.asarray(mean_rgb, np.float64)).mean())
    return np.concatenate([con * M, np.full((3, 1), (1 - con) * grey_mean)], 1).astype(np.float32)


_NOISE_BANK: np.ndarray | None = None


def _noise_bank() -> np.ndarray:
    """(512,512,3) float32 standard normal samples (fixed seed), sliced for pixel noise."""
    global _NOISE_BANK
    if _NOISE_BANK is None:
        _NOISE_BANK = np.random.default_rng(12345).standard_normal((512, 512, 3), np.float32)
    return _NOISE_BANK


def augment_crop(img: np.ndarray, rng: np.random.Generator, cfg: dict) -> np.ndarray:
    """Photometric augmentation of a composed crop (H,W,3) uint8 -> uint8: colour jitter, blur,
    Gaussian noise (the ``color``, ``blur``, ``noise`` sections of ``cfg``)."""
    if rng.random() < cfg["color"]["prob"]:
        img = cv2.transform(img, color_transform(rng, cfg["color"], cv2.mean(img)[:3]))
    if rng.random() < cfg["blur"]["prob"] and cfg["blur"]["sigma_max"] > 0:
        img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.3, cfg["blur"]["sigma_max"])))
    if rng.random() < cfg["noise"]["prob"] and cfg["noise"]["sigma_max"] > 0:
        sigma = np.float32(rng.uniform(0, cfg["noise"]["sigma_max"]))
        bank = _noise_bank()
        h, w = img.shape[:2]
        y = int(rng.integers(0, bank.shape[0] - h + 1))
        x = int(rng.integers(0, bank.shape[1] - w + 1))
        noisy = img.astype(np.float32)
        noisy += sigma * bank[y : y + h, x : x + w]
        img = np.clip(noisy, 0, 255, out=noisy).astype(np.uint8)
    return img


# ----------------------------------------------------------------------------- depth


def depth_noise(depth: np.ndarray, rng: np.random.Generator, cfg: dict) -> np.ndarray:
    """Sensor-like depth: Gaussian noise sigma = a + b z^2 (m), dropped pixels at depth edges,
    random elliptic holes. ``cfg``: the ``depth`` section. (H,W) float32 metres, 0 = missing."""
    d = depth.astype(np.float32).copy()
    valid = d > 0
    sig = cfg["noise_sigma"] + cfg["noise_sigma_quadratic"] * d * d
    d[valid] += rng.standard_normal(int(valid.sum()), dtype=np.float32) * sig[valid]
    d[valid] = np.maximum(d[valid], 1e-3)
    if cfg["edge_dropout"] > 0:
        gy = np.abs(np.diff(depth, axis=0, prepend=depth[:1]))
        gx = np.abs(np.diff(depth, axis=1, prepend=depth[:, :1]))
        edge = (np.maximum(gx, gy) > 0.02) & valid
        drop = edge & (rng.random(d.shape) < cfg["edge_dropout"])
        d[drop] = 0
    H, W = d.shape
    lo, hi = cfg["hole_size_range"]
    if cfg["hole_prob"] > 0 and hi > 0:
        r_mean = max(0.5 * (lo + hi), 0.5)
        n = rng.poisson(cfg["hole_prob"] * H * W / (np.pi * r_mean**2))
        holes = np.zeros((H, W), np.uint8)
        for _ in range(int(n)):
            cy, cx = int(rng.integers(0, H)), int(rng.integers(0, W))
            ax = (max(int(rng.uniform(lo, hi)), 1), max(int(rng.uniform(lo, hi)), 1))
            cv2.ellipse(holes, (cx, cy), ax, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        d[holes > 0] = 0
    return d
