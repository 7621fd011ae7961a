"""`calbench export` and `calbench import` with the tracker pose given by the plan; bad CSVs.

Tolerances. Export writes positions to 1 nm (6 decimals of a mm): the rounding error (uniform,
sd 0.3 nm) is 1e-5 of the 28 um deflection noise, so identifying the imported log must give the
original estimates within 1e-3 of their standard deviations (a generous bound on 1e-5 sigma).
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import MJCF, PAPER

from calbench.bench.core import InputError
from calbench.bench.log import read_log
from calbench.bench.scenario import load_plan, load_scenario, reading_times
from calbench.bench.shopfloor import read_readings
from calbench.identify.cli import main

NAMES = ["refl_a", "refl_b", "refl_c"]


def plan_text(position: bool = True) -> str:
    """The paper scenario as a plan: no [truth], the robot path absolute, the tracker position
    kept or withheld."""
    s = PAPER.read_text()
    s = s.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF.as_posix()}"')
    s = s[: s.index("[truth]")] + s[s.index("[tracker]") :]
    if not position:
        s = re.sub(r"position = \[3.5, -3.5, 3.2\].*\n", "", s)
    return s


def simulate_and_export(d: Path) -> None:
    """The paper campaign in d/paper.mcap and its readings in d/paper.csv."""
    assert main(["simulate", str(PAPER), "--out", str(d / "paper.mcap")]) == 0
    assert main(["export", str(d / "paper.mcap"), "--csv", str(d / "paper.csv")]) == 0


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("import")
    simulate_and_export(d)
    (d / "plan.toml").write_text(plan_text(True))
    (d / "plan_unplaced.toml").write_text(plan_text(False))
    return d


def identify_json(log: Path, out: Path) -> dict:
    assert main(["identify", str(log), "--json", str(out)]) == 0
    return json.loads(out.read_text())


def rows_of(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write_rows(path: Path, rows: list[dict], transform=None, fields=None) -> Path:
    """Rows (dicts) as a CSV at path, x y z mapped by ``transform`` (in mm) when given."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields or list(rows[0]))
        w.writeheader()
        for r in rows:
            r = dict(r)
            if transform is not None:
                y = transform(np.array([float(r[c]) for c in "xyz"]))
                r.update({c: f"{v:.6f}" for c, v in zip("xyz", y)})
            w.writerow({k: r[k] for k in (fields or r)})
    return path


# --------------------------------------------------------------------------- export


def test_export_writes_every_visible_reading(work):
    log = read_log(work / "paper.mcap")
    rows = rows_of(work / "paper.csv")
    seen = sum(int(m.visible.sum()) for m in log.measurements)
    assert len(rows) == seen
    assert list(rows[0]) == ["pose", "state", "point", "x", "y", "z", "time", "sigma"]
    first = log.measurements[0]
    i = first.reflectors.index(rows[0]["point"])
    xyz = np.array([float(rows[0][c]) for c in "xyz"]) * 1e-3
    assert np.max(np.abs(xyz - first.position[i])) < 0.6e-9  # 1 nm rounding
    assert float(rows[0]["sigma"]) == pytest.approx(20e-3)  # mm: the isotropic 20 um


def test_plan_is_a_scenario_without_truth(work):
    plan = load_plan(work / "plan_unplaced.toml")
    assert not plan.tracker_placed and len(plan.poses) == 16
    assert load_plan(work / "plan.toml").tracker.position.tolist() == [3.5, -3.5, 3.2]
    assert load_plan(PAPER).tracker_placed  # a scenario is a plan too (its truth ignored)
    with pytest.raises(InputError, match="truth: expected this required key"):
        load_scenario(work / "plan.toml")  # simulate still needs the truth


def test_plan_yaw_without_position_is_refused(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text(plan_text(False).replace("[tracker]\n", "[tracker]\nyaw = 10.0\n"))
    with pytest.raises(InputError, match=r"tracker.yaw: expected a tracker position with the yaw"):
        load_plan(p)


# --------------------------------------------------------------------------- import, pose given


def test_import_with_the_plans_tracker_identifies_like_the_original(work):
    out = work / "imported.mcap"
    assert (
        main(["import", str(work / "paper.csv"), "--plan", str(work / "plan.toml"), "--out", str(out)]) == 0
    )
    log = read_log(out, include_truth=True)
    assert log.truth is None and log.complete_poses == list(range(16))
    info = log.header["imported"]
    assert info["source"] == "paper.csv" and info["units"] == "mm" and info["tracker_pose"] == "plan"
    assert len(info["sha256"]) == 64 and info["rows"] == len(rows_of(work / "paper.csv"))
    a = identify_json(work / "paper.mcap", work / "a.json")
    b = identify_json(out, work / "b.json")
    for pa, pb in zip(a["parameters"], b["parameters"]):
        assert pb["truth"] is None
        assert abs(pa["estimate"] - pb["estimate"]) < 1e-3 * pa["std"], pa["name"]
        assert pb["std"] == pytest.approx(pa["std"], rel=1e-4)  # taken at estimates 1e-5 sigma apart


def test_import_in_metres_and_reexport(work):
    rows = rows_of(work / "paper.csv")
    m = work / "paper_m.csv"
    with open(m, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["point", "state", "pose", "x", "y", "z", "sigma"])  # any column order
        for r in rows:
            w.writerow(
                [r["point"], r["state"], r["pose"]]
                + [f"{float(r[c]) / 1e3:.9f}" for c in "xyz"]
                + [f"{float(r['sigma']) / 1e3:.9f}"]
            )
    out = work / "imported_m.mcap"
    assert main(["import", str(m), "--plan", str(work / "plan.toml"), "--out", str(out), "--units", "m"]) == 0
    again = work / "again.csv"
    assert main(["export", str(out), "--csv", str(again)]) == 0
    back = rows_of(again)
    assert len(back) == len(rows)
    for r, s in zip(rows, back):
        assert (r["pose"], r["state"], r["point"]) == (s["pose"], s["state"], s["point"])
        assert max(abs(float(r[c]) - float(s[c])) for c in "xyz") <= 1.01e-6  # mm
        assert s["sigma"] == r["sigma"]


def test_single_state_and_unmeasured_poses(work, capsys):
    rows = [
        r
        for r in rows_of(work / "paper.csv")
        if r["pose"] not in ("3",) and not (r["pose"] == "5" and r["state"] == "loaded")
    ]
    p = write_rows(work / "partial.csv", rows)
    out = work / "partial.mcap"
    assert main(["import", str(p), "--plan", str(work / "plan.toml"), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "no readings for poses [3]" in said and "one state only (no deflection) for poses [5]" in said
    assert "tracker pose: the plan's" in said
    rep = identify_json(out, work / "partial.json")
    assert rep["parameters"][1]["estimate"] == pytest.approx(0.12e-6, rel=0.1)


# --------------------------------------------------------------------------- bad CSVs


def _bad(work: Path, name: str, lines: list[str]) -> tuple[Path, Path]:
    p = work / f"{name}.csv"
    p.write_text("\n".join(lines) + "\n")
    out = work / f"{name}.mcap"
    return p, out


GOOD = "0,unloaded,refl_a,-2224.2929,3033.1675,-59.6551"
HEAD = "pose,state,point,x,y,z"

BAD = {
    # name: (lines, extra args, where, what)
    "unknown_point": (
        [HEAD, "0,unloaded,refl_z,-2224.2929,3033.1675,-59.6551"],
        [],
        "line 2, column point",
        "a reflector site of the robot: refl_a, refl_b, refl_c",
    ),
    "pose_outside": (
        [HEAD, GOOD, "16,loaded,refl_a,-2224.9,3033.0,-61.8"],
        [],
        "line 3, column pose",
        "a pose of the plan: an index in 0..15",
    ),
    "negative_pose": (
        [HEAD, "-1,loaded,refl_a,-2224.9,3033.0,-61.8"],
        [],
        "line 2, column pose",
        "a pose of the plan",
    ),
    "metres_as_mm": (
        [HEAD, "0,unloaded,refl_a,-2.2242929,3.0331675,-0.0596551"],
        [],
        "line 2, column x",
        "is the file in m? --units m",
    ),
    "mm_as_metres": ([HEAD, GOOD], ["--units", "m"], "line 2, column x", "is the file in mm? --units mm"),
    "not_a_number": (
        [HEAD, GOOD, "0,loaded,refl_a,-2224.9,abc,-61.8"],
        [],
        "line 3, column y",
        "expected a number, got 'abc'",
    ),
    "nan": ([HEAD, "0,loaded,refl_a,nan,3033.0,-61.8"], [], "line 2, column x", "a finite number"),
    "missing_state": (
        [HEAD, GOOD, "0,,refl_a,-2224.9,3033.0,-61.8"],
        [],
        "line 3, column state",
        "expected unloaded or loaded, got 'an empty cell'",
    ),
    "unknown_state": (
        [HEAD, "0,heavy,refl_a,-2224.9,3033.0,-61.8"],
        [],
        "line 2, column state",
        "unloaded or loaded",
    ),
    "copied_across_states": (
        [
            HEAD,
            GOOD,
            "0,loaded,refl_b,-2121.8,3076.0,-689.9",
            "0,loaded,refl_a,-2224.2929,3033.1675,-59.6551",
        ],
        [],
        "line 4, column state",
        "line 2 has the same x, y, z",
    ),
    "short_row": (
        [HEAD, "0,unloaded,refl_a,-2224.2929,3033.1675"],
        [],
        "line 2",
        "6 fields as in the header",
    ),
    "unknown_column": (
        ["pose,state,point,x,y,z,temperature", GOOD + ",20.1"],
        [],
        "line 1, column 7",
        "a column named one of",
    ),
    "missing_column": (
        ["pose,state,point,x,y", "0,unloaded,refl_a,1,2"],
        [],
        "line 1",
        "a header row with the columns pose,state,point,x,y,z",
    ),
    "header_only": ([HEAD], [], "line 2", "at least one reading"),
    "blank": ([""], [], "line 1", "a header row with the columns"),
    "time_without_offset": (
        [HEAD + ",time", GOOD + ",2026-01-05T08:00:00"],
        [],
        "line 2, column time",
        "with a UTC offset",
    ),
    "mixed_time_kinds": (
        [HEAD + ",time", GOOD + ",2026-01-05T08:00:00Z", "0,loaded,refl_a,-2224.9,3033.0,-61.8,600"],
        [],
        "line 3, column time",
        "the same kind of time in every row",
    ),
    "loaded_before_unloaded": (
        [HEAD + ",time", GOOD + ",100", "0,loaded,refl_a,-2224.9,3033.0,-61.8,50"],
        [],
        "line 3, column time",
        "the loaded readings of pose 0 after its unloaded",
    ),
    "loaded_before_unloaded_iso": (
        [
            HEAD + ",time",
            GOOD + ",2026-01-05T08:05:00Z",
            "0,loaded,refl_a,-2224.9,3033.0,-61.8,2026-01-05T08:01:00+00:00",
        ],
        [],
        "line 3, column time",
        "got '2026-01-05T08:01:00.000000Z'",
    ),
    "interleaved_poses": (
        [
            HEAD + ",time",
            GOOD + ",0",
            "1,unloaded,refl_a,-2224.9,3033.0,-61.8,10",
            "0,loaded,refl_a,-2224.9,3033.0,-61.8,20",
        ],
        [],
        "line 3, column time",
        "after every reading of pose 0 (a campaign measures one pose at a time), got '10 s'",
    ),
    "sigma_in_um": (
        [HEAD + ",sigma", GOOD + ",20"],
        [],
        "line 2, column sigma",
        "a 1-sigma from 0.0001 to 1 mm",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_csv_names_line_and_column_and_writes_nothing(work, case, capsys):
    lines, extra, where, what = BAD[case]
    p, out = _bad(work, case, lines)
    rc = main(["import", str(p), "--plan", str(work / "plan.toml"), "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert f"{p}: {where}: " in err and what in err, err
    assert err.count("\n") == 1  # one line
    assert not out.exists() and not list(work.glob(f".{case}.mcap*"))  # no output, no temp file


def test_read_readings_groups_repeats(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text(
        "\n".join(
            [HEAD, GOOD, "0,unloaded,refl_a,-2224.3,3033.2,-59.7", "0,unloaded,refl_b,-2121.8,3076.0,-689.9"]
        )
        + "\n"
    )
    t = read_readings(p, 16, NAMES)
    from calbench.bench.shopfloor import group

    g = group(t.of(0, "unloaded"), NAMES)
    assert len(g) == 2 and g[0].visible.tolist() == [True, True, False]
    assert g[1].visible.tolist() == [True, False, False]
    assert g[1].position[0] == pytest.approx([-2.2243, 3.0332, -0.0597])


def test_a_wrong_tracker_pose_in_the_plan_is_refused(work, capsys):
    """The plan's tracker turned by 90 degrees: the readings land metres from its poses."""
    p = work / "plan_turned.toml"
    p.write_text(
        plan_text(True).replace("position = [3.5, -3.5, 3.2]", "yaw = 90.0\nposition = [3.5, -3.5, 3.2]")
    )
    out = work / "turned_plan.mcap"
    assert main(["import", str(work / "paper.csv"), "--plan", str(p), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{work / 'paper.csv'}: line " in err and "seen from its [tracker] position and yaw" in err
    assert not out.exists()


def test_times_travel_through_export_and_import(work):
    """The log's reading times (the campaign clock: bench/scenario/timeline.py) go out as ISO 8601 and
    come back as the imported log's times (to the microsecond the CSV keeps), and they are the
    simulator's schedule (bench.scenario.reading_times), which the iso10360 tracker drifts on."""

    out = work / "imported_times.mcap"
    assert (
        main(["import", str(work / "paper.csv"), "--plan", str(work / "plan.toml"), "--out", str(out)]) == 0
    )
    orig = read_log(work / "paper.mcap")
    back = read_log(out)
    t0 = [m.time for m in orig.measurements]
    assert [abs(a - b.time) <= 1000 for a, b in zip(t0, back.measurements)] == [True] * len(t0)
    sched = reading_times([1] * 16, 3)
    first = min(t0)
    for m in orig.measurements:
        assert abs((m.time - first) / 1e9 - sched[(m.pose, m.state, m.repeat)]) < 1e-6


def test_times_in_seconds_count_from_the_plans_start(work):
    from datetime import datetime

    from calbench.bench.scenario import DEFAULT_START, start_ns

    rows = rows_of(work / "paper.csv")
    t = [datetime.fromisoformat(r["time"].replace("Z", "+00:00")) for r in rows]
    for r, w in zip(rows, t):
        r["time"] = f"{(w - t[0]).total_seconds() + 70.0:.6f}"
    p = write_rows(work / "seconds.csv", rows)
    out = work / "seconds.mcap"
    assert main(["import", str(p), "--plan", str(work / "plan.toml"), "--out", str(out)]) == 0
    log = read_log(out)
    got = sorted({(m.time - start_ns(DEFAULT_START)) / 1e9 for m in log.measurements})
    want = sorted({float(r["time"]) for r in rows})
    assert np.allclose(got, want, rtol=0, atol=1e-6)


def test_an_imported_log_carries_no_truth_and_the_report_says_measured(tmp_path):
    """The importer writes through the one writer, which registers the /truth/ channels; with no
    message on them the log has no truth (has_truth), so the report does not call it simulated."""
    from conftest import PAPER

    from calbench.bench.log import has_truth
    from calbench.identify.cli import main as cli

    sim, csv, imp = tmp_path / "sim.mcap", tmp_path / "r.csv", tmp_path / "imp.mcap"
    assert cli(["simulate", str(PAPER), "--out", str(sim)]) == 0
    assert cli(["export", str(sim), "--csv", str(csv)]) == 0
    plan = tmp_path / "plan.toml"
    text = PAPER.read_text().replace('robot = "../mjcf/', f'robot = "{PAPER.parent.parent}/mjcf/')
    plan.write_text(text)
    assert cli(["import", str(csv), "--plan", str(plan), "--out", str(imp)]) == 0
    assert has_truth(sim) and not has_truth(imp)
    html = tmp_path / "r.html"
    assert cli(["report", str(imp), "--out", str(html)]) == 0
    assert "the log carries ground truth" not in html.read_text()


# --------------------------------------------------------------------------- readings formats


def test_import_dispatches_to_a_toy_readings_format_registered_in_one_file(work, tmp_path, capsys):
    """tests/toy_readings.py (JSON lines, in one file), once registered, reads a .jsonl file for
    `calbench import`: the same readings as the CSV they were written from give the same
    measurements in the log. Unregistered, the file is read as CSV and refused (exit 2, nothing
    written)."""
    from toy_readings import COLUMNS, FORMAT

    from calbench.bench.shopfloor import FORMATS

    lines = [
        json.dumps(
            {
                c: r[c] if c in ("state", "point") else float(r[c]) if c in "xyz" else int(r[c])
                for c in COLUMNS
            }
        )
        for r in rows_of(work / "paper.csv")
    ]
    (tmp_path / "paper.jsonl").write_text("\n".join(lines) + "\n")
    common = ["--plan", str(work / "plan.toml"), "--out"]
    assert main(["import", str(work / "paper.csv"), *common, str(tmp_path / "csv.mcap")]) == 0
    assert FORMATS.for_path(tmp_path / "paper.jsonl").name == "csv"
    assert main(["import", str(tmp_path / "paper.jsonl"), *common, str(tmp_path / "refused.mcap")]) == 2
    assert "line 1" in capsys.readouterr().err and not (tmp_path / "refused.mcap").exists()
    FORMATS.register(FORMAT)
    try:
        with pytest.raises(ValueError, match="already registered"):
            FORMATS.register(FORMAT)
        assert FORMATS.for_path(tmp_path / "paper.jsonl") is FORMAT
        assert FORMATS.for_path(work / "paper.csv").name == "csv"
        assert main(["import", str(tmp_path / "paper.jsonl"), *common, str(tmp_path / "jsonl.mcap")]) == 0
    finally:
        FORMATS.unregister(FORMAT.name)
    a, b = read_log(tmp_path / "csv.mcap"), read_log(tmp_path / "jsonl.mcap")
    assert len(a.measurements) == len(b.measurements) > 0
    for ma, mb in zip(a.measurements, b.measurements):
        assert (ma.pose, ma.state, ma.reflectors) == (mb.pose, mb.state, mb.reflectors)
        np.testing.assert_array_equal(ma.position, mb.position)  # same numbers, same rounding
        np.testing.assert_array_equal(ma.covariance, mb.covariance)
