"""Which executor runs the pieces, and the local cluster's security promise (127.0.0.1 only)."""

from __future__ import annotations

import operator
import socket
import warnings

import dask
import numpy as np
import psutil
import pytest
from conftest import PAPER

from calbench.bench.core import InputError
from calbench.identify.cli import main
from calbench.identify.runtime import executor as X


def test_the_choice_follows_the_flag_the_configuration_and_the_measured_break_even():
    be = X.break_even_seconds(2, 10)
    assert be == pytest.approx((X.LOCAL_STARTUP_S + X.LOCAL_SHUTDOWN_S) * 2 + 10 * X.TASK_OVERHEAD_S)
    assert X.choose(None, 0.5 * be, tasks=10, workers=2).kind == X.IN_PROCESS
    assert X.choose(None, 2.0 * be, tasks=10, workers=2).kind == X.LOCAL
    assert X.choose(None, 1e6, tasks=1, workers=2).kind == X.IN_PROCESS  # one piece
    assert X.choose(None, 1e6, tasks=10, workers=1).kind == X.IN_PROCESS  # one worker
    assert X.choose("local", 0.0, workers=3) == X.ExecutorChoice(X.LOCAL, None, 3, "--scheduler local")
    assert X.choose("in-process", 1e6).kind == X.IN_PROCESS
    c = X.choose("tcp://10.0.0.5:8786", 0.0)
    assert (c.kind, c.address) == (X.REMOTE, "tcp://10.0.0.5:8786")
    with dask.config.set({"scheduler-address": "tls://10.0.0.5:8786"}):  # DASK_SCHEDULER_ADDRESS
        c = X.choose(None, 0.0)
        assert (c.kind, c.address) == (
            X.REMOTE,
            "tls://10.0.0.5:8786",
        ) and "DASK_SCHEDULER_ADDRESS" in c.reason
        assert X.choose("in-process", 0.0).kind == X.IN_PROCESS  # the flag wins
    with pytest.raises(InputError, match="tcp://HOST:PORT"):
        X.choose("http://10.0.0.5:8786", 0.0)


def test_an_unreachable_scheduler_or_tls_without_certificates_is_bad_input(capsys, monkeypatch):
    monkeypatch.setattr(X, "CONNECT_TIMEOUT_S", 1.0)
    assert main(["montecarlo", str(PAPER), "--runs", "2", "--scheduler", "tcp://127.0.0.1:9"]) == 2
    assert "a reachable Dask scheduler" in capsys.readouterr().err
    assert main(["montecarlo", str(PAPER), "--runs", "2", "--scheduler", "tls://127.0.0.1:9"]) == 2
    assert "security configuration" in capsys.readouterr().err


def test_the_local_cluster_listens_on_127_0_0_1_only_and_runs_the_same_functions():
    # Dask's default HTTP port taken (as by another calbench run's cluster): no warning, another port
    taken = socket.socket()
    try:
        taken.bind(("127.0.0.1", 8787))
    except OSError:
        pass  # already taken by someone else: the same case
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*already in use")
        ex = X.open_executor(X.choose("local", 0.0, workers=2))
    taken.close()
    with ex:
        assert ex.cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        info = ex.client.scheduler_info()["workers"]
        assert len(info) == 2 and all(a.startswith("tcp://127.0.0.1:") for a in info)
        pids = set(ex.client.run(lambda: __import__("os").getpid()).values())
        pids |= {psutil.Process(p).ppid() for p in pids}  # their nannies
        pids.add(psutil.Process().pid)  # the scheduler runs in this process
        listening = [
            c.laddr.ip
            for p in pids
            for c in psutil.Process(p).net_connections("inet")
            if c.status == psutil.CONN_LISTEN
        ]
        assert listening and set(listening) == {"127.0.0.1"}, listening
        # functions of installed modules only (workers import them): operator.mul, shared 10
        assert sorted(r for _, r in ex.run(operator.mul, [(i,) for i in range(6)], shared=(10,))) == [
            0,
            10,
            20,
            30,
            40,
            50,
        ]
        assert list(ex.ordered(operator.mul, ((i, i) for i in range(6)), window=2)) == [0, 1, 4, 9, 16, 25]
    inproc = X.InProcess()
    assert list(inproc.ordered(operator.mul, [(3, 3)])) == [9]
    assert list(inproc.run(operator.mul, [(2,)], shared=(5,))) == [(0, 10)]


class _InterruptedAfter(X.InProcess):
    """This process, with a Ctrl-C after ``n`` pieces finished."""

    def __init__(self, n):
        super().__init__()
        self.n = n

    def run(self, fn, arglist, shared=()):
        for i, a in enumerate(arglist):
            if i == self.n:
                raise KeyboardInterrupt
            yield i, fn(*shared, *a)


def test_ctrl_c_during_montecarlo_keeps_the_runs_that_finished(monkeypatch):
    from calbench.bench.scenario import load_scenario
    from calbench.identify.study import montecarlo

    monkeypatch.setattr(montecarlo, "RUNS_PER_TASK", 2)
    scn = load_scenario(PAPER)
    full = montecarlo.run_montecarlo(scn, 6, methods=("one-step",), progress=False)
    with pytest.raises(X.Interrupted) as e:
        montecarlo.run_montecarlo(
            scn, 6, methods=("one-step",), progress=False, executor=_InterruptedAfter(2)
        )
    part = e.value.partial
    assert (e.value.done, e.value.total, part.runs) == (4, 6, 4)
    assert np.array_equal(part.estimates["one-step"], full.estimates["one-step"][:4])
    assert isinstance(e.value, KeyboardInterrupt)
