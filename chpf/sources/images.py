"""A folder of image files (and optionally a folder of depth images) as a frame source."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

from chpf.bop import image_size, read_depth, read_rgb
from chpf.errors import DatasetError, SourceError
from chpf.sources.boxes import PlainBoxes, frame_boxes
from chpf.sources.camera import Camera
from chpf.sources.frame import SourceFrame
from chpf.tracking.warn import OnceWarner, SkippedFrameWarning

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def _natural_key(path: Path) -> list:
    """Sort key: numbers in a name compare as numbers (frame2 before frame10)."""
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", path.name)]


def list_images(folder: Path, what: str) -> list[Path]:
    """The image files of ``folder`` in natural order; SourceError when it is not a folder or
    holds none (``what`` names the option in the message)."""
    if not folder.is_dir():
        raise SourceError(f"{folder}: {what} folder not found")
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS]
    if not files:
        exts = ", ".join(IMAGE_EXTS)
        raise SourceError(f"{folder}: no image files ({exts}) in the {what} folder")
    return sorted(files, key=_natural_key)


def frame_ids(files: list[Path]) -> list[int]:
    """Frame ids: the file names' numbers when every name is a distinct number (BOP's
    000001.png -> 1), else the positions from 0."""
    stems = [p.stem for p in files]
    if all(s.isdigit() for s in stems) and len({int(s) for s in stems}) == len(stems):
        return [int(s) for s in stems]
    return list(range(len(files)))


def common_size(files: list[Path], folder: Path) -> tuple[int, int]:
    """(width, height) shared by the files (read from their headers; unreadable headers are left
    to the frame reader); SourceError naming two files of different sizes."""
    first: tuple[Path, tuple[int, int]] | None = None
    for p in files:
        hw = image_size(p)
        if hw is None:
            continue
        size = (int(hw[1]), int(hw[0]))
        if first is None:
            first = (p, size)
        elif size != first[1]:
            raise SourceError(
                f"{folder}: images of mixed sizes ({first[0].name} is "
                f"{first[1][0]}x{first[1][1]}, {p.name} is {size[0]}x{size[1]})"
            )
    if first is None:
        raise SourceError(f"{folder}: no readable image")
    return first[1]


class ImageFolder:
    """Sorted image files of ``path`` (module docstring of chpf.sources.frame); ``depth``: a
    folder with as many depth images (matched by position, depth_mm = raw * ``depth_scale``).

    Checked when built (SourceError naming the folder): no images, mixed sizes, a depth folder
    with another count or size, the camera's size. An unreadable image met while reading is
    skipped with one SkippedFrameWarning per run.
    """

    def __init__(
        self,
        path: str | Path,
        camera: Camera,
        boxes: PlainBoxes | dict[int, PlainBoxes],
        fps: float,
        depth: str | Path | None = None,
        depth_scale: float = 1.0,
    ) -> None:
        self.path = Path(path)
        self.camera = camera
        self.boxes = boxes
        self.fps = float(fps)
        self.depth_scale = float(depth_scale)
        self.files = list_images(self.path, "--images")
        self.ids = frame_ids(self.files)
        self.width, self.height = common_size(self.files, self.path)
        self.depth_files: list[Path] | None = None
        if depth is not None:
            dfolder = Path(depth)
            self.depth_files = list_images(dfolder, "--depth")
            if len(self.depth_files) != len(self.files):
                raise SourceError(
                    f"{dfolder}: {len(self.depth_files)} depth images but {len(self.files)} "
                    f"images in {self.path}"
                )
            dsize = common_size(self.depth_files, dfolder)
            if dsize != (self.width, self.height):
                raise SourceError(
                    f"{dfolder}: depth images are {dsize[0]}x{dsize[1]} but the images of "
                    f"{self.path} are {self.width}x{self.height}"
                )
        camera.check_size(self.width, self.height, self.path)

    @property
    def first_name(self) -> str:
        return str(self.files[0])

    def frame_ids(self) -> list[int]:
        return list(self.ids)

    def __iter__(self) -> Iterator[SourceFrame]:
        skipped = OnceWarner(SkippedFrameWarning)
        first = True
        for pos, (path, index) in enumerate(zip(self.files, self.ids, strict=True)):
            try:
                rgb = read_rgb(path)
                depth = None
                if self.depth_files is not None:
                    depth = read_depth(self.depth_files[pos], self.depth_scale)
            except DatasetError as err:
                skipped.warn(f"{err}; frame {index} skipped, the run goes on")
                continue
            if rgb.shape[:2] != (self.height, self.width) or (
                depth is not None and depth.shape != rgb.shape[:2]
            ):
                skipped.warn(
                    f"{path}: image is not {self.width}x{self.height}; frame {index} skipped, "
                    "the run goes on"
                )
                continue
            box, boxes = frame_boxes(self.boxes, index, first)
            first = False
            yield SourceFrame(
                index, rgb, depth, self.camera.K, box, pos / self.fps, str(path), None, boxes
            )
