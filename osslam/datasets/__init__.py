"""TUM RGB-D and synthetic sequence readers, all yielding :class:`osslam.types.Frame`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from osslam.config import Config
from osslam.errors import InputError

from .sequence import FrameSequence
from .tum import TumSequence

__all__ = ["FORMATS", "FrameSequence", "TumSequence", "open_sequence"]

#: On-disk sequence formats: name -> (file that marks a folder as that format, reader).
FORMATS: dict[str, tuple[str, Callable[[Path, Config], FrameSequence]]] = {
    "tum": ("rgb.txt", lambda path, cfg: TumSequence(path, cfg.dataset, cfg.camera)),
}


def open_sequence(path: str | Path, cfg: Config) -> FrameSequence:
    """Open a sequence folder with the reader of the first format in :data:`FORMATS` it matches.

    TUM (rgb.txt, depth.txt, optional groundtruth.txt) is the only format. Raises
    InputError for a path that does not exist, is not a folder, or matches no format.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "sequence folder not found")
    if not path.is_dir():
        raise InputError(path, "not a folder; expected a TUM sequence folder with rgb.txt and depth.txt")
    for marker, reader in FORMATS.values():
        if (path / marker).is_file():
            return reader(path, cfg)
    raise InputError(path, "not a sequence folder: no rgb.txt (a TUM sequence has rgb.txt and depth.txt)")
