"""Progress of long work, kept apart from the work itself: the one place calbench shows it.

Library functions take an optional ``progress`` object and call ``start(total)`` once, then
``update(label)`` per finished piece; they never print. The command line passes a
:class:`Progress` on stderr: on a terminal a tqdm bar; anywhere else (a pipe, a file, CI) a
line every EVERY_S seconds (CALBENCH_PROGRESS_S in the environment), ``calbench montecarlo: 120/1000 runs (12 %), 8.1/s, about 1.82 min
left``, and one when the work ends, so a ten-minute run is never silent. Notebooks and tests
pass nothing (or any object with these two methods). A label of the form ``"... | worker: n,
..."`` (the Dask runs' per-worker counts) is shown as it is.
"""

from __future__ import annotations

import math
import os
import sys
import time
from typing import Protocol

EVERY_S = 5.0  # seconds between two progress lines off a terminal


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


def duration(seconds: float) -> str:
    """A duration in the largest unit that keeps it readable (s, min, h, days, years)."""
    if not math.isfinite(seconds):
        return "forever"
    for unit, s in (("years", 365.25 * 86400), ("days", 86400), ("h", 3600), ("min", 60)):
        if seconds >= 2 * s:
            v = seconds / s
            return f"{v:,.0f} {unit}" if v >= 100 else f"{v:.3g} {unit}"
    return f"{seconds:.3g} s"


class Progress:
    """Progress on a stream (default stderr): a tqdm bar when it is a terminal (``tty``;
    default: ask the stream), else a line every ``every`` seconds and at :meth:`close`.
    ``name`` starts each line (e.g. ``calbench montecarlo``), ``unit`` names the pieces."""

    def __init__(
        self,
        total: int = 1,
        enabled: bool = True,
        stream=None,
        *,
        name: str = "calbench",
        unit: str = "pieces",
        tty: bool | None = None,
        every: float = EVERY_S,
        clock=time.monotonic,
    ):
        self.total = max(int(total), 1)
        self.done = 0
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.name, self.unit, self.every, self.clock = name, unit, every, clock
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)()) if tty is None else tty
        self.t0 = self.last = clock()
        self.label = ""
        self.lines = 0
        self._bar = None

    def start(self, total: int, label: str = "") -> None:
        """(Re)start for ``total`` pieces."""
        self._close_bar()
        self.total = max(int(total), 1)
        self.done = 0
        self.t0 = self.last = self.clock()
        self.label = label
        if self.enabled and self.tty:
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, desc=label or self.name, unit=self.unit, file=self.stream)

    def update(self, label: str = "", step: int = 1) -> None:
        self.done = min(self.done + step, self.total)
        self.label = label or self.label
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(step)
            if label:
                self._bar.set_postfix_str(label, refresh=False)
            return
        now = self.clock()
        if now - self.last >= self.every:
            self.last = now
            self._line()

    def line(self) -> str:
        """``name: done/total unit (pct), rate, about T left[; label]``."""
        elapsed = max(self.clock() - self.t0, 1e-9)
        rate = self.done / elapsed
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        when = f"about {duration(left)} left" if left != float("inf") else "time left unknown"
        if self.done >= self.total:
            when = f"done in {duration(elapsed)}"
        text = (
            f"{self.name}: {self.done}/{self.total} {self.unit} ({100 * self.done / self.total:.0f} %), "
            f"{rate:.3g}/s, {when}"
        )
        extra = self.label.split(" | ", 1)[1] if " | " in self.label else ""
        return f"{text}; {extra}" if extra else text

    def _line(self) -> None:
        self.stream.write(self.line() + "\n")
        self.stream.flush()
        self.lines += 1

    def _close_bar(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def close(self) -> None:
        """End the bar; off a terminal, a last line when any was written (long work only)."""
        if self._bar is not None:
            self._close_bar()
        elif self.enabled and self.lines:
            self._line()


def terminal_progress(name: str = "calbench", unit: str = "pieces") -> Progress:
    """What the command line shows on stderr: a bar on a terminal, lines elsewhere, every
    CALBENCH_PROGRESS_S seconds (environment; default EVERY_S)."""
    try:
        every = float(os.environ.get("CALBENCH_PROGRESS_S", EVERY_S))
    except ValueError:
        every = EVERY_S
    return Progress(name=name, unit=unit, every=every)


__all__ = ["EVERY_S", "ProgressSink", "Silent", "sink", "duration", "Progress", "terminal_progress"]
