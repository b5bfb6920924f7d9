"""A scene of a BOP dataset as a frame source: its images, cameras, boxes and ground truth."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from chpf.bop import BopScene
from chpf.sources.frame import SourceFrame
from chpf.tracking.boxes import BoxSource
from chpf.tracking.warn import OnceWarner


class BopSceneFrames:
    """The frames of ``scene`` with the boxes of ``boxes`` for ``obj_id`` and its ground truth
    (a list of obj_ids: each object's, in ``SourceFrame.boxes`` / ``gts``);
    depth is read when ``want_depth`` (a missing depth image: RGB only, warned once through
    ``no_depth``). time = position / ``fps`` (BOP records no timestamps)."""

    def __init__(
        self,
        scene: BopScene,
        boxes: BoxSource,
        obj_id: int | Sequence[int],
        want_depth: bool,
        no_depth: OnceWarner,
        fps: float,
    ) -> None:
        self.scene = scene
        self.path = scene.path
        self.boxes = boxes
        self.obj_id = obj_id
        self.want_depth = want_depth
        self.no_depth = no_depth
        self.fps = float(fps)

    def frame_ids(self) -> list[int]:
        return self.scene.image_ids()

    def __iter__(self) -> Iterator[SourceFrame]:
        scene, sid = self.scene, self.scene.scene_id
        self.boxes.start_scene(scene)
        for pos, im in enumerate(scene.image_ids()):
            rgb = scene.rgb(im)
            depth = scene.depth(im) if self.want_depth else None
            if self.want_depth and depth is None:
                self.no_depth.warn(
                    f"{scene.depth_path(im)}: no depth image for scene {sid} image {im} "
                    "of an RGB-D run; tracked with RGB only"
                )
            ids = [self.obj_id] if isinstance(self.obj_id, int) else list(self.obj_id)
            boxes = {o: self.boxes.box(scene, im, o, rgb.shape[1], rgb.shape[0]) for o in ids}
            gts = {}
            for o in ids:
                gt = next((p for p in scene.gt.get(im, []) if p.obj_id == o), None)
                gts[o] = None if gt is None else (gt.R, gt.t)
            several = not isinstance(self.obj_id, int)
            yield SourceFrame(
                im,
                rgb,
                depth,
                scene.camera(im).K,
                boxes[ids[0]],
                pos / self.fps,
                f"scene {sid} image {im}",
                gts[ids[0]],
                boxes if several else None,
                gts if several else None,
            )
