"""Typed errors of chpf. Every message is one line naming the file (if any) and the problem."""


class ChpfError(Exception):
    """Base class: a user-facing error; CLIs print it as one line and exit non-zero."""


class MeshError(ChpfError):
    """A mesh file is missing, unreadable, or has no faces."""


class BopFormatError(ChpfError):
    """A BOP JSON file is malformed or incomplete."""


class ResultsFormatError(ChpfError):
    """A BOP results CSV is malformed (columns, numbers, non-orthonormal R)."""


class ImageSizeError(ChpfError):
    """An image's size disagrees with its camera or with what the model expects."""


class RenderError(ChpfError):
    """No OpenGL platform works, or rendering failed."""


class BundleError(ChpfError):
    """A model bundle is missing files, has wrong hashes, or does not match the data."""


class ConfigError(ChpfError):
    """A config has an unknown key or an out-of-range value."""


class DatasetError(ChpfError):
    """A dataset or data folder is missing, incomplete, or made with another config."""


class OutputError(ChpfError):
    """An output folder cannot be written, is busy, or holds outputs of other settings."""


class InputError(ChpfError):
    """An input given to the API has the wrong type or form (e.g. a box given as text)."""


class SourceError(ChpfError):
    """A tracking input beyond BOP (image folder, video, camera file, box) is unreadable, empty
    or inconsistent with the frames."""
