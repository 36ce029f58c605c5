"""Camera intrinsics of a sequence: TUM's calibration by sensor, a camera.yaml, or the config."""

from __future__ import annotations

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

_SENSOR = re.compile(r"(?:freiburg|fr)([123])(?![0-9])", re.IGNORECASE)

CAMERA_FILE = "camera.yaml"


def sensor_from_name(name: str) -> str | None:
    """``freiburgN`` named by a sequence folder (``rgbd_dataset_freiburg1_xyz``, ``fr3_walking``), or None."""
    match = _SENSOR.search(name)
    return f"freiburg{match.group(1)}" if match else None


def read_camera_file(path: Path) -> CameraIntrinsics:
    """Intrinsics from a ``camera.yaml`` (fx, fy, cx, cy, width, height, dist)."""
    try:
        data = yaml.safe_load(path.read_text())
        dist = tuple(float(d) for d in data.get("dist", [0.0] * 5))
        if len(dist) != 5:
            raise ValueError("dist must have 5 entries")
        return CameraIntrinsics(float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]),
                                int(data.get("width", 640)), int(data.get("height", 480)), dist)
    except (yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(path, f"invalid camera file ({exc})") from None


def select_intrinsics(sequence_dir: Path, cfg: CameraConfig) -> CameraIntrinsics:
    """The intrinsics a sequence uses.

    ``camera.model`` decides: ``custom`` takes fx/fy/cx/cy/dist from the config,
    ``freiburg1/2/3`` TUM's calibration, and ``auto`` a ``camera.yaml`` in the folder if
    present, else the sensor named by the folder.
    """
    model = cfg.model.lower()
    if model == "custom":
        if min(cfg.fx, cfg.fy) <= 0:
            raise ConfigError("camera.model=custom needs camera.fx, camera.fy, camera.cx, camera.cy")
        if len(cfg.dist) != 5:
            raise ConfigError("camera.dist needs 5 coefficients (k1, k2, p1, p2, k3)")
        return CameraIntrinsics(cfg.fx, cfg.fy, cfg.cx, cfg.cy, dist=tuple(cfg.dist))
    if model in TUM_INTRINSICS:
        return TUM_INTRINSICS[model]
    if model != "auto":
        raise ConfigError(f"camera.model '{cfg.model}' unknown (auto, custom, {', '.join(TUM_INTRINSICS)})")
    camera_file = sequence_dir / CAMERA_FILE
    if camera_file.is_file():
        return read_camera_file(camera_file)
    sensor = sensor_from_name(sequence_dir.resolve().name)
    if sensor is None:
        raise InputError(sequence_dir, "cannot tell the camera from the folder name; set camera.model "
                                       "(freiburg1/2/3, or custom with camera.fx/fy/cx/cy)")
    return TUM_INTRINSICS[sensor]
