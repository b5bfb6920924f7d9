"""Where ``chpf-track``'s frames come from: a BOP scene, a folder of images or a video.

Each source is a ``FrameSource`` (``chpf.sources.frame``): it announces its frame ids and yields
``SourceFrame``s (id, rgb, optional depth, K, optional box, time) one at a time, never holding
more than one frame in memory. ``chpf.sources.camera`` reads camera files and
``chpf.sources.open`` builds a source from the command line's ``--images`` / ``--video``.
"""
