"""Two runs, one output (issue 24): a second `calbench simulate` or `calbench study` started on
the output another run is writing is refused at once with one line naming that run (the lock
beside the output, bench/core/outputs.py), and the output is the first run's, whole: a log that
reads with every planned pose, a study table with every campaign. (`montecarlo --json`:
tests/test_full_disk.py.)"""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import tempfile
from pathlib import Path

import badcases as bc
from conftest import wait_for_lock

from calbench.bench.log import read_log
from calbench.identify.cli import main

CALBENCH = [sys.executable, "-m", "calbench.identify.cli"]


def error_line(err: str) -> str:
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1, err
    return errors[0]


def first_and_second(argv_first: list[str], argv_second: list[str], out: Path) -> tuple[int, str]:
    """Start ``argv_first``, wait until it holds the lock of ``out``, run ``argv_second`` on the
    same output; returns (the first's exit status, the second's error line). The second verb runs
    once beforehand on a throwaway output, so that it runs with its modules imported while the
    first still writes, in the suite or alone."""
    with tempfile.TemporaryDirectory() as warm, contextlib.redirect_stderr(io.StringIO()):
        throwaway = str(Path(warm) / out.name)
        assert main([throwaway if a == str(out) else a for a in argv_second]) == 0
    first = subprocess.Popen([*CALBENCH, *argv_first], stderr=subprocess.PIPE, text=True)
    wait_for_lock(out, first)
    buf = io.StringIO()
    with contextlib.redirect_stderr(buf):  # in this process: no start-up time, the first still runs
        second = main(argv_second)
    still = first.poll() is None
    rc = first.wait(timeout=300)
    assert still and second == 2, buf.getvalue()
    err = error_line(buf.getvalue())
    assert f"calbench pid {first.pid} is writing it" in err and str(out) in err, err
    assert not out.with_name(f".{out.name}.lock").exists()
    return rc, err


def test_two_simulates_on_one_log(tmp_path):
    scn = tmp_path / "s.toml"
    scn.write_text(bc.scenario_text(n_poses=6, repeats=300))
    other = tmp_path / "other.toml"
    other.write_text(bc.scenario_text(n_poses=2))
    out = tmp_path / "l.mcap"
    rc, _ = first_and_second(
        ["simulate", str(scn), "--out", str(out)], ["simulate", str(other), "--out", str(out)], out
    )
    assert rc == 0
    log = read_log(out)
    assert log.complete_poses == list(range(6)) and not log.truncated
    assert len(log.measurements) == 6 * 2 * 300  # the first run's campaign, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.mcap", "other.toml", "s.toml"]


def test_two_studies_on_one_table(tmp_path):
    import pyarrow.parquet as pq

    (tmp_path / "s.toml").write_text(bc.scenario_text(n_poses=4))
    study = tmp_path / "study.toml"
    study.write_text(
        f'scenario = "{(tmp_path / "s.toml").as_posix()}"\nseeds = 10\n[[axis]]\nkey = "tracker.sigma"\nvalues = [2e-5]\n'
    )
    out = tmp_path / "r.parquet"
    argv = ["study", str(study), "--out", str(out), "--scheduler", "in-process"]
    rc, _ = first_and_second(argv, argv, out)
    assert rc == 0
    assert pq.read_table(out).num_rows == 10  # every campaign of the first run, once
