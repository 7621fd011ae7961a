"""Progress lines for the benchmarks: one line per step on stderr with the elapsed time, so that
`make bench` is never silent for minutes; stdout stays the JSON result. Every benchmark takes
``--quick`` (`make bench QUICK=1`): the same measurements on fewer runs, seeds or candidates, to
see that they work, not to quote their figures."""

from __future__ import annotations

import sys
import time

_T0 = time.perf_counter()


def say(bench: str, text: str) -> None:
    print(f"[{bench} {time.perf_counter() - _T0:7.1f} s] {text}", file=sys.stderr, flush=True)


class LineProgress:
    """A progress sink (bench/core/progress.py's protocol) printing a step line every ``every``
    finished pieces, and the last one."""

    def __init__(self, bench: str, label: str, every_fraction: float = 0.1):
        self.bench, self.label, self.frac = bench, label, every_fraction
        self.total, self.done, self.next = 1, 0, 0

    def start(self, total: int, label: str = "") -> None:
        self.total, self.done = max(int(total), 1), 0
        self.next = max(1, int(self.total * self.frac))

    def update(self, label: str = "", step: int = 1) -> None:
        self.done += step
        if self.done >= self.next or self.done >= self.total:
            say(self.bench, f"{self.label} {min(self.done, self.total)}/{self.total}")
            self.next = self.done + max(1, int(self.total * self.frac))
