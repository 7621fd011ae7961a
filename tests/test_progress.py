"""Progress everywhere (bench/core/progress.py): a tqdm bar on a terminal, elsewhere a line on
stderr every few seconds with done/total, the rate and the time left, so that a long
`calbench montecarlo` piped into a file or run in CI is never silent."""

from __future__ import annotations

import io
import os
import subprocess
import sys

from conftest import PAPER

from calbench.bench.core import Progress, duration


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_off_a_terminal_a_line_every_few_seconds_with_rate_and_time_left():
    out, clock = io.StringIO(), Clock()
    bar = Progress(stream=out, name="calbench montecarlo", unit="runs", tty=False, every=5.0, clock=clock)
    bar.start(100, "Monte Carlo")
    for _ in range(10):  # 10 runs a second: a line after 5 s and after 10 s
        clock.t += 1.0
        bar.update("", step=10)
    lines = out.getvalue().splitlines()
    assert lines[0] == "calbench montecarlo: 50/100 runs (50 %), 10/s, about 5 s left"
    assert lines[1] == "calbench montecarlo: 100/100 runs (100 %), 10/s, done in 10 s"
    bar.close()
    assert len(out.getvalue().splitlines()) == 3  # and the last one at the end


def test_short_work_off_a_terminal_says_nothing_and_per_worker_counts_are_shown():
    out, clock = io.StringIO(), Clock()
    bar = Progress(stream=out, tty=False, every=5.0, clock=clock)
    bar.start(4)
    clock.t = 1.0
    bar.update("runs 2/4 | pieces per worker: w1 1, w2 1", step=2)
    bar.close()
    assert out.getvalue() == ""  # done before the first line was due
    assert bar.line().endswith("; pieces per worker: w1 1, w2 1")
    assert duration(59.6) == "59.6 s" and duration(3725) == "62.1 min" and duration(4) == "4 s"


def test_on_a_terminal_a_tqdm_bar():
    out = io.StringIO()
    bar = Progress(stream=out, name="calbench study", unit="campaigns", tty=True)
    bar.start(8, "campaigns")
    bar.update("cell 3", step=8)
    bar.close()
    text = out.getvalue()
    assert "8/8" in text and "campaigns" in text and "cell 3" in text


def test_montecarlo_with_stderr_piped_prints_progress_lines():
    env = dict(os.environ, CALBENCH_PROGRESS_S="0")  # a line per finished block of 50 runs
    r = subprocess.run(
        [sys.executable, "-m", "calbench.identify.cli", "montecarlo", str(PAPER), "--runs", "100"]
        + ["--method", "one-step", "--scheduler", "in-process"],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    lines = [x for x in r.stderr.splitlines() if x.startswith("calbench montecarlo: ") and "/100 runs" in x]
    assert lines[0].startswith("calbench montecarlo: 50/100 runs (50 %), ") and "left" in lines[0], lines
    assert lines[-1].startswith("calbench montecarlo: 100/100 runs (100 %), ") and "done in" in lines[-1]
    assert "\r" not in r.stderr  # no bar drawn into a pipe
