"""Noise models and factors of the graph: RGB-D observations, the first-pose prior, odometry."""

from __future__ import annotations

import functools

import gtsam
import numpy as np

from osslam.config import BackendConfig
from osslam.types import CameraIntrinsics

from .observations import Observation


def to_pose3(T: np.ndarray) -> gtsam.Pose3:
    """A GTSAM pose from a 4x4 rigid transform, re-orthonormalising its rotation."""
    return gtsam.Pose3(gtsam.Rot3.ClosestTo(T[:3, :3]), np.ascontiguousarray(T[:3, 3], dtype=np.float64))


class FactorFactory:
    """Builds the factors of the graph with their noise models.

    An observation with depth becomes a ``GenericStereoFactor3D`` on a virtual stereo rig
    (right-camera column ``uR = uL - fx * baseline / depth``); one without depth becomes a
    ``GenericProjectionFactorCal3_S2``. Both use a Huber-robust isotropic pixel noise of
    ``pixel_sigma * sigma_scale`` and never throw on points behind the camera.
    """

    def __init__(self, intrinsics: CameraIntrinsics, cfg: BackendConfig, baseline: float):
        fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
        self.stereo_calibration = gtsam.Cal3_S2Stereo(fx, fy, 0.0, cx, cy, baseline)
        self.mono_calibration = gtsam.Cal3_S2(fx, fy, 0.0, cx, cy)
        self.fx_baseline = fx * baseline
        self._cfg = cfg
        self._robust = gtsam.noiseModel.mEstimator.Huber.Create(cfg.huber_k)
        self.pixel_noise = functools.lru_cache(maxsize=256)(self._pixel_noise)
        self._prior_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.prior_rotation_sigma] * 3 + [cfg.prior_translation_sigma] * 3))
        self._odometry_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.odometry_rotation_sigma] * 3 + [cfg.odometry_translation_sigma] * 3))

    def _pixel_noise(self, dim: int, sigma_scale: float) -> gtsam.noiseModel.Base:
        """The Huber-robust isotropic noise of a ``dim``-dimensional pixel measurement.

        Exposed as ``pixel_noise``, cached per (dim, scale): ORB octave scales repeat.
        """
        base = gtsam.noiseModel.Isotropic.Sigma(dim, self._cfg.pixel_sigma * sigma_scale)
        return gtsam.noiseModel.Robust.Create(self._robust, base)

    def observation(self, obs: Observation, pose_key: int, point_key: int) -> gtsam.NonlinearFactor:
        """A stereo factor when the observation has depth, a monocular projection factor otherwise."""
        if obs.has_depth:
            measured = gtsam.StereoPoint2(obs.u, obs.u - self.fx_baseline / obs.depth, obs.v)
            return gtsam.GenericStereoFactor3D(measured, self.pixel_noise(3, obs.sigma_scale), pose_key, point_key,
                                               self.stereo_calibration, False, False)
        return gtsam.GenericProjectionFactorCal3_S2(np.array([obs.u, obs.v]), self.pixel_noise(2, obs.sigma_scale),
                                                    pose_key, point_key, self.mono_calibration, False, False)

    def pose_prior(self, key: int, pose: gtsam.Pose3) -> gtsam.NonlinearFactor:
        """The tight prior that fixes the gauge at the first keyframe."""
        return gtsam.PriorFactorPose3(key, pose, self._prior_noise)

    def odometry(self, key_a: int, key_b: int, T_ab: gtsam.Pose3) -> gtsam.NonlinearFactor:
        """A loose relative-pose factor between consecutive keyframes."""
        return gtsam.BetweenFactorPose3(key_a, key_b, T_ab, self._odometry_noise)
