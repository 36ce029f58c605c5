"""Per-stage wall-clock timings and their summary statistics, and a process's peak memory."""

from __future__ import annotations

import resource
from collections import defaultdict

import numpy as np


class StageTimer:
    """Collects milliseconds per stage, one sample per frame the stage ran in."""

    def __init__(self) -> None:
        self._samples: dict[str, list[float]] = defaultdict(list)
        self._frames = 0

    def add(self, timings_ms: dict[str, float]) -> None:
        """Record the stage timings of one frame."""
        self._frames += 1
        for stage, ms in timings_ms.items():
            self._samples[stage].append(float(ms))

    def summary(self) -> dict[str, dict[str, float]]:
        """Per stage: count, mean, median, p95, max, and mean per frame (amortised over all frames)."""
        out = {}
        for stage, values in self._samples.items():
            a = np.asarray(values)
            out[stage] = {
                "count": int(a.size),
                "mean": float(a.mean()),
                "median": float(np.median(a)),
                "p95": float(np.percentile(a, 95)),
                "max": float(a.max()),
                "per_frame": float(a.sum() / max(self._frames, 1)),
            }
        return out


def peak_rss_mb() -> float:
    """This process's peak resident memory so far, in MB (one decimal)."""
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
