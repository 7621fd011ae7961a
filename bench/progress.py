"""A dependency-free progress bar on stderr, shown only on a terminal."""
from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, enabled: bool = True, width: int = 30):
        self.total = max(total, 1)
        self.done = 0
        self.enabled = enabled
        self.width = width
        self.t0 = time.perf_counter()

    def update(self, label: str = "", step: int = 1) -> None:
        self.done = min(self.done + step, self.total)
        if not self.enabled:
            return
        frac = self.done / self.total
        bar = "#" * int(frac * self.width)
        elapsed = time.perf_counter() - self.t0
        sys.stderr.write(f"\r[{bar:<{self.width}}] {self.done}/{self.total} {elapsed:5.1f}s {label:<40}")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()
