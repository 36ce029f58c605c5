"""Motion-only pose refinement against known 3D points with RGB-D (virtual stereo) residuals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from osslam.geometry import orthonormalize, se3_exp

CHI2_STEREO = 7.815
CHI2_MONO = 5.991


@dataclass
class PoseEstimate:
    """A refined world-to-camera transform and which observations it explains."""

    T_cw: np.ndarray
    inliers: np.ndarray
    n_inliers: int


def _residuals(T_cw, points, uv, ur, has_depth, fx, fy, cx, cy, bf):
    pc = points @ T_cw[:3, :3].T + T_cw[:3, 3]
    z = pc[:, 2]
    zs = np.where(np.abs(z) < 1e-6, 1e-6, z)
    inv_z = 1.0 / zs
    u = fx * pc[:, 0] * inv_z + cx
    v = fy * pc[:, 1] * inv_z + cy
    res = np.zeros((len(points), 3))
    res[:, 0] = uv[:, 0] - u
    res[:, 1] = uv[:, 1] - v
    res[:, 2] = np.where(has_depth, ur - (u - bf * inv_z), 0.0)
    return pc, inv_z, res


def _jacobian(pc, inv_z, fx, fy, bf):
    """d(projection)/d(twist) for the left perturbation T <- exp(xi) T; rows u, v, uR."""
    x, y = pc[:, 0], pc[:, 1]
    iz2 = inv_z * inv_z
    d_proj = np.zeros((len(pc), 3, 3))
    d_proj[:, 0, 0] = fx * inv_z
    d_proj[:, 0, 2] = -fx * x * iz2
    d_proj[:, 1, 1] = fy * inv_z
    d_proj[:, 1, 2] = -fy * y * iz2
    d_proj[:, 2, 0] = fx * inv_z
    d_proj[:, 2, 2] = -(fx * x - bf) * iz2
    # d(pc)/d(xi) = [I | -[pc]x]
    d_pc = np.zeros((len(pc), 3, 6))
    d_pc[:, 0, 0] = d_pc[:, 1, 1] = d_pc[:, 2, 2] = 1.0
    d_pc[:, 0, 4], d_pc[:, 0, 5] = pc[:, 2], -pc[:, 1]
    d_pc[:, 1, 3], d_pc[:, 1, 5] = -pc[:, 2], pc[:, 0]
    d_pc[:, 2, 3], d_pc[:, 2, 4] = pc[:, 1], -pc[:, 0]
    return d_proj @ d_pc


def optimize_pose(
    T_cw: np.ndarray,
    points: np.ndarray,
    uv: np.ndarray,
    depth: np.ndarray,
    sigma2: np.ndarray,
    K: np.ndarray,
    baseline: float,
    rounds: int = 4,
    iterations: int = 10,
    start_inliers: np.ndarray | None = None,
) -> PoseEstimate:
    """Refine ``T_cw`` so that ``points`` project onto ``uv`` (and match ``depth`` where > 0).

    Robust Gauss-Newton with a Huber kernel; after each round observations whose chi-square
    exceeds the 95 % threshold (3 dof with depth, 2 without) are left out of the next round,
    as ORB-SLAM's pose optimisation does. ``start_inliers`` limits the first round to a
    consensus set found beforehand; later rounds judge every observation again.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    bf = fx * baseline
    has_depth = depth > 0
    ur = np.where(has_depth, uv[:, 0] - bf / np.where(has_depth, depth, 1.0), 0.0)
    info = 1.0 / sigma2
    chi2_max = np.where(has_depth, CHI2_STEREO, CHI2_MONO)
    delta = np.sqrt(chi2_max)
    T = T_cw.copy()
    inliers = np.ones(len(points), dtype=bool) if start_inliers is None else start_inliers.copy()
    for _ in range(rounds):
        for _ in range(iterations):
            if inliers.sum() < 3:
                break
            pc, inv_z, res = _residuals(T, points[inliers], uv[inliers], ur[inliers], has_depth[inliers], fx, fy, cx, cy, bf)
            J = _jacobian(pc, inv_z, fx, fy, bf)
            J[~has_depth[inliers], 2, :] = 0.0
            w_info = info[inliers]
            chi2 = (res**2).sum(axis=1) * w_info
            e = np.sqrt(chi2)
            d = delta[inliers]
            huber = np.where(e <= d, 1.0, d / np.maximum(e, 1e-12))
            w = (w_info * huber)[:, None, None]
            H = (J.transpose(0, 2, 1) @ (w * J)).sum(axis=0)
            g = (J.transpose(0, 2, 1) @ (w * res[:, :, None])).sum(axis=0)[:, 0]
            try:
                xi = np.linalg.solve(H + 1e-9 * np.eye(6), g)
            except np.linalg.LinAlgError:
                break
            T = orthonormalize(se3_exp(xi) @ T)
            if np.linalg.norm(xi) < 1e-8:
                break
        pc, _, res = _residuals(T, points, uv, ur, has_depth, fx, fy, cx, cy, bf)
        chi2 = (res**2).sum(axis=1) * info
        inliers = (chi2 < chi2_max) & (pc[:, 2] > 0)
    return PoseEstimate(T, inliers, int(inliers.sum()))
