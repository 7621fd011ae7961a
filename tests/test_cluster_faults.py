"""Cluster faults (issue 24): a Dask worker killed (SIGKILL) in the middle of a study or a Monte
Carlo, and the scheduler lost mid-study.

A killed worker's tasks are rescheduled by Dask on the others; calbench's tasks are idempotent
and derive their random streams from (seed, key) alone (identify/runtime/executor.py), so the
run finishes with the numbers of an in-process run, bit for bit. A lost scheduler ends the command
with one line (no traceback), and a rerun resumes to the same file from the journal.

Each test has its own cluster (a killed worker or scheduler does not come back)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import PAPER
from dask_cluster import LocalDaskCluster, reference_study, same_table, strip_timing

from calbench.identify.cli import main
from calbench.identify.study import TIMING_COLUMNS

CALBENCH = str(Path(sys.executable).with_name("calbench"))
STUDY = """
name = "faults"
scenario = "{paper}"
seeds = 24
[[axis]]
key = "tracker.sigma"
values = [10e-6, 30e-6]
"""
N_CAMPAIGNS = 48
TIMING_KEYS = {"seconds", "seconds_per_run", "setup_seconds", "wall_seconds", "executor", "timings"}


def _strip(x):
    return strip_timing(x, TIMING_KEYS)


def _same_table(a: Path, b: Path) -> None:
    same_table(a, b, TIMING_COLUMNS)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The study run in one go, in this process."""
    return reference_study(tmp_path_factory.mktemp("faults"), STUDY, PAPER)


def _busy_worker(client, proc, timeout: float = 120.0) -> str:
    """The address of a worker that is running a task of ``proc``'s run."""
    t0 = time.monotonic()
    while True:
        assert proc.poll() is None, proc.communicate()
        busy = [w for w, keys in client.processing().items() if keys]
        if busy:
            return busy[0]
        assert time.monotonic() - t0 < timeout, "no task started"
        time.sleep(0.05)


def _kill_worker(cluster: LocalDaskCluster, client, address: str) -> None:
    pid = client.run(lambda: __import__("os").getpid(), workers=[address])[address]
    assert pid in cluster.worker_pids
    __import__("os").kill(pid, signal.SIGKILL)


def _run_killing_a_worker(argv: list[str], tmp_path: Path) -> None:
    """Run ``calbench ARGV --scheduler ADDR`` on a fresh 2-worker cluster, SIGKILL a worker
    while it runs one of the command's tasks, and expect the command to finish."""
    from distributed import Client

    c = LocalDaskCluster(tmp_path / "dask", workers=2)
    try:
        with Client(c.address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
            proc = subprocess.Popen(
                [CALBENCH, *argv, "--scheduler", c.address],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                cwd=tmp_path,
            )
            _kill_worker(c, client, _busy_worker(client, proc))  # its task in flight is lost
            _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    finally:
        c.stop()


def test_a_worker_killed_mid_study_changes_nothing(study, tmp_path):
    s, ref = study
    out = tmp_path / "results.parquet"
    _run_killing_a_worker(["study", str(s), "--out", str(out)], tmp_path)
    _same_table(ref, out)


def test_a_worker_killed_mid_montecarlo_changes_nothing(tmp_path):
    ref, out = tmp_path / "ref.json", tmp_path / "mc.json"
    args = ["montecarlo", str(PAPER), "--runs", "40"]
    assert main([*args, "--scheduler", "in-process", "--json", str(ref)]) == 0
    _run_killing_a_worker([*args, "--json", str(out)], tmp_path)
    assert _strip(json.loads(out.read_text())) == _strip(json.loads(ref.read_text()))


def test_a_lost_scheduler_ends_the_study_with_one_line_and_a_rerun_resumes(study, tmp_path):
    s, ref = study
    c = LocalDaskCluster(tmp_path / "dask", workers=2)
    out = tmp_path / "results.parquet"
    try:
        proc = subprocess.Popen(
            [CALBENCH, "study", str(s), "--out", str(out), "--scheduler", c.address],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=tmp_path,
        )
        parts = out.with_name(out.name + ".parts")
        t0 = time.monotonic()
        while not (parts.is_dir() and any(parts.glob("part-*.parquet"))):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() - t0 < 120, "no task finished"
            time.sleep(0.05)
        c.procs[0].send_signal(signal.SIGKILL)  # the scheduler
        _, err = proc.communicate(timeout=180)
    finally:
        c.stop()
    assert proc.returncode == 2, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert "scheduler" in last and "resume" in last, err
    assert main(["study", str(s), "--out", str(out), "--scheduler", "in-process"]) == 0
    _same_table(ref, out)


def _installed_elsewhere(folder: Path, dist: str, version: str) -> Path:
    """A folder that, first on a worker's PYTHONPATH, makes ``dist`` look installed at ``version``
    there (importlib.metadata reads the first dist-info on the path)."""
    info = folder / f"{dist.replace('-', '_')}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
    return folder


def _wait_for_workers(c: LocalDaskCluster, n: int) -> None:
    from distributed import Client

    with Client(c.address, timeout=30) as client:
        client.wait_for_workers(n, timeout=60)


def test_a_worker_with_another_calbench_is_refused(tmp_path, monkeypatch):
    from calbench.bench.core import InputError
    from calbench.identify.runtime import choose, open_executor

    monkeypatch.setenv("PYTHONPATH", str(_installed_elsewhere(tmp_path / "other", "calbench", "0.0.1")))
    c = LocalDaskCluster(tmp_path / "dask", workers=1)
    monkeypatch.delenv("PYTHONPATH")
    try:
        _wait_for_workers(c, 1)
        with pytest.raises(InputError, match=r"installed on every worker.*: 0\.0\.1"):
            open_executor(choose(c.address, 0.0))
    finally:
        c.stop()


def test_a_worker_with_another_mujoco_build_is_named(tmp_path, monkeypatch, capsys):
    from calbench.identify.runtime import choose, open_executor

    monkeypatch.setenv("PYTHONPATH", str(_installed_elsewhere(tmp_path / "other", "mujoco-core", "0.0.1")))
    c = LocalDaskCluster(tmp_path / "dask", workers=1)
    monkeypatch.delenv("PYTHONPATH")
    try:
        _wait_for_workers(c, 1)
        capsys.readouterr()
        with open_executor(choose(c.address, 0.0)):
            pass
        err = capsys.readouterr().err
        assert "has MuJoCo 0.0.1, this machine" in err and "NumPy" not in err, err
    finally:
        c.stop()


def test_a_worker_killed_mid_design_changes_nothing(tmp_path):
    """The design's pieces (candidates' information, starts of the exchange) rescheduled after a
    SIGKILL give the plan an in-process design gives, criteria and poses alike."""
    ref, out = tmp_path / "ref.json", tmp_path / "design.json"
    args = ["design", str(PAPER), "--candidates", "1500", "--starts", "4"]
    assert main([*args, "--scheduler", "in-process", "--json", str(ref)]) == 0
    _run_killing_a_worker([*args, "--json", str(out)], tmp_path)
    # the threads that made the candidates, and their phases' times (measured in this process
    # only): the machine, not the plan
    where = TIMING_KEYS | {"threads", "phase_seconds"}
    a, b = (strip_timing(json.loads(p.read_text()), where) for p in (out, ref))
    assert a == b
    assert sum(p["repeats"] for p in a["poses"]) == 12 and a["measures"]  # a plan, not two empty reports
