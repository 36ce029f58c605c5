"""Book-keeping of landmarks: buffered observations, observation factors in the graph, retirements."""

from __future__ import annotations

import numpy as np

from .observations import Observation


class LandmarkBook:
    """Tracks which landmarks are in the graph and which solver factor holds each observation.

    A landmark's observations are buffered until it qualifies for the graph; from then on
    each observation is an observation factor identified by its iSAM2 factor index. For
    each factor the book keeps the measurement (u, v, depth; depth NaN when monocular) and
    the pixel-noise scale in arrays indexed by factor index, so residuals can be evaluated
    vectorised. Retired landmarks are remembered so later observations of them are ignored.
    """

    def __init__(self) -> None:
        self._pending: dict[int, list[Observation]] = {}
        self._pending_seen: dict[int, int] = {}
        self._by_landmark: dict[int, list[int]] = {}
        self._by_keyframe: dict[int, dict[int, int]] = {}
        self._bad: dict[int, int] = {}
        self._retired: set[int] = set()
        self._keyframe, self._landmark, self._measured, self._scale = _factor_arrays(0)

    # ------------------------------------------------------------------ pending observations

    def buffer(self, obs: Observation, seq: int) -> list[Observation]:
        """Buffer an observation of a landmark not yet in the graph; returns its buffered list."""
        pending = self._pending.setdefault(obs.landmark_id, [])
        pending.append(obs)
        self._pending_seen[obs.landmark_id] = seq
        return pending

    def take_pending(self, lid: int) -> list[Observation]:
        """Remove and return the buffered observations of a landmark."""
        self._pending_seen.pop(lid, None)
        return self._pending.pop(lid, [])

    def prune_pending(self, seq: int, max_age: int) -> None:
        """Forget buffered landmarks not observed in the last ``max_age`` keyframes."""
        stale = [lid for lid, last in self._pending_seen.items() if seq - last > max_age]
        for lid in stale:
            self.take_pending(lid)

    # ------------------------------------------------------------------ factors in the graph

    def in_graph(self, lid: int) -> bool:
        """Whether the landmark has at least one observation factor in the graph."""
        return lid in self._by_landmark

    def is_retired(self, lid: int) -> bool:
        """Whether the landmark was retired."""
        return lid in self._retired

    @property
    def n_landmarks(self) -> int:
        """Number of landmarks in the graph."""
        return len(self._by_landmark)

    def landmark_ids(self) -> list[int]:
        """Ids of the landmarks in the graph."""
        return list(self._by_landmark)

    def factor_indices(self) -> list[int]:
        """Solver indices of all observation factors in the graph."""
        return [i for indices in self._by_landmark.values() for i in indices]

    def add_factor(self, index: int, obs: Observation) -> None:
        """Record that solver factor ``index`` holds ``obs``."""
        if index >= len(self._keyframe):
            self._grow(index + 1)
        self._keyframe[index] = obs.keyframe_id
        self._landmark[index] = obs.landmark_id
        self._measured[index] = (obs.u, obs.v, obs.depth)
        self._scale[index] = obs.sigma_scale
        self._by_landmark.setdefault(obs.landmark_id, []).append(index)
        self._by_keyframe.setdefault(obs.keyframe_id, {})[obs.landmark_id] = index

    def remove_factor(self, index: int) -> tuple[int, int]:
        """Forget observation factor ``index``; returns its (keyframe id, landmark id)."""
        kf, lid = int(self._keyframe[index]), int(self._landmark[index])
        indices = self._by_landmark[lid]
        indices.remove(index)
        if not indices:
            del self._by_landmark[lid]
        del self._by_keyframe[kf][lid]
        return kf, lid

    def factors_of(self, lid: int) -> list[int]:
        """Solver indices of the landmark's observation factors."""
        return list(self._by_landmark.get(lid, ()))

    def has_depth_factor(self, lid: int) -> bool:
        """Whether any of the landmark's observation factors carries depth."""
        indices = self._by_landmark.get(lid, ())
        return bool(len(indices)) and not np.isnan(self._measured[indices, 2]).all()

    def record_outlier(self, lid: int) -> int:
        """Count one more outlier observation of the landmark; returns its count."""
        self._bad[lid] = self._bad.get(lid, 0) + 1
        return self._bad[lid]

    def retire(self, lid: int) -> list[int]:
        """Retire a landmark: forget its factors and buffered observations; returns the factor indices."""
        indices = self.factors_of(lid)
        for index in indices:
            self.remove_factor(index)
        self.take_pending(lid)
        self._bad.pop(lid, None)
        self._retired.add(lid)
        return indices

    def factor_arrays(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Keyframe ids, landmark ids, measurements (u, v, depth) and noise scales of factors."""
        return self._keyframe[indices], self._landmark[indices], self._measured[indices], self._scale[indices]

    def landmarks_seen_by(self, keyframe_ids: list[int]) -> list[int]:
        """Landmarks in the graph observed by any of the keyframes, without repeats."""
        seen: dict[int, None] = {}
        for kf in keyframe_ids:
            seen.update(dict.fromkeys(self._by_keyframe.get(kf, ())))
        return list(seen)

    def remap(self, old_to_new: dict[int, int]) -> None:
        """Renumber the observation factors after the solver was rebuilt."""
        old = np.fromiter(old_to_new.keys(), dtype=np.int64, count=len(old_to_new))
        new = np.fromiter(old_to_new.values(), dtype=np.int64, count=len(old_to_new))
        fresh = _factor_arrays(int(new.max()) + 1 if len(new) else 0)
        for target, source in zip(fresh, (self._keyframe, self._landmark, self._measured, self._scale)):
            target[new] = source[old]
        self._keyframe, self._landmark, self._measured, self._scale = fresh
        self._by_landmark = {lid: [old_to_new[i] for i in indices] for lid, indices in self._by_landmark.items()}
        self._by_keyframe = {kf: {lid: old_to_new[i] for lid, i in seen.items()}
                             for kf, seen in self._by_keyframe.items()}

    def forget_all(self) -> None:
        """Drop every landmark from the graph without retiring it (they may re-enter later)."""
        self._by_landmark.clear()
        self._by_keyframe.clear()
        self._bad.clear()

    def _grow(self, size: int) -> None:
        """Enlarge the per-factor arrays to hold at least ``size`` entries."""
        n = len(self._keyframe)
        fresh = _factor_arrays(max(size, 2 * n, 1024))
        for target, source in zip(fresh, (self._keyframe, self._landmark, self._measured, self._scale)):
            target[:n] = source
        self._keyframe, self._landmark, self._measured, self._scale = fresh


def _factor_arrays(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Empty per-factor arrays: keyframe ids, landmark ids, measurements (u, v, depth), noise scales."""
    return (np.full(n, -1, dtype=np.int64), np.full(n, -1, dtype=np.int64), np.full((n, 3), np.nan), np.ones(n))
