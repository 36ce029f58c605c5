"""Camera intrinsics of a sequence: TUM's calibration by sensor, a camera.yaml, or the config."""

from __future__ import annotations

import math
import re
from pathlib import Path

import yaml

from osslam.config import CameraConfig, ConfigError
from osslam.errors import InputError
from osslam.types import CameraIntrinsics

#: TUM's published calibration of the colour cameras (fx, fy, cx, cy, d0..d4), 640x480.
TUM_INTRINSICS: dict[str, CameraIntrinsics] = {
    "freiburg1": CameraIntrinsics(517.3, 516.5, 318.6, 255.3, 640, 480, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": CameraIntrinsics(520.9, 521.0, 325.1, 249.7, 640, 480, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "freiburg3": CameraIntrinsics(535.4, 539.2, 320.1, 247.6, 640, 480, (0.0, 0.0, 0.0, 0.0, 0.0)),
}

#: File in a sequence folder that states its intrinsics (written by the synthetic generator).
CAMERA_FILE = "camera.yaml"

# "freiburgN" anywhere in a name, or "frN" as a word of its own ("fr1_desk", "tum-fr3-walking").
_SENSOR = re.compile(r"freiburg([123])(?![0-9])|(?<![a-z0-9])fr([123])(?![0-9])", re.IGNORECASE)


def sensor_from_name(name: str) -> str | None:
    """The TUM sensor ``freiburgN`` a folder name names (``rgbd_dataset_freiburg1_xyz``, ``fr3_walking``), or None."""
    match = _SENSOR.search(name)
    return f"freiburg{match.group(1) or match.group(2)}" if match else None


def write_camera_file(folder: Path, intrinsics: CameraIntrinsics) -> Path:
    """Write ``folder/camera.yaml`` so that the folder's sequence carries its own intrinsics."""
    path = Path(folder) / CAMERA_FILE
    data = {"fx": intrinsics.fx, "fy": intrinsics.fy, "cx": intrinsics.cx, "cy": intrinsics.cy,
            "width": intrinsics.width, "height": intrinsics.height, "dist": list(intrinsics.dist)}
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def read_camera_file(path: Path) -> CameraIntrinsics:
    """Intrinsics from a ``camera.yaml`` with keys fx, fy, cx, cy, width, height and optional dist (5 values)."""
    try:
        data = yaml.safe_load(path.read_text())
        if not isinstance(data, dict):
            raise ValueError("expected a mapping of fx, fy, cx, cy, width, height, dist")
        missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in data]
        if missing:
            raise ValueError(f"missing {', '.join(missing)}")
        dist = tuple(float(d) for d in data.get("dist", [0.0] * 5))
        intrinsics = CameraIntrinsics(float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]),
                                      int(data["width"]), int(data["height"]), dist)
        _check(intrinsics)
        return intrinsics
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(path, "invalid YAML", line=mark.line + 1 if mark is not None else None) from None
    except (OSError, TypeError, ValueError) as exc:
        raise InputError(path, f"invalid camera file: {exc}") from None


def select_intrinsics(sequence_dir: Path, cfg: CameraConfig) -> CameraIntrinsics:
    """The intrinsics a sequence uses, decided by ``camera.model``.

    ``custom`` takes fx/fy/cx/cy/dist/width/height from the config, ``freiburg1/2/3``
    TUM's calibration, and ``auto`` the folder's ``camera.yaml`` if present, else the
    sensor the folder name names; InputError if it names none.
    """
    model = cfg.model.lower()
    if model == "custom":
        intrinsics = CameraIntrinsics(cfg.fx, cfg.fy, cfg.cx, cfg.cy, cfg.width, cfg.height,
                                      tuple(float(d) for d in cfg.dist))
        try:
            _check(intrinsics)
        except ValueError as exc:
            raise ConfigError(f"camera.model=custom: {exc} (set camera.fx, fy, cx, cy, width, height, dist)") from None
        return intrinsics
    if model in TUM_INTRINSICS:
        return TUM_INTRINSICS[model]
    if model != "auto":
        raise ConfigError(f"camera.model '{cfg.model}' unknown (auto, custom, {', '.join(TUM_INTRINSICS)})")
    camera_file = sequence_dir / CAMERA_FILE
    if camera_file.is_file():
        return read_camera_file(camera_file)
    sensor = sensor_from_name(sequence_dir.resolve().name)
    if sensor is None:
        raise InputError(sequence_dir, "cannot tell the camera from the folder name (no freiburg1/2/3 or "
                                       "fr1/2/3 in it) and there is no camera.yaml; set camera.model "
                                       "(freiburg1, freiburg2, freiburg3, or custom with camera.fx/fy/cx/cy)")
    return TUM_INTRINSICS[sensor]


def _check(intrinsics: CameraIntrinsics) -> None:
    """ValueError unless focal lengths and image size are positive and every value finite."""
    values = (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, *intrinsics.dist)
    if not all(math.isfinite(v) for v in values):
        raise ValueError("intrinsics must be finite numbers")
    if len(intrinsics.dist) != 5:
        raise ValueError(f"dist needs 5 coefficients (k1, k2, p1, p2, k3), got {len(intrinsics.dist)}")
    if intrinsics.fx <= 0 or intrinsics.fy <= 0:
        raise ValueError(f"fx and fy must be positive, got {intrinsics.fx:g} and {intrinsics.fy:g}")
    if intrinsics.width <= 0 or intrinsics.height <= 0:
        raise ValueError(f"width and height must be positive, got {intrinsics.width} and {intrinsics.height}")
