"""Timestamps (issue 10): a log's times start at the scenario's start_time, every message in
causal order (pose, unloaded readings, wrench, loaded readings, pose done), each step lasting
bench/scenario/timeline.py's durations; the default start is fixed, so logs stay byte-identical.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime

import badcases as bc
import pytest
from mcap.records import Channel, Message

from calbench.bench.log import scan
from calbench.bench.scenario import parse_scenario
from calbench.bench.scenario import timeline as tl
from calbench.identify.cli import main

NS = 10**9
SLACK = 10  # ns


def messages(path):
    topics, out = {}, []
    for r in scan(path):
        if isinstance(r, Channel):
            topics[r.id] = r.topic
        elif isinstance(r, Message):
            out.append((r.log_time, topics[r.channel_id], json.loads(r.data)))
    return out


def kind(topic: str, m: dict) -> str:
    return topic.split("/")[-1] + (f"/{m['state']}" if "state" in m and topic != "/campaign/wrench" else "")


@pytest.fixture(scope="module")
def timed_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("t")
    scn = d / "t.toml"
    scn.write_text(bc.scenario_text(n_poses=3, repeats=2, extra='start_time = "2024-03-01T09:30:00+01:00"'))
    out = d / "t.mcap"
    assert main(["simulate", str(scn), "--out", str(out)]) == 0
    return out


def test_times_start_at_the_scenario_start_time(timed_log):
    msgs = messages(timed_log)
    start = datetime(2024, 3, 1, 8, 30, tzinfo=UTC)  # 09:30 at +01:00
    assert msgs[0][0] == tl.start_ns(start) and msgs[0][1] == "/campaign/info"
    times = [t for t, _, _ in msgs]
    assert times == sorted(times) and len(set(times)) == len(times)  # file order is time order


def test_each_pose_in_causal_order_with_the_documented_durations(timed_log):
    msgs = [
        (t, tp, m)
        for t, tp, m in messages(timed_log)
        if not tp.startswith(("/truth/", "/foxglove/")) and "pose" in m
    ]
    n_refl = 3
    read = tl.READING_PER_REFLECTOR_S * n_refl
    prev_done = None
    for p in range(3):
        mine = [(t, kind(tp, m)) for t, tp, m in msgs if m["pose"] == p]
        order = [k for _, k in mine]
        assert order == [
            "pose/unloaded",
            "measurement/unloaded",
            "measurement/unloaded",
            "wrench",
            "pose/loaded",
            "measurement/loaded",
            "measurement/loaded",
            "pose_done",
        ], order

        t0 = mine[0][0]
        if prev_done is not None:
            assert 0 < t0 - prev_done <= SLACK  # the next pose starts when one is done
        step = [b - a for (a, _), (b, _) in zip(mine, mine[1:])]
        # the truth and Foxglove messages between two steps take 1 ns each: SLACK
        expected = [tl.MOVE_S + read, read, tl.LOAD_S, 0, read, read, tl.UNLOAD_S]
        for got, want in zip(step, expected):  # drive + first reading, second reading, hang the
            assert 0 <= got - want * NS <= SLACK, (got, want)  # load, command, readings, off
        prev_done = mine[-1][0]


def test_the_default_start_is_fixed_and_logs_are_byte_identical(tmp_path):
    scn = tmp_path / "d.toml"
    scn.write_text(bc.scenario_text(n_poses=2))
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    assert main(["simulate", str(scn), "--out", str(a)]) == 0
    assert main(["simulate", str(scn), "--out", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()
    assert messages(a)[0][0] == tl.start_ns(tl.DEFAULT_START)


@pytest.mark.parametrize(
    "value, words",
    [
        ('"yesterday"', "ISO 8601"),
        ('"2024-03-01T09:30:00"', "UTC offset"),  # no offset: which clock?
        ("2024-03-01T09:30:00", "UTC offset"),  # a TOML local date-time
        ("2024-03-01", "ISO 8601"),  # a date only
        ('"1900-01-01T00:00:00Z"', "between 1970"),
        ("3", "ISO 8601"),
    ],
)
def test_a_bad_start_time_is_refused(tmp_path, capsys, value, words):
    scn = tmp_path / "b.toml"
    scn.write_text(bc.scenario_text(n_poses=1, extra=f"start_time = {value}"))
    out = tmp_path / "b.mcap"
    assert main(["simulate", str(scn), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "start_time" in err and words in err and not out.exists()


def test_start_time_forms_that_mean_the_same_instant(tmp_path):
    forms = [
        '"2024-03-01T08:30:00Z"',
        "2024-03-01T08:30:00Z",
        '"2024-03-01T09:30:00+01:00"',
        "2024-03-01 08:30:00+00:00",
    ]
    got = set()
    for v in forms:
        text = bc.scenario_text(n_poses=1, extra=f"start_time = {v}")
        got.add(parse_scenario(text, tmp_path / "s.toml").start_time)
    assert got == {datetime(2024, 3, 1, 8, 30, tzinfo=UTC)}


def test_durations_in_words():
    assert tl.duration(30) == "30 s" and tl.duration(600) == "10 min"
    assert tl.duration(3 * 3600) == "3 h" and tl.duration(1e11) == "3,169 years"
    assert tl.size(4.8e6) == "4.8 MB" and tl.size(6e11) == "600 GB"
