"""Typed records exchanged between the front-end and the back-end."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class KeyframeObservations:
    """Everything the back-end learns about one new keyframe.

    ``landmark_ids``, ``uv``, ``depth`` and ``sigma_scale`` are parallel arrays, one entry
    per observation: pixel coordinates are undistorted, a depth of 0 or NaN means missing,
    and ``sigma_scale`` multiplies the pixel noise (the ORB octave scale). ``new_landmarks``
    holds the front-end's initial position of each landmark created at this keyframe; the
    back-end does not need it, because it re-triangulates a landmark from its most recent
    depth observation when the landmark enters the graph. ``moving_landmarks`` are those
    the front-end saw on moving objects since the previous keyframe; the back-end retires them.
    """

    keyframe_id: int
    pose_guess: np.ndarray
    landmark_ids: np.ndarray
    uv: np.ndarray
    depth: np.ndarray
    sigma_scale: np.ndarray
    new_landmarks: dict[int, np.ndarray] = field(default_factory=dict)
    moving_landmarks: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass
class BackendUpdate:
    """What one back-end update tells the front-end.

    ``poses`` holds the optimised ``T_world_camera`` of every keyframe in the graph;
    ``landmarks`` the optimised positions of the landmarks observed by the most recent
    keyframes (all landmarks after :meth:`IsamBackend.finish`). ``retired_landmarks`` must
    no longer be used; ``outlier_observations`` lists the (keyframe, landmark) pairs whose
    factors were removed as outliers. ``ok`` is False when the solver failed and the
    back-end recovered by dropping part of the new information.
    """

    poses: dict[int, np.ndarray]
    landmarks: dict[int, np.ndarray]
    retired_landmarks: list[int]
    outlier_observations: list[tuple[int, int]]
    n_factors: int
    n_landmarks: int
    ok: bool
    time_ms: float


@dataclass
class GraphEstimate:
    """The current estimate of every keyframe pose and landmark position in the graph."""

    poses: dict[int, np.ndarray]
    landmarks: dict[int, np.ndarray]
