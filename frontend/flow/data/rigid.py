"""Ground-truth flow of real or synthetic RGB-D sequences from depth and poses, occlusions found by a depth test."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from osslam.datasets.sequence import FrameSequence
from osslam.errors import InputError
from osslam.geometry import invert, transform_points
from osslam.imaging import values_at
from osslam.types import CameraIntrinsics, Frame

from .sample import FlowSample

#: Maps frame-1 pixels (N, 2) and their world points (N, 3) to world points at frame 2 (movers); None: static scene.
SceneMotion = Callable[[np.ndarray, np.ndarray], np.ndarray]


def rigid_flow(depth1: np.ndarray, depth2: np.ndarray, T_wc1: np.ndarray, T_wc2: np.ndarray,
               intrinsics: CameraIntrinsics, occlusion_tol: float = 0.05,
               motion: SceneMotion | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Flow (H, W, 2) from frame 1 to frame 2 of the scene points frame 1's depth sees, and its validity.

    Pixels are back-projected through the (distorted) camera, moved by the camera motion
    (and ``motion`` for points that move themselves), and projected into frame 2. A pixel
    is valid when it has depth, lands inside frame 2, and frame 2's depth there agrees with
    the point's depth within ``occlusion_tol`` (relative), i.e. it is not occluded.
    """
    h, w = depth1.shape
    v, u = np.mgrid[0:h, 0:w]
    has = depth1 > 0
    pix = np.column_stack([u[has], v[has]]).astype(np.float64)
    z = depth1[has].astype(np.float64)
    rays = intrinsics.normalized(pix)
    world = transform_points(T_wc1, np.column_stack([rays * z[:, None], z]))
    if motion is not None:
        world = motion(pix, world)
    cam2 = transform_points(invert(T_wc2), world)
    front = cam2[:, 2] > 1e-3
    proj = np.full((len(cam2), 2), -1.0)
    if front.any():
        proj[front] = intrinsics.project(cam2[front])
    inside = front & (proj[:, 0] >= 0) & (proj[:, 0] <= w - 1) & (proj[:, 1] >= 0) & (proj[:, 1] <= h - 1)
    seen = values_at(depth2, proj).astype(np.float64)
    visible = inside & (seen > 0) & (np.abs(seen - cam2[:, 2]) < occlusion_tol * cam2[:, 2])
    flow = np.zeros((h, w, 2), np.float32)
    valid = np.zeros((h, w), bool)
    flow[has] = (proj - pix).astype(np.float32)
    valid[has] = visible
    flow[~valid] = 0.0
    return flow, valid


class RigidFlowPairs:
    """Pairs (i, i + gap) of a sequence with ground-truth poses, with their rigid flow as :class:`FlowSample`.

    Pairs without a pose at either frame are left out. ``motion_of`` gives, for a pair of
    frames, the motion of points that move by themselves (a composite's movers).
    """

    def __init__(self, sequence: FrameSequence, gaps: tuple[int, ...] = (1,), occlusion_tol: float = 0.05,
                 motion_of: Callable[[Frame, Frame], SceneMotion | None] | None = None):
        self.sequence = sequence
        self.occlusion_tol = occlusion_tol
        self.motion_of = motion_of
        poses = _has_poses(sequence)
        self.pairs = [(i, i + g) for g in gaps for i in range(len(sequence) - g) if poses[i] and poses[i + g]]
        if not self.pairs:
            raise InputError(getattr(sequence, "path", "sequence"), "no frame pair has ground-truth poses at both ends")

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, k: int) -> FlowSample:
        i, j = self.pairs[k]
        a, b = self.sequence[i], self.sequence[j]
        motion = self.motion_of(a, b) if self.motion_of is not None else None
        flow, valid = rigid_flow(a.depth, b.depth, a.gt_pose, b.gt_pose, a.intrinsics, self.occlusion_tol, motion)
        return FlowSample(a.rgb, b.rgb, flow, valid, a.gt_mask)


def _has_poses(sequence: FrameSequence) -> list[bool]:
    """Whether each frame has a ground-truth pose, without reading its images where the sequence can tell."""
    gt = getattr(sequence, "groundtruth", None)
    stamps = getattr(sequence, "timestamps", None)
    if gt is not None and stamps is not None:
        return [gt.pose_at(float(t)) is not None for t in stamps]
    return [sequence[i].gt_pose is not None for i in range(len(sequence))]
