"""Progress of long work, kept apart from the work itself.

Library functions take an optional ``progress`` object and call ``start(total)`` once, then
``update(label)`` per finished piece; they never print. The command line passes a
:class:`Progress`, a dependency-free bar on stderr shown only on a terminal; notebooks and
tests pass nothing (or any object with these two methods).
"""

from __future__ import annotations

import sys
import time
from typing import Protocol


class ProgressSink(Protocol):
    def start(self, total: int, label: str = "") -> None: ...
    def update(self, label: str = "", step: int = 1) -> None: ...


class Silent:
    """A sink that shows nothing."""

    def start(self, total: int, label: str = "") -> None:
        pass

    def update(self, label: str = "", step: int = 1) -> None:
        pass


def sink(progress: ProgressSink | None | bool) -> ProgressSink:
    """``progress`` itself, or a silent sink for None/False."""
    return progress if progress else Silent()


class Progress:
    """A text bar on stderr: ``[#####     ] 12/30   4.1s label``."""

    def __init__(self, total: int = 1, enabled: bool = True, width: int = 30, stream=None):
        self.total = max(total, 1)
        self.done = 0
        self.enabled = enabled
        self.width = width
        self.stream = stream or sys.stderr
        self.t0 = time.perf_counter()

    def start(self, total: int, label: str = "") -> None:
        """(Re)start the bar for ``total`` pieces."""
        self.total = max(int(total), 1)
        self.done = 0
        self.t0 = time.perf_counter()
        if label:
            self._draw(label)

    def update(self, label: str = "", step: int = 1) -> None:
        self.done = min(self.done + step, self.total)
        self._draw(label)

    def _draw(self, label: str) -> None:
        if not self.enabled:
            return
        frac = self.done / self.total
        bar = "#" * int(frac * self.width)
        elapsed = time.perf_counter() - self.t0
        self.stream.write(f"\r[{bar:<{self.width}}] {self.done}/{self.total} {elapsed:5.1f}s {label:<40}")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()


def terminal_progress() -> Progress:
    """The bar the command line uses: shown when stderr is a terminal."""
    return Progress(enabled=sys.stderr.isatty())


__all__ = ["ProgressSink", "Silent", "sink", "Progress", "terminal_progress"]
