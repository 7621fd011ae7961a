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
from conftest import MJCF, PAPER

from calbench.bench.core import STATES, InputError
from calbench.bench.log import SCHEMAS, checker, findings, problems
from calbench.bench.model import Robot
from calbench.bench.scenario import load_plan
from calbench.bench.shopfloor import ROW_BYTES, TABLE_BYTES_PER_ROW, read_readings
from calbench.bench.tracker import tracker_rotation
from calbench.identify.cli import main
from calbench.identify.shopfloor import import_readings, rigid_points

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


def write_csv(path: Path, plan_file: Path, rows: int, seed: int = 0) -> Path:
    """``rows`` readings along the paper plan with the tracker where the plan puts it: the
    reflectors by rigid kinematics (what check_placed compares with), loaded 1 mm lower, 20 um
    noise, every pose measured in both states with times."""
    plan = load_plan(plan_file)
    robot = Robot.from_file(MJCF)
    keys = [(p, n) for p in range(len(plan.poses)) for n in NAMES]
    world = rigid_points(robot, plan, keys).reshape(len(plan.poses), len(NAMES), 3)
    rot = tracker_rotation(plan.tracker)
    base = (world - plan.tracker.position) @ rot * 1e3  # mm, tracker frame
    per_pose = 2 * len(NAMES)
    k = max(rows // (len(plan.poses) * per_pose), 1)
    rng = np.random.default_rng(seed)
    with open(path, "w") as f:
        f.write("pose,state,point,x,y,z,time\n")
        for p in range(len(plan.poses)):
            for s, shift in (("unloaded", 0.0), ("loaded", -1.0)):
                xyz = base[p] + [0.0, 0.0, shift] + rng.normal(0, 0.02, (k, len(NAMES), 3))
                for j in range(k):
                    t = 1000 * p + (500 if s == "loaded" else 0) + 0.01 * j
                    for i, name in enumerate(NAMES):
                        x, y, z = xyz[j, i]
                        f.write(f"{p},{s},{name},{x:.6f},{y:.6f},{z:.6f},{t:.2f}\n")
    return path


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
