"""Logs are input (issue 10): the one reader (bench/log/read.py) refuses a damaged or impossible
log whole, naming topic, pose and field, and every verb gives the same answer; a cut-short log
keeps its complete poses and every verb says what was lost.

Each bad log is made from a good one with tests/badcases.py, which works on the bytes with the
mcap library alone. Every refusal is checked through the real command line too: exit status 2,
one line, no traceback, no output file, the input unchanged.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import badcases as bc
import numpy as np
import pytest
from conftest import PAPER

from calbench.bench.core import InputError
from calbench.bench.log import CorruptLogError, Damage, LogHeader, LogWriter, read_log, scan
from calbench.identify.cli import main

VERBS = {  # every verb that reads a log, with the output it would write
    "identify": lambda log, tmp: ["identify", str(log), "--json", str(tmp / "id.json")],
    "discover": lambda log, tmp: ["discover", str(log), "--json", str(tmp / "d.json")],
    "view": lambda log, tmp: ["view", str(log), "--rrd", str(tmp / "v.rrd")],
    "report": lambda log, tmp: ["report", str(log), "--out", str(tmp / "r.html")],
    "export": lambda log, tmp: ["export", str(log), "--csv", str(tmp / "e.csv")],
}


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("paper") / "paper.mcap"
    assert main(["simulate", str(PAPER), "--out", str(out)]) == 0
    return out


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def refused_by_every_verb(log: Path, tmp: Path, capsys, *words: str) -> str:
    """Run every verb on ``log``: exit 2, one line naming the log and ``words``, no output file,
    the log unchanged. Returns the message (the same for every verb)."""
    before = digest(log)
    messages = set()
    for verb, argv in VERBS.items():
        out = tmp / verb
        out.mkdir(exist_ok=True)
        rc = main(argv(log, out))
        err = capsys.readouterr().err.strip()
        assert rc == 2, (verb, err)
        assert len(err.splitlines()) == 1 and "Traceback" not in err, err
        assert str(log) in err and all(w in err for w in words), (verb, err)
        assert list(out.iterdir()) == [], (verb, list(out.iterdir()))
        messages.add(err.split(": error: ", 1)[1])
    assert digest(log) == before
    assert len(messages) == 1, messages  # one reader, one answer
    return messages.pop()


def mutate(paper_log: Path, tmp: Path, topic: str, fn, pose: int = 3) -> Path:
    return bc.rewrite_json(paper_log, tmp / "bad.mcap", bc.edit_pose(topic, pose, fn))


# --------------------------------------------------------------------------- the cases


def test_a_five_element_q(paper_log, tmp_path, capsys):
    bad = mutate(paper_log, tmp_path, "/campaign/pose", lambda m: m.update(q=m["q"][:5]))
    msg = refused_by_every_verb(bad, tmp_path, capsys, "/campaign/pose pose 3", "q", "6 items")
    assert "calbench recover" in msg


def test_a_missing_visible_key(paper_log, tmp_path, capsys):
    bad = mutate(paper_log, tmp_path, "/tracker/measurement", lambda m: m.pop("visible"))
    refused_by_every_verb(bad, tmp_path, capsys, "/tracker/measurement pose 3", "visible", "required")


def test_a_string_where_a_position_belongs(paper_log, tmp_path, capsys):
    bad = mutate(
        paper_log, tmp_path, "/tracker/measurement", lambda m: m["position"].__setitem__(0, "1.0, 2.0, 3.0")
    )
    refused_by_every_verb(bad, tmp_path, capsys, "/tracker/measurement pose 3", "position[0]")


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_a_non_finite_position_is_never_computed_with(paper_log, tmp_path, capsys, value):
    bad = mutate(
        paper_log, tmp_path, "/tracker/measurement", lambda m: m["position"][0].__setitem__(2, value)
    )
    refused_by_every_verb(
        bad, tmp_path, capsys, "/tracker/measurement pose 3", "position[0][2]", "finite number"
    )


@pytest.mark.parametrize(
    "cov, why",
    [
        ([[4e-10, 0, 0], [0, float("nan"), 0], [0, 0, 4e-10]], "finite number"),
        ([[4e-10, 1e-10, 0], [0, 4e-10, 0], [0, 0, 4e-10]], "symmetric positive definite"),
        ([[4e-10, 0, 0], [0, -4e-10, 0], [0, 0, 4e-10]], "symmetric positive definite"),
    ],
)
def test_a_covariance_that_cannot_be_one(paper_log, tmp_path, capsys, cov, why):
    def edit(m):
        i = m["visible"].index(True)
        m["covariance"][i] = cov

    bad = mutate(paper_log, tmp_path, "/tracker/measurement", edit)
    refused_by_every_verb(bad, tmp_path, capsys, "/tracker/measurement pose 3", "covariance", why)


def test_a_reading_whose_lists_disagree(paper_log, tmp_path, capsys):
    bad = mutate(paper_log, tmp_path, "/tracker/measurement", lambda m: m.update(visible=m["visible"][:-1]))
    refused_by_every_verb(
        bad, tmp_path, capsys, "/tracker/measurement pose 3", "visible", "one per reflector"
    )


def test_visible_with_a_null_position(paper_log, tmp_path, capsys):
    def edit(m):
        i = m["visible"].index(True)
        m["position"][i] = None

    bad = mutate(paper_log, tmp_path, "/tracker/measurement", edit)
    refused_by_every_verb(bad, tmp_path, capsys, "/tracker/measurement pose 3", "null exactly where")


def test_a_pose_index_outside_the_plan_is_a_corrupt_log(paper_log, tmp_path, capsys):
    """Pose 999 in a 16-pose campaign: not a 17th pose."""
    bad = bc.rewrite_json(
        paper_log, tmp_path / "p999.mcap", lambda t, m: {**m, "pose": 999} if m.get("pose") == 15 else m
    )
    refused_by_every_verb(bad, tmp_path, capsys, "pose 999", "0..15", "n_poses = 16")


def test_a_message_given_twice(paper_log, tmp_path, capsys):
    seen = []

    def edit(t, m):
        if t == "/campaign/wrench" and m["pose"] == 4:
            seen.append(m)
        if t == "/campaign/wrench" and m["pose"] == 5:
            return seen[0]  # pose 4's wrench again, instead of pose 5's
        return m

    bad = bc.rewrite_json(paper_log, tmp_path / "dup.mcap", edit)
    refused_by_every_verb(bad, tmp_path, capsys, "/campaign/wrench pose 4", "each message once")


def test_a_reading_of_a_reflector_the_header_does_not_list(paper_log, tmp_path, capsys):
    """view, report and export accepted it (identify and discover refused it in their own words);
    with an empty header list view and discover gave a traceback."""
    bad = mutate(
        paper_log, tmp_path, "/tracker/measurement", lambda m: m["reflectors"].__setitem__(0, "refl_zz")
    )
    refused_by_every_verb(
        bad,
        tmp_path,
        capsys,
        "/tracker/measurement pose 3 unloaded repeat 0",
        "reflectors",
        "refl_a, refl_b, refl_c",
        "refl_zz",
    )
    empty = bc.rewrite_json(
        paper_log,
        tmp_path / "empty.mcap",
        lambda t, m: {**m, "reflectors": []} if t == "/campaign/info" else m,
    )
    refused_by_every_verb(empty, tmp_path, capsys, "/tracker/measurement pose 0", "lists (none)")


def test_readings_of_one_pose_with_different_reflector_lists(paper_log, tmp_path, capsys):
    """The rows of a pose's readings are matched by position: a reordered list in one reading
    would pair different reflectors."""
    bad = mutate(
        paper_log,
        tmp_path,
        "/tracker/measurement",
        lambda m: {**m, **{k: m[k][::-1] for k in ("reflectors", "position", "covariance", "visible")}},
    )
    refused_by_every_verb(
        bad, tmp_path, capsys, "/tracker/measurement pose 3", "reflectors", "the pose's first reading"
    )


def test_a_pose_commanded_differently_in_its_two_states(paper_log, tmp_path, capsys):
    """A pose is one command; view, report and export drew and exported such a pose."""

    def edit(t, m):
        if t == "/campaign/pose" and m["pose"] == 3 and m["state"] == "loaded":
            m["q"][1] += 0.1
        return m

    bad = bc.rewrite_json(paper_log, tmp_path / "qdiff.mcap", edit)
    refused_by_every_verb(
        bad, tmp_path, capsys, "/campaign/pose pose 3 loaded: q", "the command of the unloaded state"
    )


def test_recover_drops_the_poses_the_reader_refuses(paper_log, tmp_path, capsys):
    """What the reader refuses, recover leaves out, naming why; the rest reads."""

    def edit(t, m):
        if t == "/campaign/pose" and m["pose"] == 3 and m["state"] == "loaded":
            m["q"][1] += 0.1
        if t == "/tracker/measurement" and m["pose"] == 7 and m["state"] == "loaded":
            m["reflectors"][2] = "refl_zz"
        return m

    bad = bc.rewrite_json(paper_log, tmp_path / "two.mcap", edit)
    fixed = tmp_path / "fixed.mcap"
    assert main(["recover", str(bad), "--out", str(fixed)]) == 0
    out = capsys.readouterr().out
    assert "dropped pose 3 (its command differs" in out and "pose 7 (its readings name other" in out
    rec = read_log(fixed)
    assert rec.lost_poses == [3, 7] and rec.complete_poses == [p for p in range(16) if p not in (3, 7)]


def test_not_json(paper_log, tmp_path, capsys):
    bad = mutate(paper_log, tmp_path, "/campaign/wrench", lambda m: b'{"pose": 3, "force": [1,')
    refused_by_every_verb(bad, tmp_path, capsys, "/campaign/wrench", "not JSON")


def test_a_bit_flipped_chunk_that_still_decompresses(paper_log, tmp_path, capsys):
    """Only the chunk's CRC tells: every verb refuses the log alike (before, `discover` used 15
    of 16 poses of such a log while `identify` refused it)."""
    bad = bc.flip_bit_in_chunk(paper_log, tmp_path / "flip.mcap", seed=1)
    refused_by_every_verb(bad, tmp_path, capsys, "Chunk", "CRC mismatch")


def test_a_damaged_attachment(paper_log, tmp_path, capsys):
    data = bytearray(paper_log.read_bytes())
    i = data.index(b"<mujoco")  # the MJCF attachment travels uncompressed
    data[i + 1] ^= 0x01
    bad = tmp_path / "att.mcap"
    bad.write_bytes(bytes(data))
    refused_by_every_verb(bad, tmp_path, capsys, "Attachment", "CRC mismatch")


def test_a_damaged_metadata_record_fails_the_data_section_crc(paper_log, tmp_path, capsys):
    data = bytearray(paper_log.read_bytes())
    i = data.index(b'"scenario"') if b'"scenario"' in data else data.index(b"scenario")
    data[data.index(b"Klimchik", i)] ^= 0x20  # the scenario text in the metadata record
    bad = tmp_path / "meta.mcap"
    bad.write_bytes(bytes(data))
    refused_by_every_verb(bad, tmp_path, capsys, "DataEnd", "metadata")


def test_a_missing_channel(paper_log, tmp_path, capsys):
    bad = bc.drop_topic(paper_log, tmp_path / "nowrench.mcap", "/campaign/wrench")
    refused_by_every_verb(bad, tmp_path, capsys, "/campaign/wrench")


# --------------------------------------------------------------------------- cut short


def test_a_cut_log_every_verb_says_what_was_lost(paper_log, tmp_path, capsys):
    cut = bc.truncate(paper_log, tmp_path / "cut.mcap", int(paper_log.stat().st_size * 0.6))
    log = read_log(cut)
    n = len(log.complete_poses)
    assert 0 < n < 16 and log.truncated and log.lost_poses == list(range(n, 16))
    line = log.completeness()
    assert f"{n} of 16 planned poses complete, {16 - n} lost [{n}-15]" in line
    assert "cut short" in line
    for verb in ("discover", "view", "export"):
        out = tmp_path / verb
        out.mkdir()
        assert main(VERBS[verb](cut, out)) == 0
        assert line in capsys.readouterr().out, verb
    rep = json.loads((tmp_path / "discover" / "d.json").read_text())
    assert rep["lost_poses"] == list(range(n, 16)) and rep["truncated"] is True
    assert main(VERBS["identify"](cut, tmp_path)) == 0
    assert f"{16 - n} lost" in capsys.readouterr().out


def test_a_finished_file_cut_is_damage_not_a_crash(paper_log, tmp_path):
    """A record whose length runs past the end of a file that ends with the closing magic: the
    file was not cut by a crash, it is damaged."""
    data = bytearray(paper_log.read_bytes())
    spans = bc.chunk_spans(bytes(data))
    start = spans[3][0]
    data[start + 1 : start + 9] = (10**9).to_bytes(8, "little")  # the chunk's record length
    bad = tmp_path / "len.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(CorruptLogError, match="runs past the end"):
        read_log(bad)


def test_an_opcode_flipped_to_an_unknown_one_is_noticed(paper_log, tmp_path):
    """MCAP readers skip unknown records; the chunk's message indexes and the summary's
    statistics notice the chunk that vanished."""
    data = bytearray(paper_log.read_bytes())
    start = bc.chunk_spans(bytes(data))[4][0]
    data[start] = 0x80  # a private opcode: skipped
    bad = tmp_path / "op.mcap"
    bad.write_bytes(bytes(data))
    assert any(isinstance(e, Damage) for e in scan(bad))
    with pytest.raises(CorruptLogError, match="MessageIndex"):
        read_log(bad)


# --------------------------------------------------------------------------- earlier logs


def test_logs_of_the_previous_version_still_read(paper_log, tmp_path):
    """Times from 1970 (the old synthetic clock), no data-section CRC, no campaign_end record:
    read as before, with the same readings."""
    from mcap.records import Attachment, Channel, Message, Metadata, Schema
    from mcap.writer import CompressionType, Writer

    older = tmp_path / "older.mcap"
    t0 = None
    with open(older, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)  # mcap's default: no data CRC
        w.start()
        ids, sids = {}, {}
        for r in scan(paper_log):
            if isinstance(r, Schema) and r.id not in sids:
                sids[r.id] = w.register_schema(r.name, r.encoding, r.data)
            elif isinstance(r, Channel) and r.id not in ids:
                ids[r.id] = w.register_channel(r.topic, r.message_encoding, sids[r.schema_id])
            elif isinstance(r, Message):
                t0 = r.log_time if t0 is None else t0
                w.add_message(ids[r.channel_id], r.log_time - t0, r.data, r.log_time - t0, r.sequence)
            elif isinstance(r, Metadata) and r.name != "campaign_end":
                w.add_metadata(r.name, dict(r.metadata))
            elif isinstance(r, Attachment):
                w.add_attachment(0, 0, r.name, r.media_type, r.data)
        w.finish()
    new, old = read_log(paper_log, include_truth=True), read_log(older, include_truth=True)
    assert old.complete_poses == list(range(16)) and old.end == "finished" and not old.truncated
    assert len(old.measurements) == len(new.measurements)
    for a, b in zip(old.measurements, new.measurements):
        assert np.array_equal(a.position, b.position, equal_nan=True)


def test_a_synthetic_writer_log_keeps_its_own_checks(tmp_path):
    """The writer refuses what the reader would refuse, so a calbench log never needs it."""
    header = LogHeader(
        "s",
        "seed = 1\n",
        "s.toml",
        "r.xml",
        "<mujoco/>",
        ["R1"],
        "payload",
        {
            "position": [1.0, 0, 0],
            "yaw": 0.0,
            "model": "isotropic",
            "sigma": 2e-5,
            "distance": [1e-5, 0.0],
            "transverse": [1e-5, 0.0],
        },
        1,
        n_poses=1,
    )
    with LogWriter(tmp_path / "w.mcap", header) as w:
        with pytest.raises(ValueError):
            w.measurement(0, "unloaded", 0, ["R1"], [[np.inf, 0, 0]], np.eye(3)[None] * 1e-10, [True])
        w.pose(0, "unloaded", np.zeros(6))
        w.measurement(0, "unloaded", 0, ["R1"], [[1.0, 0, 0]], np.eye(3)[None] * 1e-10, [True])
        w.wrench(0, [0, 0, -1.0], [0, 0, 0], "payload", None)
        w.pose(0, "loaded", np.zeros(6))
        w.measurement(0, "loaded", 0, ["R1"], [[1.0, 0, 0]], np.eye(3)[None] * 1e-10, [True])
        w.pose_done(0)
    log = read_log(tmp_path / "w.mcap")
    assert log.complete_poses == [0] and log.end == "finished" and log.completeness() is None


def test_not_mcap_is_an_input_error_naming_the_magic(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_text("hello")
    with pytest.raises(InputError, match="magic bytes"):
        read_log(p)
