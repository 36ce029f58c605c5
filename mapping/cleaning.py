"""Cleaning the fused cloud (paper §3.4): statistical outlier removal, then the KD-tree residue step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from osslam.config import MappingConfig

from .fusion import FusedCloud


@dataclass
class CleaningReport:
    """How many points each cleaning step removed."""

    removed_sor: int
    removed_residue: int


def statistical_outlier_mask(points: np.ndarray, neighbors: int, std_ratio: float) -> np.ndarray:
    """Open3D's statistical outlier removal as a keep-mask.

    A point goes when its mean distance to its ``neighbors`` nearest points exceeds the
    mean over the cloud by more than ``std_ratio`` standard deviations.
    """
    import open3d as o3d

    if neighbors <= 0 or len(points) <= neighbors:
        return np.ones(len(points), bool)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    _, kept = pcd.remove_statistical_outlier(nb_neighbors=neighbors, std_ratio=std_ratio)
    keep = np.zeros(len(points), bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    return keep


def mean_neighbor_distance(points: np.ndarray, neighbors: int) -> np.ndarray:
    """Each point's mean distance to its ``neighbors`` nearest other points (KD-tree)."""
    k = min(neighbors, len(points) - 1)
    if k < 1:
        return np.zeros(len(points))
    dist, _ = cKDTree(points).query(points, k=k + 1, workers=-1)
    return dist[:, 1:].mean(axis=1)


def residue_mask(points: np.ndarray, support: np.ndarray, near_dynamic: np.ndarray, min_support: int,
                 cluster_radius: float, neighbors: int, std_ratio: float) -> np.ndarray:
    """Keep-mask of the residue step: sparse, weakly supported clusters (moving-object residue) go.

    Points near a dynamic mask (``near_dynamic``) and seen by fewer than ``min_support``
    views are linked into clusters by a KD-tree radius graph (``cluster_radius``).
    Mean neighbour distances over the whole cloud are taken as Gaussian; a cluster whose
    mean lies more than ``std_ratio`` standard deviations above the cloud's mean (below
    it, for a negative ratio) is residue and removed.
    """
    keep = np.ones(len(points), bool)
    weak = np.flatnonzero((support < min_support) & near_dynamic)
    if min_support <= 0 or len(weak) == 0 or len(points) <= neighbors:
        return keep
    spacing = mean_neighbor_distance(points, neighbors)
    limit = spacing.mean() + std_ratio * spacing.std()
    pairs = cKDTree(points[weak]).query_pairs(cluster_radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(weak), len(weak)))
    n_clusters, labels = connected_components(graph, directed=False)
    cluster_spacing = np.bincount(labels, spacing[weak], n_clusters) / np.bincount(labels, minlength=n_clusters)
    keep[weak[cluster_spacing[labels] > limit]] = False
    return keep


def clean(cloud: FusedCloud, cfg: MappingConfig) -> tuple[FusedCloud, CleaningReport]:
    """Statistical outlier removal, then the residue step, with the counts each removed."""
    sor = statistical_outlier_mask(cloud.points, cfg.sor_neighbors, cfg.sor_std_ratio)
    cloud_sor = cloud.select(sor)
    res = residue_mask(cloud_sor.points, cloud_sor.support, cloud_sor.near_dynamic, cfg.residue_min_support,
                       cfg.residue_cluster_radius, cfg.residue_neighbors, cfg.residue_std_ratio)
    return cloud_sor.select(res), CleaningReport(int((~sor).sum()), int((~res).sum()))
