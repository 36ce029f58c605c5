"""Small typed records passed between the stages of the pipeline.

Conventions used everywhere in OS-SLAM:

* A pose is a 4x4 ``float64`` homogeneous matrix ``T_world_camera`` (camera to world),
  the convention of TUM ground truth files.
* Colour images are ``uint8`` arrays of shape (H, W, 3) in RGB order.
* Depth images are ``float32`` arrays of shape (H, W) in metres; 0 means no measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from osslam.geometry import project_pinhole


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole camera with OpenCV's five-parameter radial-tangential distortion."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int = 640
    height: int = 480
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def K(self) -> np.ndarray:
        """The 3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion coefficients (k1, k2, p1, p2, k3) as OpenCV expects them."""
        return np.asarray(self.dist, dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        """Whether any distortion coefficient is non-zero."""
        return any(abs(d) > 0.0 for d in self.dist)

    def undistort(self, pixels: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of the distorted image mapped to the ideal pinhole image."""
        pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion:
            return pixels.copy()
        import cv2

        return cv2.undistortPoints(pixels.reshape(-1, 1, 2), self.K, self.dist_coeffs, P=self.K).reshape(-1, 2)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) in the distorted image of camera-frame points (N, 3) in front of the camera."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not self.has_distortion:
            return project_pinhole(points, self.K)
        k1, k2, p1, p2, k3 = self.dist  # OpenCV's model, as cv2.projectPoints applies it
        x, y = points[:, 0] / points[:, 2], points[:, 1] / points[:, 2]
        xy, x2, y2 = x * y, x * x, y * y
        r2 = x2 + y2
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2)
        yd = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy
        return np.column_stack([self.fx * xd + self.cx, self.fy * yd + self.cy])

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) of undistorted pixels (N, 2) at their depths (N,) in metres."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        return np.column_stack([(uv[:, 0] - self.cx) / self.fx * z, (uv[:, 1] - self.cy) / self.fy * z, z])

    def normalized(self, pixels: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates (x/z, y/z) of pixels (N, 2): the viewing rays."""
        return (self.undistort(pixels) - [self.cx, self.cy]) / [self.fx, self.fy]


def kinect_depth_sigma(z: np.ndarray) -> np.ndarray:
    """Standard deviation (metres) of Kinect-like depth noise at depth ``z``, growing with z squared."""
    return 0.0012 + 0.0019 * np.square(z - 0.4)


@dataclass
class Frame:
    """One RGB-D frame: colour, depth, timestamp, intrinsics and optional ground truth."""

    index: int
    timestamp: float
    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: CameraIntrinsics
    gt_pose: np.ndarray | None = None
    source: str = ""
    gt_mask: np.ndarray | None = None  # (H, W) bool, pixels of moving objects, when the sequence has masks


@dataclass
class TrackingResult:
    """What the system reports for one tracked frame."""

    timestamp: float
    pose: np.ndarray
    state: str
    is_keyframe: bool
    n_features: int
    n_matches: int
    n_inliers: int
    timings_ms: dict[str, float] = field(default_factory=dict)
    mask: np.ndarray | None = None  # the pixels this frame ignored (caller's mask and gating), if any


@dataclass
class StampedPose:
    """A timestamped camera-to-world pose."""

    timestamp: float
    pose: np.ndarray
