"""Vectorised reprojection geometry of the virtual stereo camera: back-projection and chi-square."""

from __future__ import annotations

import numpy as np

from osslam.types import CameraIntrinsics


def backproject(T_wc: np.ndarray, u: float, v: float, depth: float, intrinsics: CameraIntrinsics) -> np.ndarray:
    """World position of a pixel with depth seen from camera pose ``T_wc``."""
    p_c = intrinsics.backproject(np.array([[u, v]]), np.array([depth]))[0]
    return T_wc[:3, :3] @ p_c + T_wc[:3, 3]


def camera_depths(T_wc: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Depth (camera z) of each point in its camera: ``T_wc`` (N, 4, 4), ``points`` (N, 3)."""
    return np.einsum("ni,ni->n", T_wc[:, :3, 2], points - T_wc[:, :3, 3])


def reprojection_chi2(T_wc: np.ndarray, points: np.ndarray, measured: np.ndarray, sigma: np.ndarray,
                      intrinsics: CameraIntrinsics, fx_baseline: float) -> np.ndarray:
    """Squared whitened reprojection errors, without the robust loss.

    ``T_wc`` (N, 4, 4) camera poses, ``points`` (N, 3) world positions, ``measured`` (N, 3)
    holding (uL, v, uR) with uR NaN for monocular observations, ``sigma`` (N,) pixel noise.
    Stereo rows sum three squared residuals, monocular rows two; points on or behind the
    camera plane get an infinite error.
    """
    p_c = np.einsum("nji,nj->ni", T_wc[:, :3, :3], points - T_wc[:, :3, 3])
    z = p_c[:, 2]
    in_front = z > 0.0
    inv_z = np.where(in_front, 1.0 / np.where(in_front, z, 1.0), 0.0)
    u_l = intrinsics.fx * p_c[:, 0] * inv_z + intrinsics.cx
    v = intrinsics.fy * p_c[:, 1] * inv_z + intrinsics.cy
    err = (u_l - measured[:, 0]) ** 2 + (v - measured[:, 1]) ** 2
    stereo = ~np.isnan(measured[:, 2])
    err[stereo] += (u_l[stereo] - fx_baseline * inv_z[stereo] - measured[stereo, 2]) ** 2
    chi2 = err / sigma**2
    chi2[~in_front] = np.inf
    return chi2
