"""Errors that OS-SLAM reports to users as one line, naming the offending file."""

from __future__ import annotations

from pathlib import Path


class OsslamError(Exception):
    """Base class of every error the CLI reports without a traceback."""


class InputError(OsslamError):
    """Bad input data: a missing or unreadable file, a malformed line, an empty sequence."""

    def __init__(self, path: str | Path, message: str, line: int | None = None):
        self.path = str(path)
        self.line = line
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")
