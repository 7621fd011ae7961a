"""Inputs of a chosen size for the memory tests (tests/test_sizes.py) and benchmarks/sizes_bench.py:
a readings CSV of N rows along the paper plan, and a campaign log of P poses of R readings each
made from a simulated one.

Both are what a user could hand calbench: the CSV has the paper plan's reflectors where rigid
kinematics puts them (what `calbench import` compares a placed tracker with), 20 um noise,
loaded 1 mm lower, times in seconds; the log repeats the simulated log's poses (its commands,
loads and first readings, with 20 um noise added to every repeat) under a header planning P
poses. Every reader check applies to them as to any file.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

import numpy as np

from calbench.bench.log import LogHeader, LogWriter, read_log
from calbench.bench.model import Robot
from calbench.bench.scenario import load_plan
from calbench.bench.tracker import tracker_rotation
from calbench.identify.shopfloor import rigid_points

NAMES = ["refl_a", "refl_b", "refl_c"]


def readings_file(path: Path, plan_file: Path, rows: int, seed: int = 0) -> Path:
    """About ``rows`` readings along the plan (module docstring), every pose in both states."""
    plan = load_plan(plan_file)
    robot = Robot.from_file(plan.robot)
    keys = [(p, n) for p in range(len(plan.poses)) for n in NAMES]
    world = rigid_points(robot, plan, keys).reshape(len(plan.poses), len(NAMES), 3)
    base = (world - plan.tracker.position) @ tracker_rotation(plan.tracker) * 1e3  # mm, tracker frame
    k = max(rows // (len(plan.poses) * 2 * len(NAMES)), 1)
    rng = np.random.default_rng(seed)
    with open(path, "w") as f:
        f.write("pose,state,point,x,y,z,time\n")
        for p in range(len(plan.poses)):
            for s, shift in (("unloaded", 0.0), ("loaded", -1.0)):
                xyz = base[p] + [0.0, 0.0, shift] + rng.normal(0, 0.02, (k, len(NAMES), 3))
                for j in range(k):
                    t = 1000 * p + (500 if s == "loaded" else 0) + 0.01 * j
                    f.writelines(
                        f"{p},{s},{name},{x:.6f},{y:.6f},{z:.6f},{t:.2f}\n"
                        for name, (x, y, z) in zip(NAMES, xyz[j])
                    )
    return path


@contextlib.contextmanager
def _no_fsync():
    """The writer makes every pose durable (fsync); a made-up log need not wait for the disk."""
    real = os.fsync
    os.fsync = lambda fd: None
    try:
        yield
    finally:
        os.fsync = real


def replicated_log(src: Path, out: Path, poses: int, repeats: int, seed: int = 0, fast: bool = False) -> Path:
    """A log of ``poses`` poses, ``repeats`` readings per state each, from the simulated log
    ``src`` (module docstring). ``fast`` writes the readings' JSON straight into the MCAP writer,
    skipping LogWriter's own checks (a benchmark's gigabytes; the reader checks them all)."""
    log = read_log(src)
    h = log.header
    header = LogHeader(
        scenario_name=h["scenario_name"],
        scenario_text=log.scenario_text or "",
        scenario_filename="replicated.toml",
        robot_filename=h["robot"],
        mjcf_text=log.mjcf_text or "",
        reflectors=list(h["reflectors"]),
        payload_site=h["payload_site"],
        tracker=h["tracker"],
        seed=h["seed"],
        n_poses=poses,
        n_joints=h.get("n_joints"),
    )
    names = list(h["reflectors"])
    rng = np.random.default_rng(seed)
    src_poses = log.complete_poses
    # fast: every (source pose, state, repeat)'s message encoded once, the pose index spliced in
    templates: dict = {}
    with _no_fsync(), LogWriter(out, header) as w:
        for p in range(poses):
            s = src_poses[p % len(src_poses)]
            q, wr = log.poses[s].unloaded, log.wrenches[s]
            w.pose(p, "unloaded", q)
            for state in ("unloaded", "loaded"):
                if state == "loaded":
                    w.wrench(p, wr.force, wr.moment, wr.site, wr.mass)
                    w.pose(p, "loaded", q)
                m = log.readings(s, state)[0].in_order(names)
                if fast:
                    key = (s, state)
                    if key not in templates:
                        noise = rng.normal(0, 2e-5, (repeats, *m.position.shape))
                        templates[key] = [
                            _encoded(state, r, names, m.position + noise[r], m.covariance, m.visible)
                            for r in range(repeats)
                        ]
                    head = b'{"pose":' + str(p).encode()
                    for tail in templates[key]:
                        _add(w, head + tail)
                    continue
                noise = rng.normal(0, 2e-5, (repeats, *m.position.shape))
                for r in range(repeats):
                    w.measurement(p, state, r, names, m.position + noise[r], m.covariance, m.visible)
            w.pose_done(p)
    return out


def _encoded(state, repeat, names, pos, cov, visible) -> bytes:
    """A reading's JSON after its pose index: ``,"state":...}``."""
    vis = [bool(v) for v in visible]
    msg = {
        "pose": 0,
        "state": state,
        "repeat": repeat,
        "reflectors": names,
        "position": [p.tolist() if v else None for p, v in zip(pos, vis)],
        "covariance": [c.tolist() if v else None for c, v in zip(cov, vis)],
        "visible": vis,
    }
    text = json.dumps(msg, separators=(",", ":")).encode()
    return text[len(b'{"pose":0') :]


def _add(w: LogWriter, data: bytes) -> None:
    t = w.clock.advance(1.0)
    w._last_time = t
    w._writer.add_message(
        channel_id=w._channels["/tracker/measurement"], log_time=t, data=data, publish_time=t, sequence=0
    )
