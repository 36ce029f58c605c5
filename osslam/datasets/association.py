"""TUM list files (``timestamp filename``) and nearest-timestamp association of colour and depth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from osslam.errors import InputError


@dataclass(frozen=True)
class StampedFiles:
    """Timestamps (strictly increasing) and file names read from a TUM list file such as ``rgb.txt``."""

    path: Path
    timestamps: np.ndarray
    files: list[str]


def read_file_list(path: str | Path) -> StampedFiles:
    """Read a TUM ``timestamp filename`` list; blank lines and ``#`` comments are skipped.

    Raises InputError naming the file (and the line) when it is missing, a line is
    malformed, a timestamp does not increase, or the list is empty.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found" if not path.exists() else "not a file")
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror}") from None
    stamps: list[float] = []
    files: list[str] = []
    for n, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.split()
        if len(parts) < 2:
            raise InputError(path, f"expected 'timestamp filename', got {text[:60]!r}", line=n)
        try:
            t = float(parts[0])
        except ValueError:
            raise InputError(path, f"timestamp {parts[0][:30]!r} is not a number", line=n) from None
        if not np.isfinite(t):
            raise InputError(path, f"timestamp {parts[0]!r} is not finite", line=n)
        if stamps and t <= stamps[-1]:
            raise InputError(path, f"timestamps must increase: {t:.6f} after {stamps[-1]:.6f}", line=n)
        stamps.append(t)
        files.append(parts[1])
    if not stamps:
        raise InputError(path, "no entries (only comments or blank lines)")
    return StampedFiles(path, np.asarray(stamps), files)


def associate(first: np.ndarray, second: np.ndarray, max_time_diff: float) -> list[tuple[int, int]]:
    """One-to-one index pairs ``(i, j)`` of nearest timestamps, ``|first[i] - second[j]| <= max_time_diff``.

    As TUM's ``associate.py``: candidate pairs are taken greedily by increasing time
    difference, each stamp used at most once. The result is sorted by ``i``.
    """
    if max_time_diff < 0:
        raise ValueError(f"max_time_diff must be >= 0, got {max_time_diff}")
    first = np.asarray(first, dtype=np.float64)
    second = np.asarray(second, dtype=np.float64)
    order = np.argsort(second, kind="stable")
    sorted_second = second[order]
    lo = np.searchsorted(sorted_second, first - max_time_diff, side="left")
    hi = np.searchsorted(sorted_second, first + max_time_diff, side="right")
    candidates: list[tuple[float, int, int]] = []
    for i in range(len(first)):
        for k in range(lo[i], hi[i]):
            diff = abs(first[i] - sorted_second[k])
            if diff <= max_time_diff:
                candidates.append((diff, i, int(order[k])))
    candidates.sort()
    used_first: set[int] = set()
    used_second: set[int] = set()
    pairs = []
    for _, i, j in candidates:
        if i not in used_first and j not in used_second:
            used_first.add(i)
            used_second.add(j)
            pairs.append((i, j))
    return sorted(pairs)
