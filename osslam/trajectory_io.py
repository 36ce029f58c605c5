"""Reading and writing TUM trajectory files (``timestamp tx ty tz qx qy qz qw``, camera to world).

Reading validates every line and reports problems as :class:`osslam.errors.InputError`
naming the file and the line, so a bad file never reaches the metrics. Shared by the
system (results), the datasets (ground truth) and the evaluation.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from osslam.errors import InputError

log = logging.getLogger(__name__)

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"
TUM_FIELDS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
MIN_QUATERNION_NORM = 1e-8


@dataclass(frozen=True)
class TumTrajectory:
    """Timestamped camera-to-world poses: increasing timestamps, positions and unit quaternions (x, y, z, w)."""

    timestamps: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    name: str = ""

    def __len__(self) -> int:
        """Number of poses."""
        return int(self.timestamps.shape[0])

    @property
    def poses(self) -> np.ndarray:
        """The poses as an (N, 4, 4) array of ``T_world_camera`` matrices."""
        out = np.tile(np.eye(4), (len(self), 1, 1))
        out[:, :3, :3] = Rotation.from_quat(self.quaternions).as_matrix()
        out[:, :3, 3] = self.positions
        return out


def _parse_line(text: str, path: Path, line: int) -> list[float]:
    """The eight numbers of one data line, with a unit quaternion; InputError if the line is bad."""
    fields = text.split()
    if len(fields) != len(TUM_FIELDS):
        raise InputError(path, f"expected {len(TUM_FIELDS)} fields ({' '.join(TUM_FIELDS)}), got {len(fields)}",
                         line=line)
    values = []
    for name, field in zip(TUM_FIELDS, fields):
        try:
            value = float(field)
        except ValueError:
            raise InputError(path, f"{name} is not a number: {field!r}", line=line) from None
        if not math.isfinite(value):
            raise InputError(path, f"{name} is not finite: {field!r}", line=line)
        values.append(value)
    norm = math.sqrt(sum(q * q for q in values[4:]))
    if norm < MIN_QUATERNION_NORM:
        raise InputError(path, "quaternion has zero length and cannot be normalised", line=line)
    values[4:] = [q / norm for q in values[4:]]
    return values


def read_tum(path: str | Path) -> TumTrajectory:
    """Read and validate a TUM trajectory file; ``#`` comments and blank lines are skipped.

    Raises InputError for a missing or unreadable file, a malformed line (field count,
    non-numeric or non-finite value, zero quaternion), a timestamp that does not increase,
    and a file without poses. Quaternions are normalised to unit length.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found" if not path.exists() else "not a file")
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError:
        raise InputError(path, "not a text file") from None
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror}") from None
    rows: list[list[float]] = []
    previous_line = 0
    for number, text in enumerate(lines, start=1):
        text = text.strip()
        if not text or text.startswith("#"):
            continue
        values = _parse_line(text, path, number)
        if rows and values[0] <= rows[-1][0]:
            raise InputError(path, f"timestamp {values[0]:.6f} does not increase "
                             f"(line {previous_line} has {rows[-1][0]:.6f})", line=number)
        rows.append(values)
        previous_line = number
    if not rows:
        raise InputError(path, "no poses (the file has no data lines)")
    data = np.array(rows, dtype=np.float64)
    log.debug("read %d poses from %s", len(rows), path)
    return TumTrajectory(timestamps=data[:, 0], positions=data[:, 1:4], quaternions=data[:, 4:8], name=str(path))


def write_tum(path: str | Path, timestamps: Sequence[float] | np.ndarray,
              poses: Sequence[np.ndarray] | np.ndarray) -> Path:
    """Write ``T_world_camera`` poses with their timestamps as a TUM trajectory file.

    Timestamps get 6 decimals, translations and quaternions 9. An empty sequence writes
    only the header. Raises ValueError when the lengths differ, a pose is not 4x4, or a
    value is not finite.
    """
    path = Path(path)
    stamps = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    mats = np.asarray(poses, dtype=np.float64) if len(poses) else np.zeros((0, 4, 4))
    if mats.ndim != 3 or mats.shape[1:] != (4, 4):
        raise ValueError(f"poses must be 4x4 matrices, got an array of shape {mats.shape}")
    if stamps.shape[0] != mats.shape[0]:
        raise ValueError(f"{stamps.shape[0]} timestamps but {mats.shape[0]} poses")
    if not (np.isfinite(stamps).all() and np.isfinite(mats).all()):
        raise ValueError("timestamps and poses must be finite")
    lines = [TUM_HEADER]
    if len(stamps):
        quats = Rotation.from_matrix(mats[:, :3, :3]).as_quat()
        for t, T, q in zip(stamps, mats, quats):
            x, y, z = T[:3, 3]
            lines.append(f"{t:.6f} {x:.9f} {y:.9f} {z:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    path.write_text("\n".join(lines) + "\n")
    log.debug("wrote %d poses to %s", len(stamps), path)
    return path
