"""chpf.atomic.npz_bytes: deterministic .npz bytes, stored or compressed member by member."""

from __future__ import annotations

import io
import zipfile

import numpy as np

from chpf.atomic import ZIP_METHODS, npz_bytes


def _depth_like() -> np.ndarray:
    """(64,32,32) float16 crops of a smooth surface on an empty (0) background, as a codebook's
    depth: the kind of array where bzip2 or lzma beat deflate."""
    yy, xx = np.mgrid[-1:1:32j, -1:1:32j]
    r = np.hypot(xx, yy)
    tilt = np.linspace(-0.02, 0.02, 64)[:, None, None]
    depth = 0.5 + tilt * xx - 0.03 * np.sqrt(np.clip(1 - r**2, 0, None))
    return np.where(r < 0.8, depth, 0.0).astype(np.float16)


def test_compressed_members_take_the_smallest_method_and_read_back() -> None:
    rng = np.random.default_rng(0)
    arrays = {"depth": _depth_like(), "emb": rng.normal(size=(64, 16)).astype(np.float32)}
    data = npz_bytes(arrays, compressed=True)
    assert data == npz_bytes({k: v.copy() for k, v in arrays.items()}, compressed=True)
    with np.load(io.BytesIO(data)) as z:
        for key, val in arrays.items():
            np.testing.assert_array_equal(z[key], val)
    infos = {i.filename: i for i in zipfile.ZipFile(io.BytesIO(data)).infolist()}
    assert {i.compress_type for i in infos.values()} <= set(ZIP_METHODS)
    for key, val in arrays.items():  # no method would have made the member smaller
        npy = io.BytesIO()
        np.lib.format.write_array(npy, val)
        for method in ZIP_METHODS:
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w", compression=method) as zf:
                zf.writestr(key + ".npy", npy.getvalue())
            assert infos[key + ".npy"].compress_size <= zf.infolist()[0].compress_size
    # the depth-like array is one where deflate alone (the usual savez_compressed) loses
    assert infos["depth.npy"].compress_type != zipfile.ZIP_DEFLATED


def test_stored_members_are_uncompressed() -> None:
    arrays = {"a": np.arange(10, dtype=np.int32), "b": _depth_like()}
    data = npz_bytes(arrays)
    assert {i.compress_type for i in zipfile.ZipFile(io.BytesIO(data)).infolist()} == {
        zipfile.ZIP_STORED
    }
    with np.load(io.BytesIO(data)) as z:
        np.testing.assert_array_equal(z["b"], arrays["b"])
