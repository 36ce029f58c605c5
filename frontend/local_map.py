"""The tracker's map: landmarks with descriptors, keyframes, and their covisibility."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Keyframe:
    """A keyframe: its pose (camera to world) and the landmarks it observes."""

    id: int
    frame_index: int
    timestamp: float
    pose: np.ndarray
    landmark_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


class LandmarkMap:
    """Landmarks in growable arrays, indexed by their integer id, plus the keyframes seeing them."""

    def __init__(self, capacity: int = 4096):
        self.positions = np.zeros((capacity, 3))
        self.descriptors = np.zeros((capacity, 32), dtype=np.uint8)
        self.octave = np.zeros(capacity, dtype=np.int32)
        self.alive = np.zeros(capacity, dtype=bool)
        self.born = np.zeros(capacity, dtype=np.int64)  # frame index at which each landmark was mapped
        self.seen = np.zeros(capacity, dtype=np.int32)  # keyframes observing each landmark
        self.size = 0
        self.keyframes: dict[int, Keyframe] = {}
        self._observers: dict[int, set[int]] = {}

    def _grow(self, extra: int) -> None:
        need = self.size + extra
        if need <= len(self.alive):
            return
        cap = max(need, 2 * len(self.alive))
        for name in ("positions", "descriptors", "octave", "alive", "born", "seen"):
            old = getattr(self, name)
            new = np.zeros((cap,) + old.shape[1:], dtype=old.dtype)
            new[: self.size] = old[: self.size]
            setattr(self, name, new)

    def add_landmarks(self, positions: np.ndarray, descriptors: np.ndarray, octave: np.ndarray,
                      frame_index: int = 0) -> np.ndarray:
        """Store new landmarks mapped at frame ``frame_index`` and return their ids."""
        n = len(positions)
        self._grow(n)
        ids = np.arange(self.size, self.size + n, dtype=np.int64)
        self.positions[ids] = positions
        self.descriptors[ids] = descriptors
        self.octave[ids] = octave
        self.born[ids] = frame_index
        self.alive[ids] = True
        self.size += n
        return ids

    def add_keyframe(self, kf: Keyframe) -> None:
        """Register a keyframe and its observations for covisibility."""
        self.keyframes[kf.id] = kf
        for lid in kf.landmark_ids.tolist():
            observers = self._observers.setdefault(lid, set())
            if kf.id not in observers:
                observers.add(kf.id)
                self.seen[lid] += 1

    def retire(self, ids: list[int] | np.ndarray) -> None:
        """Stop using landmarks (culled by the back-end or seen moving)."""
        ids = np.asarray(ids, dtype=np.int64)
        if len(ids):
            self.alive[ids] = False

    def drop_observation(self, kf_id: int, lid: int) -> None:
        """Forget that a keyframe observes a landmark."""
        kf = self.keyframes.get(kf_id)
        if kf is not None:
            kf.landmark_ids = kf.landmark_ids[kf.landmark_ids != lid]
        observers = self._observers.get(lid, set())
        if kf_id in observers:
            observers.discard(kf_id)
            self.seen[lid] -= 1

    def most_observing(self, ids: np.ndarray) -> int | None:
        """The keyframe that observes most of the given landmarks, or None when none does."""
        counts: Counter[int] = Counter()
        for lid in ids.tolist():
            counts.update(self._observers.get(lid, ()))
        return counts.most_common(1)[0][0] if counts else None

    def covisible(self, kf_id: int, n: int) -> list[int]:
        """The ``n`` keyframes sharing most landmarks with ``kf_id``, itself first."""
        counts: Counter[int] = Counter()
        for lid in self.keyframes[kf_id].landmark_ids.tolist():
            counts.update(self._observers.get(lid, ()))
        counts.pop(kf_id, None)
        return [kf_id] + [k for k, _ in counts.most_common(max(0, n - 1))]

    def local_landmarks(self, kf_ids: list[int]) -> np.ndarray:
        """Ids of the live landmarks observed by any of the given keyframes."""
        if not kf_ids:
            return np.zeros(0, dtype=np.int64)
        ids = np.unique(np.concatenate([self.keyframes[k].landmark_ids for k in kf_ids]))
        return ids[self.alive[ids]]
