"""Honest time estimates (issue 23): the verbs announce durations from per-piece costs measured
at their start on a few pieces, not from constants tuned to one machine. The model (pieces x
measured cost) is held to the measured cost of the whole job; the factor allows for a machine
shared with other work (the announced figure must be within 1.5x: benchmarks/estimates_bench.py
prints announced against taken on the paper and KR 270 scenarios)."""

from __future__ import annotations

import time

import numpy as np
from conftest import PAPER

from calbench.bench.scenario import load_scenario
from calbench.identify.runtime import InProcess
from calbench.identify.study import measure_montecarlo, run_montecarlo
from calbench.identify.study import montecarlo as M

FACTOR = 2.0  # the check's allowance for the machine's load changing between probe and job


def test_montecarlo_estimate_is_the_measured_cost_per_run_and_changes_no_result():
    scn = load_scenario(PAPER)
    methods = ("one-step", "two-step", "two-step-weighted")
    M._setup.cache_clear()
    plain = run_montecarlo(scn, 4, methods, executor=InProcess())
    M._setup.cache_clear()
    cost = measure_montecarlo(scn, methods, probe=3)
    assert cost.probed == 3 and cost.setup_seconds > 0 and cost.seconds_per_piece > 0
    runs = 20
    t = time.perf_counter()
    mc = run_montecarlo(scn, runs, methods, executor=InProcess())
    taken = time.perf_counter() - t
    assert 1 / FACTOR < cost.seconds(runs) / taken < FACTOR, (cost.seconds(runs), taken)
    for m in methods:  # the probe's own noise seeds: the runs' numbers are untouched
        np.testing.assert_array_equal(mc.estimates[m][:4], plain.estimates[m])
    M._setup.cache_clear()


def test_design_announces_its_candidates_from_the_first_ones_timed(tmp_path):
    """`design` times its first PROBE_CANDIDATES candidates and announces the rest from them: the
    announced work is the candidates' count times that cost, and the phase takes about that."""
    import contextlib

    from calbench.identify.design import DesignRequest, run_design
    from calbench.identify.runtime import InProcess

    seen = {}

    @contextlib.contextmanager
    def pieces(work, tasks, setup, basis):
        seen.update(work=work, basis=basis)
        t = time.perf_counter()
        yield InProcess()
        seen["taken"] = time.perf_counter() - t

    n = 1000
    req = DesignRequest(
        scenario=PAPER, configs=8, export_candidates=tmp_path / "c.npz", candidates=n, processes=1
    )
    run_design(req, pieces=pieces)
    assert "measured on the first 200" in seen["basis"]
    assert 1 / FACTOR < seen["work"] / seen["taken"] < FACTOR, seen
