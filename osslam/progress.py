"""A one-line progress bar on a terminal; silent when output is not a terminal or in CI."""

from __future__ import annotations

import os
import sys
import time
from typing import TextIO


class Progress:
    """Shows ``done/total``, frames per second and a short status on one updating line."""

    def __init__(self, total: int, label: str = "", stream: TextIO | None = None, enabled: bool | None = None):
        self.total = total
        self.label = label
        self.stream = stream or sys.stderr
        if enabled is None:
            enabled = self.stream.isatty() and not os.environ.get("CI")
        self.enabled = enabled
        self._start = time.perf_counter()
        self._last_draw = 0.0

    def update(self, done: int, status: str = "") -> None:
        """Redraw the line (at most ten times a second, and always at the end)."""
        if not self.enabled:
            return
        now = time.perf_counter()
        if done < self.total and now - self._last_draw < 0.1:
            return
        self._last_draw = now
        width = 30
        filled = int(width * done / max(self.total, 1))
        rate = done / max(now - self._start, 1e-9)
        bar = "#" * filled + "-" * (width - filled)
        self.stream.write(f"\r{self.label} [{bar}] {done}/{self.total} {rate:5.1f} fps {status}\033[K")
        if done >= self.total:
            self.stream.write("\n")
        self.stream.flush()
