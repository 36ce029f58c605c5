"""TUM RGB-D and synthetic sequence readers, all yielding :class:`osslam.types.Frame`."""

from __future__ import annotations

from pathlib import Path

from osslam.config import Config
from osslam.errors import InputError

from .tum import TumSequence


def open_sequence(path: str | Path, cfg: Config) -> TumSequence:
    """Open a sequence folder on disk (TUM layout: rgb.txt, depth.txt, optional groundtruth.txt)."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "sequence folder not found")
    if not path.is_dir():
        raise InputError(path, "not a folder; expected a TUM sequence folder with rgb.txt and depth.txt")
    return TumSequence(path, cfg.dataset, cfg.camera)
