"""Comparing clouds: distance of each point to a reference cloud, the share farther than a threshold,
which points lie on movers rather than on the static scene, and the rigid registration of one
cloud onto another."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def distances_to(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Each point's distance to its nearest reference point."""
    if len(reference) == 0:
        return np.full(len(points), np.inf)
    dist, _ = cKDTree(reference).query(points, k=1, workers=-1)
    return dist


def fraction_farther(points: np.ndarray, reference: np.ndarray, threshold: float) -> float:
    """Share of ``points`` farther than ``threshold`` from every reference point (ghost points, for instance)."""
    if len(points) == 0:
        return 0.0
    return float((distances_to(points, reference) > threshold).mean())


def on_movers(points: np.ndarray, movers: np.ndarray, static: np.ndarray, radius: float) -> np.ndarray:
    """Which ``points`` lie within ``radius`` of a sample of the movers and nearer to it than to any static sample.

    ``movers`` and ``static`` are samples of what the sensor saw, split by ground-truth
    masks: a ghost point on a mover is residue the dynamic masks let through.
    """
    to_mover = distances_to(points, movers)
    return (to_mover <= radius) & (to_mover < distances_to(points, static))


def register(points: np.ndarray, reference: np.ndarray, max_distance: float) -> np.ndarray:
    """The rigid transform (4x4) that brings ``points`` onto ``reference``: point-to-plane ICP from the identity.

    Only pairs closer than ``max_distance`` count, so points farther off than that (a
    mover's residue, say) do not pull the result.
    """
    import open3d as o3d

    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(reference, np.float64)))
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05, max_nn=30))
    icp = o3d.pipelines.registration
    return icp.registration_icp(source, target, max_distance, np.eye(4),
                                icp.TransformationEstimationPointToPlane()).transformation
