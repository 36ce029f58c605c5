"""Folders that appear whole or not at all: built beside their place, then renamed into it."""

from __future__ import annotations

import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def folder_aside(target: Path) -> Iterator[Path]:
    """A new temporary folder's path beside ``target`` (hidden, same file system), for the caller to build and rename.

    Whatever is left there when the block ends, renamed or not (a failed or interrupted build), is removed.
    """
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
