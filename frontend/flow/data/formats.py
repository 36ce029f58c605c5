"""Readers and writers of the standard flow files: Middlebury .flo, KITTI 16-bit PNG, PFM."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from osslam.errors import InputError

FLO_MAGIC = 202021.25
_KITTI_OFFSET = 2 ** 15
_KITTI_SCALE = 64.0


def read_flo(path: str | Path) -> np.ndarray:
    """Flow (H, W, 2) float32 from a Middlebury ``.flo`` file."""
    data = _read_bytes(path)
    if len(data) < 12 or np.frombuffer(data[:4], "<f4")[0] != np.float32(FLO_MAGIC):
        raise InputError(path, "not a .flo file (bad magic number)")
    w, h = (int(v) for v in np.frombuffer(data[4:12], "<i4"))
    if w <= 0 or h <= 0 or len(data) != 12 + 8 * w * h:
        raise InputError(path, f"truncated or corrupt .flo file ({w}x{h} header, {len(data)} bytes)")
    return np.frombuffer(data[12:], "<f4").reshape(h, w, 2).copy()


def write_flo(path: str | Path, flow: np.ndarray) -> None:
    """Write flow (H, W, 2) as a Middlebury ``.flo`` file."""
    h, w = flow.shape[:2]
    with open(path, "wb") as f:
        f.write(np.array([FLO_MAGIC], "<f4").tobytes())
        f.write(np.array([w, h], "<i4").tobytes())
        f.write(np.asarray(flow, "<f4").tobytes())


def read_kitti_flow(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Flow (H, W, 2) float32 and validity (H, W) bool from a KITTI 16-bit 3-channel PNG."""
    if not Path(path).is_file():
        raise InputError(path, "flow file not found")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.dtype != np.uint16 or raw.ndim != 3 or raw.shape[2] != 3:
        raise InputError(path, "not a KITTI flow PNG (16-bit, 3 channels)")
    rgb = raw[:, :, ::-1].astype(np.float32)
    flow = (rgb[:, :, :2] - _KITTI_OFFSET) / _KITTI_SCALE
    return flow, rgb[:, :, 2] > 0


def write_kitti_flow(path: str | Path, flow: np.ndarray, valid: np.ndarray) -> None:
    """Write flow and validity as a KITTI 16-bit PNG (flow quantised to 1/64 px)."""
    uv = np.clip(np.round(flow * _KITTI_SCALE + _KITTI_OFFSET), 0, 2 ** 16 - 1)
    rgb = np.dstack([uv, valid.astype(np.float64)]).astype(np.uint16)
    if not cv2.imwrite(str(path), rgb[:, :, ::-1]):
        raise InputError(path, "cannot write the PNG")


def read_pfm(path: str | Path) -> np.ndarray:
    """Image (H, W) or (H, W, 3) float32 from a PFM file, top row first."""
    data = _read_bytes(path)
    parts = data.split(b"\n", 3)
    if len(parts) < 4 or parts[0].strip() not in (b"PF", b"Pf"):
        raise InputError(path, "not a PFM file (header must start with PF or Pf)")
    channels = 3 if parts[0].strip() == b"PF" else 1
    try:
        w, h = (int(v) for v in parts[1].split())
        scale = float(parts[2])
    except ValueError:
        raise InputError(path, "corrupt PFM header") from None
    dtype = "<f4" if scale < 0 else ">f4"
    body = parts[3]
    if len(body) != 4 * w * h * channels:
        raise InputError(path, f"truncated PFM file ({w}x{h}x{channels} header, {len(body)} data bytes)")
    image = np.frombuffer(body, dtype).reshape(h, w, channels) if channels == 3 else np.frombuffer(body, dtype).reshape(h, w)
    return np.flipud(image).astype(np.float32)


def write_pfm(path: str | Path, image: np.ndarray) -> None:
    """Write an (H, W) or (H, W, 3) float image as little-endian PFM."""
    image = np.asarray(image, np.float32)
    header = b"PF\n" if image.ndim == 3 else b"Pf\n"
    with open(path, "wb") as f:
        f.write(header + f"{image.shape[1]} {image.shape[0]}\n-1\n".encode())
        f.write(np.flipud(image).astype("<f4").tobytes())


def read_flow(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Flow and validity from any of the formats, chosen by suffix (.flo, .png, .pfm)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".flo":
        flow = read_flo(path)
    elif suffix == ".png":
        return read_kitti_flow(path)
    elif suffix == ".pfm":
        flow = read_pfm(path)
        if flow.ndim != 3:
            raise InputError(path, "PFM flow needs 3 channels")
        flow = flow[:, :, :2]
    else:
        raise InputError(path, f"unknown flow format '{suffix}' (.flo, .png, .pfm)")
    return flow, np.all(np.isfinite(flow), axis=2) & (np.abs(flow).max(axis=2) < 1e9)


def read_image(path: str | Path) -> np.ndarray:
    """A colour image as uint8 RGB (H, W, 3)."""
    if not Path(path).is_file():
        raise InputError(path, "image not found")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(path, "cannot decode image (corrupt or not an image)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _read_bytes(path: str | Path) -> bytes:
    """The file's bytes; InputError naming it when missing."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise InputError(path, "flow file not found") from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror})") from None
