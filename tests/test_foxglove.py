"""The log's Foxglove topics (bench/log/foxglove.py): valid against Foxglove's official JSON Schemas,
geometrically right when composed the way Foxglove composes frames, written pose by pose, and
free of any true value outside /truth/.

The shipped schemas are the npm package's files (bench/log/foxglove_schemas/LICENSE says how they
were taken); the validator is the reference ``jsonschema`` implementation, draft 2020-12.
"""

from __future__ import annotations

import json
from importlib.resources import files
from pathlib import Path

import jsonschema
import mujoco
import numpy as np
import pytest
from conftest import PAPER, ROOT
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from calbench.bench.campaign import run_campaign
from calbench.bench.log import TRUTH_PREFIX, read_log, strip_truth
from calbench.bench.log import foxglove as fx
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.bench.tracker import to_world_frame

ROUNDING = 1e-7  # m: bench/log/foxglove.py rounds coordinates to 0.1 um


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fox") / "paper.mcap"
    run_campaign(load_scenario(PAPER), out)
    return out


def messages(path: Path) -> list[tuple[str, str, int, dict]]:
    """(topic, schema name, log time, decoded message) of every Foxglove message, file order."""
    out = []
    with open(path, "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            if schema.name.startswith("foxglove."):
                out.append((channel.topic, schema.name, m.log_time, json.loads(m.data)))
    return out


def official(name: str) -> dict:
    return json.loads(files("calbench.bench.log").joinpath("foxglove_schemas", f"{name}.json").read_text())


def stamps(x):
    """Every Foxglove time {sec, nsec} inside a message (a lifetime is a duration)."""
    if isinstance(x, dict):
        if set(x) == {"sec", "nsec"}:
            yield x
        for k, v in x.items():
            if k != "lifetime":
                yield from stamps(v)
    elif isinstance(x, list):
        for v in x:
            yield from stamps(v)


def test_every_foxglove_message_validates_against_the_official_schema(paper_log):
    validators: dict[str, jsonschema.Draft202012Validator] = {}
    counts: dict[str, int] = {}
    with open(paper_log, "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            if not channel.topic.startswith(("/foxglove/", "/truth/foxglove/")):
                assert not schema.name.startswith("foxglove.")
                continue
            assert (schema.encoding, channel.message_encoding) == ("jsonschema", "json")
            assert schema.name == fx.TOPICS[channel.topic]
            if schema.name not in validators:
                js = json.loads(schema.data)
                assert js == official(schema.name)  # the official text, not a copy of ours
                jsonschema.Draft202012Validator.check_schema(js)
                validators[schema.name] = jsonschema.Draft202012Validator(js)
            msg = json.loads(m.data)
            validators[schema.name].validate(msg)
            for s in stamps(msg):  # Foxglove time = the log time
                assert s["sec"] * 10**9 + s["nsec"] == m.log_time
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    n = len(load_scenario(PAPER).poses)
    assert counts == {
        fx.TF: n + 1,
        fx.ROBOT: 1,
        fx.SCENE: n,
        fx.LOG: n + 1,
        fx.TRUTH_TF: n,
        fx.TRUTH_ROBOT: 1,
        fx.TRUTH_SCENE: n,
    }
    # the validators can fail: a missing field and an out-of-range nanosecond are rejected
    v = validators["foxglove.FrameTransforms"]
    bad = {"transforms": [fx.transform(3_999_999_999, "a", "b", [0, 0, 0], fx.IDENTITY)]}
    assert v.is_valid(bad)
    bad["transforms"][0]["timestamp"]["nsec"] = 10**9
    assert not v.is_valid(bad) and not v.is_valid({})
    assert not validators["foxglove.SceneUpdate"].is_valid({"deletions": [], "entities": [{"id": "x"}]})


def _mat(q: dict) -> np.ndarray:
    """Rotation matrix of a Foxglove quaternion {x, y, z, w} (own formula, normalised)."""
    x, y, z, w = (q[k] for k in "xyzw")
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _vec(v: dict) -> np.ndarray:
    return np.array([v["x"], v["y"], v["z"]])


def world_primitives(scene: dict, tf: dict, kind: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(centre, rotation, size) in the world of every ``kind`` primitive of a static scene,
    composed with the frames of one FrameTransforms message as Foxglove does: a point p of the
    child frame is R p + t in the parent (here always the world)."""
    frames = {t["child_frame_id"]: (_mat(t["rotation"]), _vec(t["translation"])) for t in tf["transforms"]}
    frames["world"] = (np.eye(3), np.zeros(3))
    out = []
    for e in scene["entities"]:
        R, t = frames[e["frame_id"]]
        for p in e[kind]:
            out.append(
                (R @ _vec(p["pose"]["position"]) + t, R @ _mat(p["pose"]["orientation"]), _vec(p["size"]))
            )
    return out


def assert_geoms_drawn_where_mujoco_puts_them(model, qpos, scene, tf, prefix=""):
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    cubes = world_primitives(scene, tf, "cubes")
    cyls = world_primitives(scene, tf, "cylinders")
    gt = mujoco.mjtGeom
    n_box = n_cyl = 0
    for g in range(model.ngeom):
        typ = int(model.geom_type[g])
        if typ not in (gt.mjGEOM_BOX, gt.mjGEOM_CYLINDER, gt.mjGEOM_CAPSULE):
            continue
        size = (
            2 * model.geom_size[g][[0, 1, 2]] if typ == gt.mjGEOM_BOX else 2 * model.geom_size[g][[0, 0, 1]]
        )
        prims = cubes if typ == gt.mjGEOM_BOX else cyls
        n_box += typ == gt.mjGEOM_BOX
        n_cyl += typ != gt.mjGEOM_BOX
        R = data.geom_xmat[g].reshape(3, 3)
        hits = [
            1
            for c, Rp, s in prims
            if np.linalg.norm(c - data.geom_xpos[g]) < 10 * ROUNDING
            and np.allclose(s, size, atol=ROUNDING)
            # boxes: the same axes; cylinders: the same z axis (their own x, y are free)
            and (
                np.allclose(Rp, R, atol=1e-6)
                if typ == gt.mjGEOM_BOX
                else np.allclose(Rp[:, 2], R[:, 2], atol=1e-6)
            )
        ]
        assert hits, f"{prefix}geom {model.geom(g).name} not drawn at its MuJoCo pose"
    assert (len(cubes), len(cyls)) == (n_box, n_cyl)


def test_a_foxglove_reader_puts_every_geom_where_mujoco_does(paper_log):
    msgs = messages(paper_log)
    log = read_log(paper_log, include_truth=True)
    robot = Robot.from_xml(log.mjcf_text)
    static = next(m for tp, _, _, m in msgs if tp == fx.ROBOT)
    tfs = [m for tp, _, _, m in msgs if tp == fx.TF][1:]  # one per pose after the start
    true_static = next(m for tp, _, _, m in msgs if tp == fx.TRUTH_ROBOT)
    true_tfs = [m for tp, _, _, m in msgs if tp == fx.TRUTH_TF]
    for p in (0, 7, 15):
        q = log.poses[p].unloaded
        assert_geoms_drawn_where_mujoco_puts_them(
            robot.model,
            robot.rigid_qpos(q),
            {"entities": [e for e in static["entities"] if e["id"] != "tracker"]},
            tfs[p],
        )
        qpos = log.truth.joints[p].loaded.qpos
        assert_geoms_drawn_where_mujoco_puts_them(
            robot.model,
            qpos,
            {"entities": [e for e in true_static["entities"] if e["frame_id"].startswith("true_loaded/")]},
            true_tfs[p],
            "true loaded ",
        )
    # the tracker frame is the scenario's tracker
    tr = next(t for t in tfs[0]["transforms"] if t["child_frame_id"] == fx.TRACKER)
    np.testing.assert_allclose(_vec(tr["translation"]), load_scenario(PAPER).tracker.position)


def test_measured_arrows_are_the_magnified_mean_deflections(paper_log):
    """Against an independent reduction of /tracker/measurement: mean of the repeats per state,
    tracker -> world, loaded - unloaded, times 200."""
    spec = load_scenario(PAPER).tracker
    log = read_log(paper_log)
    scenes = [m for tp, _, _, m in messages(paper_log) if tp == fx.SCENE]
    assert len(scenes) == len(log.complete_poses)
    names = log.header["reflectors"]
    for p, scene in zip(log.complete_poses, scenes):
        mean = {}
        for state in ("unloaded", "loaded"):
            reps = [m for m in log.measurements if m.pose == p and m.state == state]
            vis = np.array([r.visible for r in reps])
            pos = np.array([np.where(r.visible[:, None], r.position, 0.0) for r in reps])
            with np.errstate(invalid="ignore"):  # never seen: 0/0, a NaN row as wanted
                mean[state] = to_world_frame(spec, pos.sum(axis=0) / vis.sum(axis=0)[:, None])
        d = mean["loaded"] - mean["unloaded"]
        ok = np.all(np.isfinite(d), axis=1)
        arrows = next(e for e in scene["entities"] if e["id"] == "deflection_x200")["arrows"]
        assert len(arrows) == ok.sum() > 0
        for a, i in zip(arrows, np.flatnonzero(ok)):
            tail = _vec(a["pose"]["position"])
            vec = _mat(a["pose"]["orientation"])[:, 0] * (a["shaft_length"] + a["head_length"])
            np.testing.assert_allclose(tail, mean["unloaded"][i], atol=ROUNDING)
            np.testing.assert_allclose(vec, fx.MAGNIFY * d[i], atol=10 * ROUNDING)
        spheres = next(e for e in scene["entities"] if e["id"] == "measured/loaded")["spheres"]
        seen = np.flatnonzero(np.all(np.isfinite(mean["loaded"]), axis=1))
        got = np.array([_vec(s["pose"]["position"]) for s in spheres])
        np.testing.assert_allclose(got, mean["loaded"][seen], atol=ROUNDING)
        meta = {
            m["key"]: m["value"]
            for e in scene["entities"]
            if e["id"] == "deflection_x200"
            for m in e["metadata"]
        }
        assert meta == {
            "magnification": "200",
            **{names[i]: f"{np.linalg.norm(d[i]) * 1e6:.1f} um" for i in np.flatnonzero(ok)},
        }


def test_each_pose_writes_its_foxglove_messages_before_its_pose_done(paper_log):
    """Crash tolerance: in file order, pose p's Foxglove messages lie between the markers of
    poses p-1 and p (pose_done ends a chunk, so a crash keeps them with their pose)."""
    topics: dict[int, str] = {}
    since_done: list[str] = []
    per_pose = []
    with open(paper_log, "rb") as f:
        for rec in StreamReader(f).records:
            if isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                topic = topics[rec.channel_id]
                if topic == "/campaign/pose_done":
                    per_pose.append(since_done)
                    since_done = []
                elif "foxglove" in topic:
                    since_done.append(topic)
    assert since_done == []
    first = {fx.TF, fx.ROBOT, fx.LOG, fx.TRUTH_ROBOT}
    for p, seen in enumerate(per_pose):
        per = [fx.TF, fx.SCENE, fx.LOG, fx.TRUTH_TF, fx.TRUTH_SCENE]
        assert sorted(set(seen)) == sorted(set(per) | (first if p == 0 else set())), p
        assert sorted(seen) == sorted(per + ([fx.TF, fx.ROBOT, fx.LOG, fx.TRUTH_ROBOT] if p == 0 else []))


def _numbers_3(x, out):
    """Every {x, y, z} triple in a message (positions, translations, sizes)."""
    if isinstance(x, dict):
        if {"x", "y", "z"} <= set(x) and "w" not in x:
            out.add((x["x"], x["y"], x["z"]))
        for v in x.values():
            _numbers_3(v, out)
    elif isinstance(x, list):
        for v in x:
            _numbers_3(v, out)
    return out


def test_stripped_log_keeps_the_foxglove_view_and_no_true_value(paper_log, tmp_path):
    public = tmp_path / "public.mcap"
    strip_truth(paper_log, public)
    full, stripped = messages(paper_log), messages(public)
    assert {tp for tp, *_ in stripped} == {fx.TF, fx.ROBOT, fx.SCENE, fx.LOG}
    assert [m for m in full if not m[0].startswith(TRUTH_PREFIX)] == stripped
    # no true position appears on a public topic: the true reflectors, the body frames and the
    # flange at the true equilibria (those that differ from the commanded ones at all)
    log = read_log(paper_log, include_truth=True)
    robot = Robot.from_xml(log.mjcf_text)
    data = mujoco.MjData(robot.model)
    shown = set()
    for _, _, _, m in stripped:
        _numbers_3(m, shown)
    shown = np.array(sorted(shown))

    def positions(qpos):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(robot.model, data)
        return np.vstack([data.xpos, data.site_xpos, data.geom_xpos])

    secrets = []
    for p in log.complete_poses:
        commanded = positions(robot.rigid_qpos(log.poses[p].unloaded))
        for state in ("unloaded", "loaded"):
            true = positions(log.truth.joints[p].get(state).qpos)
            moved = np.linalg.norm(true - commanded, axis=1) > 1e-6
            secrets.append(true[moved])
            secrets.append(log.truth.reflectors[p].get(state).position_world)
    secrets = np.vstack(secrets)
    assert len(secrets) > 100
    dist = np.min(np.linalg.norm(shown[:, None, :] - secrets[None, :, :], axis=2), axis=0)
    # a leaked value would sit within the rounding; the nearest honest one (a measured
    # reflector) is tracker noise away, ~20 um
    assert dist.min() > 1e-6, dist.min()


def test_layout_opens_the_3d_panel_on_these_topics(paper_log):
    layout = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
    panels = layout["configById"]
    three_d = [v for k, v in panels.items() if k.startswith("3D!")]
    assert len(three_d) == 1
    named = set(three_d[0]["topics"])
    assert {fx.TF, fx.ROBOT, fx.SCENE} <= named <= set(fx.TOPICS)
    assert three_d[0]["followTf"] == fx.WORLD
    with open(paper_log, "rb") as f:
        in_log = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert named <= in_log


def test_the_writer_hook_keeps_channels_and_times_honest(tmp_path):
    """LogWriter.add_channel/next_time/write: no re-registered topic, no message on an unknown
    channel, no time that goes back, no message its channel's schema rejects."""
    from calbench.bench.log import LogHeader, LogWriter

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
            "distance": [0.0, 0.0],
            "transverse": [0.0, 0.0],
        },
        1,
    )
    with LogWriter(tmp_path / "x.mcap", header) as w:
        w.add_channel(fx.LOG, "foxglove.Log", fx.schema_text("foxglove.Log"))
        with pytest.raises(ValueError):
            w.add_channel(fx.LOG, "foxglove.Log", fx.schema_text("foxglove.Log"))
        with pytest.raises(ValueError):
            w.add_channel("/campaign/pose", "foxglove.Log", fx.schema_text("foxglove.Log"))
        t = w.next_time(5)
        w.write(fx.LOG, fx.log_message(t, "hello"), t)
        with pytest.raises(ValueError):  # not after the last message
            w.write(fx.LOG, fx.log_message(t, "again"), t)
        with pytest.raises(ValueError):  # never registered
            w.write(fx.SCENE, fx.scene_update([]), w.next_time(0))
        with pytest.raises(ValueError):  # the schema requires "name"
            msg = fx.log_message(w.next_time(0), "x")
            del msg["name"]
            w.write(fx.LOG, msg, w.next_time(0))
    msgs = messages(tmp_path / "x.mcap")
    assert [(tp, t_, m["message"]) for tp, _, t_, m in msgs] == [(fx.LOG, t, "hello")]
