"""A compensation job (docs/contract.md, "Job file"): a path of nominal joint commands, each with
the process load, and the tool point that must land on target.

Read through :class:`calbench.bench.core.Table`, so every mistake names the file, the key and
what was expected (exit status 2): a point outside the joint limits, a wrench whose size says it
is in the wrong units, a tool body the robot does not have.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import InputError, Table, frozen_array, parse_toml, read_text
from calbench.bench.model import Robot
from calbench.bench.scenario import check_commands

# A wrench is "plausible" below these sizes: the heaviest industrial robots carry 2.3 t (23 kN);
# 100 kN and 100 kN*m are 4 x that at 1 m. Larger values are a unit slip (N*mm, or g for kg).
MAX_FORCE = 1e5  # N
MAX_MOMENT = 1e5  # N*m
MAX_PAYLOAD = 1e4  # kg


@dataclass(frozen=True)
class Tool:
    """The point that must land on target: a site of the MJCF, or a point fixed in a body."""

    site: str | None = None
    body: str | None = None
    pos: np.ndarray | None = None  # m, in the body's frame


@dataclass(frozen=True)
class JobPoint:
    """One point of the path: the nominal command (rad) and its load (a wrench at the tool point
    in the world frame, N and N*m; or a payload mass at the payload site, kg)."""

    q: np.ndarray
    wrench: np.ndarray | None = None
    payload: float | None = None


@dataclass(frozen=True)
class Job:
    path: Path
    robot: Path  # the MJCF the job names (resolved against the job's folder)
    tool: Tool
    points: tuple[JobPoint, ...]
    text: str = ""


def _tool(top: Table) -> Tool:
    if not top.has("tool"):
        return Tool()
    t = top.sub("tool")
    t.only(("body", "site", "pos"))
    if t.has("site"):
        if t.has("body") or t.has("pos"):
            raise t.fail("site", "either site, or body with pos, not both")
        return Tool(site=t.string("site"))
    if not t.has("body"):
        raise t.fail("body", "a body of the MJCF (or site = a site's name)")
    pos = frozen_array(t.vector("pos", 3)) if t.has("pos") else frozen_array(np.zeros(3))
    return Tool(body=t.string("body"), pos=pos)


def _point(p: Table) -> JobPoint:
    p.only(("q", "wrench", "payload"))
    q = frozen_array(np.radians(p.vector("q", None)))
    if p.has("wrench") == p.has("payload"):
        raise p.fail("wrench", "exactly one of wrench = [Fx, Fy, Fz, Mx, My, Mz] (N, N*m) or payload (kg)")
    if p.has("payload"):
        m = p.number("payload", positive=True)
        if m > MAX_PAYLOAD:
            raise p.fail("payload", f"a mass in kg, at most {MAX_PAYLOAD:g} (is it in grams?)", m)
        return JobPoint(q, payload=m)
    w = p.vector("wrench", 6)
    if math.hypot(*w[:3]) > MAX_FORCE:  # hypot: no overflow warning for a 1e300 typo
        raise p.fail("wrench", f"a force of at most {MAX_FORCE:g} N (is it in the wrong units?)", w.tolist())
    if math.hypot(*w[3:]) > MAX_MOMENT:
        raise p.fail("wrench", f"a moment of at most {MAX_MOMENT:g} N*m (is it in N*mm?)", w.tolist())
    return JobPoint(q, wrench=frozen_array(w))


def parse_job(text: str, path: str | Path) -> Job:
    """A job from its TOML text (InputError naming the file and key on any mistake); the robot
    checks (:func:`check_job`) need the model and come after."""
    path = Path(path)
    top = parse_toml(text, path)
    top.only(("name", "description", "robot", "tool", "point"))
    for k in ("name", "description"):
        if top.has(k):
            top.string(k)
    robot = (path.parent / top.string("robot")).resolve()
    raw = top.raw("point")
    if not isinstance(raw, list) or not raw:
        raise top.fail("point", "one or more [[point]] tables (the path)", "none" if not raw else raw)
    points = tuple(_point(Table(path, p, f"point[{i}]")) for i, p in enumerate(raw))
    return Job(path, robot, _tool(top), points, text)


def load_job(path: str | Path) -> Job:
    path = Path(path)
    return parse_job(read_text(path, "job TOML"), path)


def check_job(job: Job, robot: Robot) -> None:
    """The job against the robot: every command has one angle per actuated joint, within the
    joint limits; the tool names a site or body the MJCF has (InputError naming the key)."""
    m = robot.model
    name = robot.source.name if robot.source else "the robot"
    if job.tool.site is not None and mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, job.tool.site) < 0:
        sites = [m.site(i).name for i in range(m.nsite)]
        raise InputError(
            job.path, "tool.site", f"a site of {name} (one of {', '.join(sites)})", job.tool.site
        )
    if job.tool.body is not None and mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, job.tool.body) < 0:
        bodies = [m.body(i).name for i in range(1, m.nbody)]
        raise InputError(
            job.path, "tool.body", f"a body of {name} (one of {', '.join(bodies)})", job.tool.body
        )
    if job.tool.site is None and job.tool.body is None and robot.flange_site < 0:
        raise InputError(job.path, "tool", f"a [tool] table ({name} names no calbench:flange site)")
    check_commands(job.path, [(f"point[{i}].q", p.q) for i, p in enumerate(job.points)], robot.limits(), name)


__all__ = ["Job", "JobPoint", "Tool", "parse_job", "load_job", "check_job", "MAX_FORCE", "MAX_MOMENT"]
