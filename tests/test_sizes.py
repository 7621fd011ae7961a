"""Inputs of any size in bounded memory (issue 24): the bounds of the design, proved at small scale.

Each test measures the memory a step allocates (tracemalloc: Python objects, numpy arrays and
array.array columns all report to it) at N and at 10 N of something and holds the growth to
the budget the code states, per row or per reading. The budgets are the designs' byte counts
(bench/shopfloor/formats.py ROW_BYTES, bench/shopfloor/readings.py TABLE_BYTES_PER_ROW, ...),
not fits to a measurement: the old reader (every row an object, ~1.3 kB a row) fails them by
an order of magnitude. benchmarks/sizes_bench.py measures the same at full size (10^6 rows,
2 GB logs) as peak RSS.
"""

from __future__ import annotations

import json
import random
import re
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from big_inputs import readings_file, replicated_log
from conftest import MJCF, PAPER

from calbench.bench.core import STATES, InputError
from calbench.bench.log import SCHEMAS, LogReadings, checker, findings, message_problems, problems, read_log
from calbench.bench.shopfloor import ROW_BYTES, TABLE_BYTES_PER_ROW, read_readings
from calbench.bench.view import measured_deflections
from calbench.identify.cli import main
from calbench.identify.core import from_log
from calbench.identify.shopfloor import import_readings

NAMES = ["refl_a", "refl_b", "refl_c"]


def peak_bytes(fn, *args, **kwargs) -> tuple[int, object]:
    """The peak of memory allocated while ``fn`` runs (above what was allocated before)."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        out = fn(*args, **kwargs)
        return tracemalloc.get_traced_memory()[1] - base, out
    finally:
        tracemalloc.stop()


# --------------------------------------------------------------------------- the schema check


def mutations(m, rng: random.Random):
    """``m`` with one value somewhere replaced by something a log might hold instead."""
    junk = [None, True, 0, -1, 1.5, float("nan"), float("inf"), "x", [], {}, [1.0], [[1.0, 2.0, 3.0]]]

    def paths(v, at=()):
        yield at
        if isinstance(v, dict):
            for k, x in v.items():
                yield from paths(x, (*at, k))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                yield from paths(x, (*at, i))

    spots = list(paths(m))
    for _ in range(60):
        out = json.loads(json.dumps(m))
        at = rng.choice(spots[1:])
        parent = out
        for k in at[:-1]:
            parent = parent[k]
        if rng.random() < 0.15 and isinstance(parent, dict):
            del parent[at[-1]]
        elif rng.random() < 0.15 and isinstance(parent, list):
            parent.append(rng.choice(junk))
        else:
            parent[at[-1]] = rng.choice(junk)
        yield out


MESSAGES = {
    "/tracker/measurement": {
        "pose": 3,
        "state": "loaded",
        "repeat": 1,
        "reflectors": NAMES,
        "position": [[1.0, 2.0, 3.0], [1.5, 2.5, 3.5], None],
        "covariance": [[[4e-10, 0.0, 0.0], [0.0, 4e-10, 0.0], [0.0, 0.0, 4e-10]]] * 2 + [None],
        "visible": [True, True, False],
    },
    "/campaign/pose": {"pose": 0, "state": "unloaded", "q": [0.0, 0.1, -0.2, 0.3, 0.4, 0.5]},
    "/campaign/wrench": {
        "pose": 2,
        "state": "loaded",
        "force": [0.0, 0.0, -6867.0],
        "moment": [0.0, 0.0, 0.0],
        "site": "payload",
        "mass": 700.0,
    },
    "/truth/parameters": {
        "compliance": [1e-7] * 6,
        "compensator": {"stiffness": 1e5, "preload": 0.1},
        "compensators": {"b": {"stiffness": 1.0, "preload": 0.0}},
        "effects": {},
    },
}


@pytest.mark.parametrize("topic", sorted(MESSAGES))
def test_the_compiled_schema_check_agrees_with_the_findings(topic):
    """The fast check (bench/log/schema.py checker) says valid exactly when the walk that names
    the field finds nothing, on 600 seeded mutations per topic."""
    schema = SCHEMAS[topic]
    assert checker(schema)(MESSAGES[topic]) and problems(MESSAGES[topic], schema) == []
    rng = random.Random(24)
    refused = 0
    for _ in range(10):
        for m in mutations(MESSAGES[topic], rng):
            found = findings(m, schema)
            assert checker(schema)(m) == (found == []), (m, found)
            assert problems(m, schema) == found
            refused += bool(found)
    assert refused > 100  # the mutations do break messages


# --------------------------------------------------------------------------- the readings CSV


@pytest.fixture(scope="module")
def plan_file(tmp_path_factory) -> Path:
    s = PAPER.read_text().replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF.as_posix()}"')
    s = s[: s.index("[truth]")] + s[s.index("[tracker]") :]
    path = tmp_path_factory.mktemp("sizes") / "plan.toml"
    path.write_text(s)
    return path


write_csv = readings_file


def test_the_table_grows_by_its_columns_not_by_row_objects(tmp_path, plan_file):
    """Reading 10x the rows costs at most TABLE_BYTES_PER_ROW more per extra row (peak, while
    reading: the columns, their spare room and the copied-row check); the table holds
    ROW_BYTES a row."""
    n = 1600
    small = write_csv(tmp_path / "small.csv", plan_file, n)
    large = write_csv(tmp_path / "large.csv", plan_file, 10 * n)
    p_small, t_small = peak_bytes(read_readings, small, 16, NAMES)
    p_large, t_large = peak_bytes(read_readings, large, 16, NAMES)
    extra = len(t_large) - len(t_small)
    assert extra > 8 * n
    assert (p_large - p_small) / extra <= TABLE_BYTES_PER_ROW
    assert t_large.nbytes == ROW_BYTES * len(t_large)
    # the streaming read and the read of the text agree row for row
    again = read_readings(large, 16, NAMES, text=large.read_text())
    for col in ("line", "pose", "state", "point", "position", "time", "sigma"):
        assert np.array_equal(getattr(again, col), getattr(t_large, col), equal_nan=True), col


def test_the_import_holds_one_pose_of_readings_at_a_time(tmp_path, plan_file):
    """The whole import (read, register or check, write the log pose by pose) at N and 10N rows:
    the growth is the table's (TABLE_BYTES_PER_ROW a row) plus one pose's readings, each at most
    READING_BYTES (an ImportedReading and its arrays with the registration's per-reading
    temporaries, ~1.7 kB measured, budgeted at 3 kB), never all of them."""
    reading_bytes = 3000
    n = 500
    out = []
    for rows in (n, 10 * n):
        csv_path = write_csv(tmp_path / f"r{rows}.csv", plan_file, rows)
        peak, res = peak_bytes(import_readings, csv_path, plan_file, tmp_path / f"r{rows}.mcap")
        largest = max(len(res.table.rows(p, s)) for p in range(16) for s in STATES) // len(NAMES)
        out.append((peak, len(res.table), 2 * largest))
    (p1, r1, k1), (p2, r2, k2) = out
    budget = TABLE_BYTES_PER_ROW * (r2 - r1) + reading_bytes * (k2 - k1)
    assert p2 - p1 <= budget, (p2 - p1, budget)
    # all the readings at once (the old import) would need more than twice that
    assert 2 * budget < 1300 * (r2 - r1)


def test_the_import_shows_progress_in_mb_read_and_poses_written(tmp_path, plan_file):
    class Record:
        def __init__(self):
            self.total, self.done, self.closed = None, 0, False

        def start(self, total, label=""):
            self.total, self.done = total, 0

        def update(self, label="", step=1):
            self.done += step

    csv_path = write_csv(tmp_path / "r.csv", plan_file, 20_000)
    read, written = Record(), Record()
    import_readings(csv_path, plan_file, tmp_path / "r.mcap", read_progress=read, write_progress=written)
    mb = -(-csv_path.stat().st_size // (1 << 20))
    assert read.total == mb and read.done == mb
    assert written.total == 16 and written.done == 16


def test_a_readings_file_too_big_for_memory_is_refused_up_front(tmp_path, plan_file, monkeypatch, capsys):
    csv_path = write_csv(tmp_path / "r.csv", plan_file, 2000)
    monkeypatch.setattr("calbench.bench.core.memory.available_bytes", lambda: 50_000)
    rc = main(["import", str(csv_path), "--plan", str(plan_file), "--out", str(tmp_path / "r.mcap")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    assert re.search(r"r\.csv: \(file\): expected an input whose work fits in this machine's memory", err)
    rows = float(re.search(r"~([\d,]+) rows at 100 B", err).group(1).replace(",", ""))
    assert rows == pytest.approx(2000, rel=0.1)  # the estimate from the file's first bytes
    assert not (tmp_path / "r.mcap").exists()


def test_a_byte_that_is_not_utf8_is_named_by_its_line(tmp_path):
    p = tmp_path / "r.csv"
    p.write_bytes(
        b"pose,state,point,x,y,z\n0,unloaded,refl_a,-2224.3,3033.2,-59.7\n0,loaded,refl_\xff,1,2,3\n"
    )
    with pytest.raises(InputError, match=r"r\.csv: line 3: expected UTF-8 text"):
        read_readings(p, 16, NAMES)


# --------------------------------------------------------------------------- campaign logs


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("log")
    assert main(["simulate", str(PAPER), "--out", str(d / "paper.mcap")]) == 0
    return d / "paper.mcap"


def read_a_pose_at_a_time(monkeypatch) -> None:
    """read_log keeps no reading in memory (as for a log of more than KEEP_READINGS)."""
    monkeypatch.setattr("calbench.bench.log.read.KEEP_READINGS", 0)


def outputs(log: Path, d: Path) -> dict:
    """What identify, export, report, view and discover make of ``log`` (names and timings out)."""
    d.mkdir()
    assert main(["identify", str(log), "--json", str(d / "id.json")]) == 0
    assert main(["export", str(log), "--csv", str(d / "r.csv")]) == 0
    assert main(["report", str(log), "--out", str(d / "r.html")]) == 0
    ident = json.loads((d / "id.json").read_text())
    ident.pop("seconds", None)
    opened = read_log(log)
    return {
        "identify": ident,
        "export": (d / "r.csv").read_bytes(),
        "report": (d / "r.html").read_text().replace(str(d), "OUT"),
        "view": {p: {n: v.tolist() for n, v in r.items()} for p, r in measured_deflections(opened).items()},
        "observations": [(o.index, o.dp.tolist(), o.cov.tolist()) for o in from_log(opened).poses],
        "readings": [
            (m.pose, m.state, m.repeat, repr(m.position.tolist()), m.time) for m in opened.measurements
        ],
        "first": opened.first_reading_time,
    }


def test_a_log_read_a_pose_at_a_time_gives_every_verb_the_same_results(paper_log, tmp_path, monkeypatch):
    kept = outputs(paper_log, tmp_path / "kept")
    read_a_pose_at_a_time(monkeypatch)
    assert isinstance(read_log(paper_log).measurements, LogReadings)
    assert outputs(paper_log, tmp_path / "lazy") == kept


def test_a_log_that_changes_while_read_a_pose_at_a_time_is_refused(paper_log, tmp_path, monkeypatch):
    read_a_pose_at_a_time(monkeypatch)
    copy = tmp_path / "c.mcap"
    copy.write_bytes(paper_log.read_bytes())
    log = read_log(copy)
    assert len(log.readings(0, "unloaded")) == 1
    copy.write_bytes(paper_log.read_bytes()[:-1] + b"\x00")  # rewritten since it was checked
    with pytest.raises(InputError, match="expected the log unchanged while it is read"):
        log.readings(1, "unloaded")


def log_peak(log: Path) -> int:
    """Peak memory of what identify does with a log before fitting: read it, make the
    observations (every pose's mean readings and deflection covariance)."""
    return peak_bytes(lambda: len(from_log(read_log(log)).poses))[0]


def test_the_log_reader_holds_a_pose_at_a_time(paper_log, tmp_path, monkeypatch):
    """Logs beyond KEEP_READINGS: 10x the poses costs only the per-pose bookkeeping (commands,
    loads, where each pose's readings are, its observation: POSE_BYTES, ~2.5 kB measured,
    budgeted at 6 kB); 10x the readings per pose costs one pose's readings, READING_BYTES each
    (the record, ~1 kB, and its share of the arrays the pose's mean and deflection covariance
    stack, ~2 kB: 3.1 kB measured, budgeted at 5 kB), not all of them. Kept in memory, the
    readings of every pose would cost ~1 kB each, and stacked twice as much."""
    pose_bytes, reading_bytes = 6000, 5000
    read_a_pose_at_a_time(monkeypatch)
    few = replicated_log(paper_log, tmp_path / "few.mcap", poses=16, repeats=5)
    many = replicated_log(paper_log, tmp_path / "many.mcap", poses=160, repeats=5)
    deep = replicated_log(paper_log, tmp_path / "deep.mcap", poses=16, repeats=50)
    base = log_peak(few)
    assert log_peak(many) - base <= pose_bytes * 144
    assert pose_bytes * 144 < 1000 * 2 * 5 * 144  # what holding the readings would add
    assert log_peak(deep) - base <= reading_bytes * 2 * 45  # one pose's extra readings
    assert reading_bytes * 2 * 45 < 1000 * 2 * 45 * 16  # every pose's extra readings


@pytest.mark.parametrize("seed", range(3))
def test_the_fast_covariance_check_agrees_with_eigenvalues(seed):
    """read.py accepts a plainly positive definite covariance from its leading minors and asks
    eigvalsh otherwise: the verdict equals eigvalsh's on random, near-singular, indefinite and
    asymmetric matrices of every scale."""
    rng = np.random.default_rng(seed)
    base = dict(MESSAGES["/tracker/measurement"])
    for _ in range(300):
        a = rng.normal(size=(3, 3))
        kind = rng.integers(4)
        if kind == 0:
            c = a @ a.T  # positive definite
        elif kind == 1:
            u = np.linalg.qr(a)[0]
            c = u @ np.diag([1.0, 1.0, rng.choice([1e-17, 1e-15, 1e-12, 0.0, -1e-15])]) @ u.T
        elif kind == 2:
            c = a + a.T  # indefinite, mostly
        else:
            c = a @ a.T + np.diag([0, 0, 1e-6]) * np.eye(3)[rng.integers(3)]
        c = c * 10.0 ** rng.integers(-14, 3)
        sym = 0.5 * (c + c.T)
        scale = np.abs(c).max()
        if np.abs(c - c.T).max() > 1e-9 * scale or not scale > 0:
            want = "an asymmetric or zero matrix"
        else:
            want = "a matrix with an eigenvalue <= 0" if np.linalg.eigvalsh(sym).min() <= 0 else None
        m = dict(base, covariance=[c.tolist(), c.tolist(), None])
        found = message_problems("/tracker/measurement", m, None)
        assert (found[0].got if found else None) == want, (c, found)


def test_checking_a_big_log_shows_its_progress(paper_log, tmp_path, monkeypatch):
    """Within showing_progress (the command line's), a log above PROGRESS_BYTES shows the MB
    checked: started with the file's size, advanced to its end, closed."""
    from calbench.bench.log import showing_progress

    big = replicated_log(paper_log, tmp_path / "big.mcap", poses=40, repeats=400, fast=True)
    monkeypatch.setattr("calbench.bench.log.read.PROGRESS_BYTES", 1 << 20)
    seen = []

    class Bar:
        def __init__(self, name):
            self.name, self.total, self.done, self.closed = name, 0, 0, False
            seen.append(self)

        def start(self, total, label=""):
            self.total = total

        def update(self, label="", step=1):
            self.done += step

        def close(self):
            self.closed = True

    read_log(paper_log)  # no sink asked for: nothing shown
    with showing_progress(Bar):
        read_log(paper_log)  # small: nothing shown
        assert not seen
        read_log(big)
    mb = big.stat().st_size >> 20
    assert mb >= 2 and len(seen) == 1
    (bar,) = seen
    assert big.name in bar.name and bar.total == mb and mb - 1 <= bar.done <= mb and bar.closed


def test_a_design_or_a_job_too_big_for_memory_is_refused_up_front(tmp_path, monkeypatch, capsys):
    """The design's candidates (CANDIDATE_BYTES each at their peak) and a compensation job's
    points (POINT_BYTES each) are estimated before any work: beyond the memory available, exit 2
    with the estimate."""
    monkeypatch.setattr("calbench.bench.core.memory.available_bytes", lambda: 10_000_000)
    rc = main(["design", str(PAPER), "--candidates", "5000", "--json", str(tmp_path / "d.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert (
        "--candidates: candidates: expected an input whose work fits" in err
        and "5,000 candidates at 7000 B each: ~35 MB" in err
    )
    job = tmp_path / "job.toml"
    points = "".join(
        "[[point]]\nq = [0, 10, -10, 0, -30, 0]\nwrench = [0, 0, -1000, 0, 0, 0]\n" for _ in range(700)
    )
    job.write_text(f'robot = "{MJCF.as_posix()}"\n[tool]\nbody = "link6"\n{points}')
    rc = main(
        [
            "compensate",
            str(job),
            "--identified",
            str(tmp_path / "none.json"),
            "--out",
            str(tmp_path / "c.csv"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert (
        "job.toml: point: expected an input whose work fits" in err
        and "700 points at 16000 B each: ~11.2 MB" in err
    )
    assert not (tmp_path / "d.json").exists() and not (tmp_path / "c.csv").exists()
