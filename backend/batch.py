"""The new factors and variables of one solver update."""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from .observations import Observation


@dataclass
class Batch:
    """Factors and initial values to add in one iSAM2 update.

    Each factor is tagged with the observation it encodes (None for pose factors), so a
    batch that made the solver fail can be pruned landmark by landmark.
    """

    factors: list[gtsam.NonlinearFactor] = field(default_factory=list)
    observations: list[Observation | None] = field(default_factory=list)
    poses: dict[int, gtsam.Pose3] = field(default_factory=dict)
    points: dict[int, np.ndarray] = field(default_factory=dict)

    def add(self, factor: gtsam.NonlinearFactor, obs: Observation | None = None) -> None:
        """Append a factor, tagged with its observation when it is one."""
        self.factors.append(factor)
        self.observations.append(obs)

    def values(self) -> gtsam.Values:
        """Initial values of the new variables: ``x`` keyframe poses and ``l`` landmark points."""
        values = gtsam.Values()
        for kf, pose in self.poses.items():
            values.insert(X(kf), pose)
        for lid, point in self.points.items():
            values.insertPoint3(L(lid), point)
        return values

    def landmarks(self) -> list[int]:
        """Landmarks with an observation factor in the batch, without repeats."""
        return list(dict.fromkeys(o.landmark_id for o in self.observations if o is not None))

    def without_landmark(self, lid: int) -> Batch:
        """A copy without the factors and initial value of landmark ``lid``."""
        keep = [i for i, o in enumerate(self.observations) if o is None or o.landmark_id != lid]
        points = {k: p for k, p in self.points.items() if k != lid}
        return Batch([self.factors[i] for i in keep], [self.observations[i] for i in keep], dict(self.poses), points)

    def without_observations(self) -> Batch:
        """A copy with only the pose variables and their prior or odometry factors."""
        keep = [i for i, o in enumerate(self.observations) if o is None]
        return Batch([self.factors[i] for i in keep], [None] * len(keep), dict(self.poses), {})
