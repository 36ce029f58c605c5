"""Rigid-body helpers on 4x4 homogeneous matrices."""

from __future__ import annotations

import cv2
import numpy as np


def pose_from_rvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """The 4x4 rigid transform of OpenCV's rotation vector and translation (as PnP solvers return them)."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = np.ravel(tvec)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform."""
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def skew(w: np.ndarray) -> np.ndarray:
    """The 3x3 cross-product matrix of a 3-vector."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (Rodrigues)."""
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-10:
        return np.eye(3) + W
    return np.eye(3) + np.sin(theta) / theta * W + (1.0 - np.cos(theta)) / theta**2 * (W @ W)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Rigid transform of a twist (translation part first, rotation second).

    The translation is applied directly (not through the SO(3) left Jacobian); for the
    small increments of an iterative solver both forms converge to the same optimum.
    """
    T = np.eye(4)
    T[:3, :3] = so3_exp(xi[3:])
    T[:3, 3] = xi[:3]
    return T


def rotation_angle_deg(T: np.ndarray) -> float:
    """Rotation angle of a transform, in degrees."""
    c = (np.trace(T[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a rigid transform to an (N, 3) array of points."""
    return points @ T[:3, :3].T + T[:3, 3]


def project_pinhole(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of camera-frame points (N, 3) through the pinhole ``K``; depths within 1e-6 of zero count as 1e-6."""
    z = np.where(np.abs(points[:, 2]) < 1e-6, 1e-6, points[:, 2])
    return points[:, :2] / z[:, None] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]


def row_lengths(d: np.ndarray) -> np.ndarray:
    """Euclidean lengths of the rows of ``d`` (N, 2), as ``np.linalg.norm(d, axis=1)`` gives them but faster."""
    sq = d * d
    return np.sqrt(sq[:, 0] + sq[:, 1])


def orthonormalize(T: np.ndarray) -> np.ndarray:
    """The nearest rigid transform (rotation projected onto SO(3)), so round-off never accumulates."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    out = T.copy()
    out[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out
