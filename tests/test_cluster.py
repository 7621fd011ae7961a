"""montecarlo, design and study on a real Dask cluster give the numbers of a local run.

One module-scoped cluster: a `dask scheduler` and two `dask worker` processes on 127.0.0.1,
started and stopped by the fixture (tests/dask_cluster.py). "Same numbers" means bit for bit:
every task derives its random stream from (seed, its key) and starts from the same state
(identify/runtime/executor.py), so neither the executor, the worker count, the cut into tasks nor the
order of completion may change a single bit. Run counts are small: these tests are about where
the work runs, not about statistics (tests/test_montecarlo.py, tests/test_design.py).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import PAPER
from dask_cluster import LocalDaskCluster, reference_study, same_table, self_signed, strip_timing, tls_env

from calbench.bench.scenario import load_scenario
from calbench.identify.cli import main
from calbench.identify.design import candidates, generate_candidates, load_design_scenario
from calbench.identify.methods import method_names
from calbench.identify.runtime import choose, open_executor
from calbench.identify.study import TIMING_COLUMNS, montecarlo

CALBENCH = str(Path(sys.executable).with_name("calbench"))
TIMING_KEYS = {
    "seconds",
    "seconds_per_run",
    "setup_seconds",
    "wall_seconds",
    "executor",
    "timings",
    "candidates",
    "refinement",
}


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    from distributed import Client

    c = LocalDaskCluster(tmp_path_factory.mktemp("dask"), workers=2)
    client = None
    try:
        client = Client(c.address, timeout=30)
        client.wait_for_workers(2, timeout=60)
        yield c, client
    finally:
        if client is not None:
            client.close()
        c.stop()


def _strip(x):
    """A JSON report without what depends on the clock or on where it ran."""
    return strip_timing(x, TIMING_KEYS)


def test_montecarlo_on_the_cluster_gives_the_local_numbers(cluster, monkeypatch, tmp_path):
    c, _ = cluster
    scn = load_scenario(PAPER)
    local = montecarlo.run_montecarlo(scn, 8, methods=method_names(), progress=False)  # one task
    monkeypatch.setattr(montecarlo, "RUNS_PER_TASK", 3)  # three
    with open_executor(choose(c.address, 0.0)) as ex:
        assert ex.choice.workers == 2
        remote = montecarlo.run_montecarlo(scn, 8, methods=method_names(), progress=False, executor=ex)
        # the progress line's per-worker counts: every piece counted once, for a worker
        counts = ex.worker_counts()
        assert sum(counts.values()) == 3 and set(counts) <= {"w1", "w2"}
        if len(counts) == 2:
            assert ex.progress_label("runs 8/8").startswith("runs 8/8 | pieces per worker: w1 ")
    for m in method_names():
        assert np.array_equal(local.estimates[m], remote.estimates[m], equal_nan=True), m
        assert np.array_equal(local.stds[m], remote.stds[m], equal_nan=True), m
    assert _strip(local.summary()) == _strip(remote.summary())
    # and through the command line
    out_l, out_r = tmp_path / "l.json", tmp_path / "r.json"
    assert (
        main(["montecarlo", str(PAPER), "--runs", "4", "--scheduler", "in-process", "--json", str(out_l)])
        == 0
    )
    assert (
        main(["montecarlo", str(PAPER), "--runs", "4", "--scheduler", c.address, "--json", str(out_r)]) == 0
    )
    rl, rr = json.loads(out_l.read_text()), json.loads(out_r.read_text())
    assert "cluster" in rr["executor"] and rl["executor"] != rr["executor"]
    assert _strip(rl) == _strip(rr)


def test_design_on_the_cluster_gives_the_local_candidates_and_plan(cluster, monkeypatch, tmp_path):
    c, _ = cluster
    scn, st = load_design_scenario(PAPER)
    local = generate_candidates(scn, st, n=150)
    monkeypatch.setattr(candidates, "CANDIDATE_BLOCK", 64)  # more, smaller tasks
    with open_executor(choose(c.address, 0.0)) as ex:
        remote = generate_candidates(scn, st, n=150, executor=ex)
    for k in ("q", "wrench", "kind", "blocks"):
        assert np.array_equal(getattr(local, k), getattr(remote, k)), k
    args = ["design", str(PAPER), "--configs", "4", "--candidates", "60", "--starts", "1", "--no-refine"]
    js_l, js_r = tmp_path / "l.json", tmp_path / "r.json"
    assert main(args + ["--json", str(js_l), "--scheduler", "in-process"]) == 0
    assert main(args + ["--json", str(js_r), "--scheduler", c.address]) == 0
    assert _strip(json.loads(js_l.read_text())) == _strip(json.loads(js_r.read_text()))


# 3 cells x 30 seeds: each cell is two tasks (identify/study/run.py aims at ~2 s of campaigns a
# task), so the six tasks end at three different times on two workers and a kill after the first
# part always finds work unfinished (with 6 seeds a cell was one task, and the last task could
# finish between the first part and the signal)
N_CAMPAIGNS = 90
STUDY = """
name = "cluster test"
scenario = "{paper}"
seeds = 30
[[axis]]
key = "tracker.sigma"
values = [10e-6, 20e-6, 40e-6]
"""


def _rows(out: Path):
    """Every row finished so far: the file and the journal beside it."""
    tables = [pq.read_table(out)] if out.exists() else []
    parts = out.with_name(out.name + ".parts")
    tables += [pq.read_table(p) for p in sorted(parts.glob("part-*.parquet"))] if parts.is_dir() else []
    return sum(t.num_rows for t in tables)


def _wait_for_a_part(proc, out: Path, timeout: float = 120.0) -> None:
    parts = out.with_name(out.name + ".parts")
    t0 = time.monotonic()
    while not (parts.is_dir() and any(parts.glob("part-*.parquet"))):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout, "no task finished"
        time.sleep(0.05)


def _same_table(a: Path, b: Path) -> None:
    same_table(a, b, TIMING_COLUMNS)


@pytest.fixture(scope="module")
def study_reference(tmp_path_factory):
    """The small study run in one go, in this process."""
    return reference_study(tmp_path_factory.mktemp("study"), STUDY, PAPER)


def _scheduler_tasks(client) -> int:
    return client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks))


def test_a_study_killed_midway_resumes_to_the_same_parquet_file(cluster, study_reference, tmp_path):
    c, client = cluster
    study, ref = study_reference
    out = tmp_path / "results.parquet"
    proc = subprocess.Popen(
        [CALBENCH, "study", str(study), "--out", str(out), "--scheduler", c.address],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=tmp_path,
    )
    _wait_for_a_part(proc, out)
    proc.send_signal(signal.SIGKILL)  # a crash: no chance to tidy up
    proc.wait()
    kept = _rows(out)
    assert 0 < kept < N_CAMPAIGNS  # what finished survived; the rest did not run
    assert main(["study", str(study), "--out", str(out), "--scheduler", c.address]) == 0
    _same_table(ref, out)
    assert not out.with_name(out.name + ".parts").exists()  # the journal is merged and gone
    assert main(["study", str(study), "--out", str(out), "--scheduler", c.address]) == 0  # nothing to do
    _same_table(ref, out)


def test_ctrl_c_cancels_the_cluster_tasks_and_keeps_what_finished(cluster, study_reference, tmp_path):
    c, client = cluster
    study, ref = study_reference
    out = tmp_path / "results.parquet"
    proc = subprocess.Popen(
        [CALBENCH, "study", str(study), "--out", str(out), "--scheduler", c.address],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )
    _wait_for_a_part(proc, out)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "resume" in err
    n = pq.read_table(out).num_rows  # merged into the file on the way out
    assert 0 < n < N_CAMPAIGNS
    t0 = time.monotonic()
    while _scheduler_tasks(client):  # the cluster forgets the cancelled tasks
        assert time.monotonic() - t0 < 20, _scheduler_tasks(client)
        time.sleep(0.2)
    assert main(["study", str(study), "--out", str(out), "--scheduler", "in-process"]) == 0
    _same_table(ref, out)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="the TLS recipe needs openssl")
def test_a_tls_cluster_with_dasks_security_configuration(tmp_path):
    certs = self_signed(tmp_path / "certs")
    c = LocalDaskCluster(tmp_path / "tls", workers=1, certs=certs)
    try:
        assert c.address.startswith("tls://127.0.0.1:")
        base = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
        out = tmp_path / "mc.json"
        cmd = [
            CALBENCH,
            "montecarlo",
            str(PAPER),
            "--runs",
            "3",
            "--scheduler",
            c.address,
            "--json",
            str(out),
        ]
        r = subprocess.run(cmd, env={**base, **tls_env(certs)}, capture_output=True, text=True, timeout=180)
        assert r.returncode == 0, r.stderr
        ref = tmp_path / "ref.json"
        assert (
            main(["montecarlo", str(PAPER), "--runs", "3", "--scheduler", "in-process", "--json", str(ref)])
            == 0
        )
        assert _strip(json.loads(out.read_text())) == _strip(json.loads(ref.read_text()))
        r = subprocess.run(cmd, env=base, capture_output=True, text=True, timeout=60)  # no certificates
        assert r.returncode == 2 and "security configuration" in r.stderr, r.stderr
    finally:
        c.stop()
