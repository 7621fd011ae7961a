"""Load and validate a calibration campaign scenario (TOML, see docs/contract.md).

The file speaks degrees for joint angles and the tracker yaw; everything returned here is SI
(radians, metres). Every bad input raises :class:`bench.errors.InputError` naming the file, the
key path (0-based for ``[[pose]]`` entries and vector elements, e.g. ``pose[3].q[1]``) and what
was expected, so the CLI can report it and exit with status 2. The ``[tracker]`` table is the
tracker family's to read (bench/tracker/base.py: TrackerSpec.from_table, each model its own keys).
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import dataclass
from datetime import date, datetime
from pathlib import Path
from typing import Any

import numpy as np

from calbench.bench.core import InputError, Table, describe, frozen_array, parse_toml, read_text, write_text
from calbench.bench.model import LEGACY_COMPENSATOR, Params, Spring
from calbench.bench.model.effects import TRUTH_SCHEMAS, read_table
from calbench.bench.tracker import TrackerSpec

from .timeline import DEFAULT_START, parse_start_time

JOINT_LIMIT_TOL = 1e-9  # rad, absorbs degree->radian round-off at a limit


# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class Pose:
    """One measurement configuration: joint angles (rad), optional world wrench, repeat count."""

    q: np.ndarray
    wrench: np.ndarray | None
    repeats: int = 1


@dataclass(frozen=True)
class Work:
    """Where the calibrated robot will work: joint angles (rad) and the process wrench."""

    q: np.ndarray
    wrench: np.ndarray


@dataclass(frozen=True)
class Scenario:
    """A validated campaign, in SI units, with the exact text it was read from."""

    path: Path
    text: str
    robot: Path
    seed: int
    compliance: np.ndarray  # (N,) rad/(N*m), N = the robot's calbench:actuated
    compensators: dict[str, Spring]  # by tendon ([truth.compensator] is the tendon "compensator")
    effects: dict[str, dict]
    tracker: TrackerSpec
    load_mass: float
    work: Work | None
    poses: tuple[Pose, ...]
    name: str = ""  # the file's `name`, else its stem
    start_time: datetime = DEFAULT_START  # UTC; when the campaign's log clock starts


# --------------------------------------------------------------------------- field checks


# --------------------------------------------------------------------------- sections

TOP_KEYS = (
    "name",
    "description",
    "start_time",
    "robot",
    "seed",
    "truth",
    "tracker",
    "load",
    "work",
    "pose",
    "design",
)
# [design]: settings of `calbench design` (identify/design/settings.py validates the values)
DESIGN_KEYS = (
    "min_height",
    "min_radius",
    "candidates",
    "seed",
    "clearance",
    "compensator_margin",
    "lateral_force",
    "lateral_fraction",
)


def _effects(c: Table) -> dict[str, dict]:
    """The optional hidden effects, present only in the simulated truth: one table per
    registered effect that declares one (bench/model/effects/registry.py), each checked against
    the keys its registration declares. In the registry's order (the order the bench applies
    them), whatever the file's."""
    c.only(tuple(TRUTH_SCHEMAS))
    return {name: read_table(schema, c.sub(name)) for name, schema in TRUTH_SCHEMAS.items() if c.has(name)}


def _tracker(c: Table) -> TrackerSpec:
    """The scenario's ``[tracker]`` table (yaw and the model's angles in degrees)."""
    return TrackerSpec.from_table(c)


def _joint_vector(c: Table, name: str, n: int | None) -> np.ndarray:
    """Joint angles in degrees -> rad: one per actuated joint, as many as truth.compliance."""
    value = c.raw(name)
    if n is not None and isinstance(value, list) and len(value) != n:
        raise c.fail(
            name,
            f"an array of {n} numbers (one per actuated joint, as in truth.compliance)",
            f"{len(value)} elements",
        )
    return frozen_array(np.radians(c.vector(name, n)))


def _joint_count(top: dict, truth: dict) -> int | None:
    """The number of actuated joints the file speaks of: the most common length among
    truth.compliance and every pose's q (ties: truth.compliance's), so that the odd one out is
    the key reported. None when there is nothing to count."""
    lengths = [len(truth["compliance"])] if isinstance(truth.get("compliance"), list) else []
    poses = top.get("pose")
    for p in poses if isinstance(poses, list) else []:
        if isinstance(p, dict) and isinstance(p.get("q"), list):
            lengths.append(len(p["q"]))
    lengths = [n for n in lengths if n > 0]
    if not lengths:
        return None
    return max(dict.fromkeys(lengths), key=lengths.count)  # first (compliance) wins ties


def _spring(c: Table) -> Spring:
    c.only(("stiffness", "preload"))
    return Spring(stiffness=c.number("stiffness", nonneg=True), preload=c.number("preload", nonneg=True))


def _compensators(truth: Table) -> dict[str, Spring]:
    """``[truth.compensator]`` (the tendon named "compensator") and ``[truth.compensators.T]``."""
    out: dict[str, Spring] = {}
    if truth.has("compensator"):
        out[LEGACY_COMPENSATOR] = _spring(truth.sub("compensator"))
    if truth.has("compensators"):
        tables = truth.sub("compensators")
        for name in tables.table:
            if name in out:
                raise tables.fail(
                    name, f"one table per tendon: [truth.{LEGACY_COMPENSATOR}] already gives it"
                )
            out[name] = _spring(tables.sub(name))
    return out


def _poses(file: Path, value: Any, n_joints: int | None) -> tuple[Pose, ...]:
    if not isinstance(value, list) or not value:
        raise InputError(file, "pose", "at least one [[pose]] table", describe(value))
    poses = []
    for i, entry in enumerate(value):
        p = Table(file, entry, f"pose[{i}]")
        p.only(("q", "wrench", "repeats"))
        poses.append(
            Pose(
                q=_joint_vector(p, "q", n_joints),
                wrench=frozen_array(p.vector("wrench", 6)) if p.has("wrench") else None,
                repeats=p.integer("repeats", lo=1) if p.has("repeats") else 1,
            )
        )
    return tuple(poses)


# --------------------------------------------------------------------------- entry points


def _document(text: str, path: Path) -> Table:
    """The scenario's top-level table: TOML, known keys, name and description strings."""
    top = parse_toml(text, path)
    top.only(TOP_KEYS)
    for name in ("name", "description"):
        if top.has(name):
            top.string(name)
    return top


def _robot(top: Table, path: Path) -> Path:
    robot_rel = top.string("robot")
    robot = (path.parent / robot_rel).resolve()
    if not robot.is_file():
        raise InputError(path, "robot", f"an existing MJCF file (resolved to {robot})", robot_rel)
    return robot


def _truth(top: Table) -> tuple[np.ndarray, dict[str, Spring], dict[str, dict]]:
    """The [truth] table: N compliances, the compensator springs by tendon, the effects."""
    truth = top.sub("truth")
    truth.only(("compliance", "compensator", "compensators", "effects"))
    compliance = frozen_array(truth.vector("compliance", _joint_count(top.table, truth.table), positive=True))
    compensators = _compensators(truth)
    effects = _effects(truth.sub("effects")) if truth.has("effects") else {}
    return compliance, compensators, effects


def _campaign(top: Table, path: Path, n_joints: int | None) -> dict[str, Any]:
    """What a scenario and a plan share: the load, the work pose, the poses, the name. Every q
    has ``n_joints`` angles (None: as many as the file's poses mostly have)."""
    if n_joints is None:
        n_joints = _joint_count(top.table, {})
    load = top.sub("load")
    load.only(("mass",))
    if top.has("design"):
        top.sub("design").only(DESIGN_KEYS)
    work = None
    if top.has("work"):
        w = top.sub("work")
        w.only(("q", "wrench"))
        work = Work(q=_joint_vector(w, "q", n_joints), wrench=frozen_array(w.vector("wrench", 6)))
    return {
        "load_mass": load.number("mass", positive=True),
        "work": work,
        "poses": _poses(path, top.raw("pose"), n_joints),
        "name": top.string("name") if top.has("name") else path.stem,
        "start_time": (
            parse_start_time(top.raw("start_time"), path) if top.has("start_time") else DEFAULT_START
        ),
    }


def parse_scenario(text: str, path: str | Path, seed: int | None = None) -> Scenario:
    """Validate scenario ``text`` read from ``path`` (used for messages and the robot path).

    ``seed`` (when given) overrides the file's seed, which then need not be present.
    """
    path = Path(path)
    top = _document(text, path)
    robot = _robot(top, path)

    if seed is None:
        seed = top.integer("seed", lo=0)
    else:
        if top.has("seed"):
            top.integer("seed", lo=0)  # still reject a malformed value in the file
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError("--seed", "seed", "an integer >= 0", seed)
        seed = int(seed)

    compliance, compensators, effects = _truth(top)
    return Scenario(
        path=path,
        text=text,
        robot=robot,
        seed=seed,
        compliance=compliance,
        compensators=compensators,
        effects=effects,
        tracker=_tracker(top.sub("tracker")),
        **_campaign(top, path, len(compliance)),
    )


@dataclass(frozen=True)
class Plan:
    """A measurement plan: a scenario without ``[truth]`` (docs/contract.md), what a real
    campaign knows before it starts: the robot, the commanded poses, the loads and the
    tracker's noise model.

    The tracker's ``position`` (and ``yaw``) are optional: ``tracker_placed`` says whether the
    file gave them. When it did not, ``tracker`` carries the noise model only, its pose a
    placeholder (origin, no rotation) that ``calbench import`` replaces by the registered one.
    A ``[truth]`` table, if present (a plan written by ``calbench design`` carries its prior),
    is validated like a scenario's and otherwise ignored.
    """

    path: Path
    text: str
    robot: Path
    seed: int
    tracker: TrackerSpec
    tracker_placed: bool
    load_mass: float
    work: Work | None
    poses: tuple[Pose, ...]
    name: str = ""
    start_time: datetime = DEFAULT_START  # UTC; a readings file's seconds count from here


def parse_plan(text: str, path: str | Path) -> Plan:
    """Validate a plan (see :class:`Plan`): a scenario whose ``[truth]``, ``seed`` and tracker
    position are optional; everything present is checked as in :func:`parse_scenario`."""
    path = Path(path)
    top = _document(text, path)
    robot = _robot(top, path)
    seed = top.integer("seed", lo=0) if top.has("seed") else 0
    n_joints = None
    if top.has("truth"):
        n_joints = len(_truth(top)[0])
    tr = top.sub("tracker")
    placed = tr.has("position")
    if not placed and tr.has("yaw"):
        raise tr.fail(
            "yaw",
            "a tracker position with the yaw (without a position, `calbench "
            "import` registers the whole tracker pose)",
        )
    if not placed:
        tr = Table(path, {**tr.table, "position": [0.0, 0.0, 0.0]}, tr.prefix)
    return Plan(
        path=path,
        text=text,
        robot=robot,
        seed=seed,
        tracker=_tracker(tr),
        tracker_placed=placed,
        **_campaign(top, path, n_joints),
    )


def load_plan(path: str | Path) -> Plan:
    """Read and validate the plan file at ``path`` (see :func:`parse_plan`)."""
    path = Path(path)
    return parse_plan(read_text(path, "plan"), path)


def load_scenario(path: str | Path, seed: int | None = None) -> Scenario:
    """Read and validate the scenario file at ``path``; ``seed`` overrides the file's seed."""
    path = Path(path)
    return parse_scenario(read_text(path, "scenario"), path, seed)


def scenario_variant(
    src: str | Path,
    out: str | Path,
    *,
    name: str | None = None,
    seed: int | None = None,
    compensator: tuple[float, float] | None = None,
    extra: str = "",
    robot: str | Path | None = None,
    drop: tuple[str, ...] = (),
) -> Path:
    """Write a copy of scenario ``src`` at ``out`` with a few truths changed, keeping its comments.

    The robot path is made absolute (the copy may live elsewhere), or is ``robot``; ``name``,
    ``seed`` and the compensator's (stiffness, preload) replace the file's; the tables named in
    ``drop`` (e.g. ``"truth.compensator"`` for a robot without the spring) are removed, their
    keys and comments with them; ``extra`` is TOML inserted before ``[tracker]``, e.g. a hidden
    ``[truth.effects.*]`` table. The result is validated.
    """
    src, out = Path(src), Path(out)
    text = src.read_text(encoding="utf-8")
    robot = (
        Path(robot).resolve() if robot is not None else (src.parent / tomllib.loads(text)["robot"]).resolve()
    )

    def sub(pattern: str, value: str, flags: int = re.MULTILINE) -> None:
        nonlocal text
        text, n = re.subn(pattern, lambda m: m.group(1) + value, text, count=1, flags=flags)
        if n != 1:
            raise ValueError(f"{src}: cannot set {pattern!r}")

    sub(r'^(robot\s*=\s*)"[^"]*"', f'"{robot.as_posix()}"')
    if name is not None:
        sub(r'^(name\s*=\s*)"[^"]*"', f'"{name}"')
    if seed is not None:
        sub(r"^(seed\s*=\s*)\d+", str(int(seed)))
    if compensator is not None:
        # within [truth.compensator]: up to the next line that opens a table
        for key, value in zip(("stiffness", "preload"), compensator):
            sub(
                rf"(^\[truth\.compensator\](?:(?!^\[).)*?^{key}\s*=\s*)\S+",
                repr(float(value)),
                re.MULTILINE | re.DOTALL,
            )
    for table in drop:  # the table's header up to the next table's
        text, n = re.subn(rf"^\[{re.escape(table)}\]\n(?:(?!\[).*\n)*", "", text, count=1, flags=re.MULTILINE)
        if n != 1:
            raise ValueError(f"{src}: no table [{table}] to drop")
    if extra:
        sub(r"^()(?=\[tracker\])", extra.strip() + "\n\n")
    parse_scenario(text, out)  # raises InputError on a bad variant, before writing it
    write_text(out, text)
    return out


def scenario_params(scn: Scenario, n_joints: int, compensators: tuple[str, ...]) -> Params:
    """The truth as Params for a robot with ``n_joints`` actuated joints and the named
    compensator tendons (its calbench:actuated and calbench:compensators); InputError naming
    the key that does not fit the robot."""
    if len(scn.compliance) != n_joints:
        raise InputError(
            scn.path,
            "truth.compliance",
            f"an array of {n_joints} numbers (one per actuated joint of {scn.robot.name})",
            f"{len(scn.compliance)} elements",
        )

    def key(t: str) -> str:
        return f"truth.{LEGACY_COMPENSATOR}" if t == LEGACY_COMPENSATOR else f"truth.compensators.{t}"

    for t in compensators:
        if t not in scn.compensators:
            raise InputError(
                scn.path,
                key(t),
                f"this table (stiffness, preload): {scn.robot.name} has the compensator tendon {t!r}",
            )
    for t in scn.compensators:
        if t not in compensators:
            raise InputError(
                scn.path,
                key(t),
                "a compensator tendon of the robot (calbench:compensators: "
                + (", ".join(compensators) or "none")
                + ")",
                t,
            )
    return Params(np.asarray(scn.compliance, dtype=float), {t: scn.compensators[t] for t in compensators})


def check_joint_limits(scn: Scenario, limits: np.ndarray) -> None:
    """Reject poses (and the work pose) outside the robot's joint ``limits`` ((N, 2) rad)."""
    named = [(f"pose[{i}].q", p.q) for i, p in enumerate(scn.poses)]
    if scn.work is not None:
        named.append(("work.q", scn.work.q))
    check_commands(scn.path, named, limits, scn.robot.name)


def check_commands(file: object, named, limits: np.ndarray, robot_name: str) -> None:
    """Every command ``q`` of ``named`` ((key, q) pairs, rad) of the input ``file`` has one
    angle per actuated joint of the robot ``robot_name`` and is within its joint ``limits``
    ((N, 2) rad, JOINT_LIMIT_TOL beyond them allowed); InputError naming the key otherwise."""
    limits = np.asarray(limits, dtype=float)
    n = len(limits)
    if limits.shape != (n, 2):
        raise ValueError(f"limits must have shape (N, 2), got {limits.shape}")
    for key, q in named:
        if len(q) != n:
            raise InputError(
                file,
                key,
                f"an array of {n} numbers (one per actuated joint of {robot_name})",
                f"{len(q)} elements",
            )
        for j in range(n):
            lo, hi = limits[j]
            if not lo - JOINT_LIMIT_TOL <= q[j] <= hi + JOINT_LIMIT_TOL:
                raise InputError(
                    file,
                    f"{key}[{j}]",
                    f"joint {j + 1} within [{math.degrees(lo):.3f}, {math.degrees(hi):.3f}] degrees",
                    round(math.degrees(q[j]), 6),
                )


# --------------------------------------------------------------------------- writing


def scenario_as_dict(scn: Scenario, relative_to: str | Path) -> dict:
    """The scenario in file units (degrees), with ``robot`` relative to directory ``relative_to``.

    Feed it, possibly edited (e.g. new poses), to :func:`scenario_to_toml` to write a plan.
    Angles are rounded to 1e-10 degree (< 2e-12 rad) so the file reads 30.0, not 29.999...
    """

    def deg(q: np.ndarray) -> list[float]:
        return np.round(np.degrees(q), 10).tolist()

    tr = scn.tracker
    header = {k: v for k, v in tomllib.loads(scn.text).items() if k in ("name", "description", "start_time")}
    doc: dict[str, Any] = {
        **header,
        "robot": Path(os.path.relpath(scn.robot, Path(relative_to).resolve())).as_posix(),
        "seed": scn.seed,
        "truth": Params(scn.compliance, scn.compensators).as_dict(),
        "tracker": tr.to_table(),
        "load": {"mass": scn.load_mass},
    }
    if scn.effects:
        doc["truth"]["effects"] = {
            name: {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in e.items()}
            for name, e in scn.effects.items()
        }
    if scn.work is not None:
        doc["work"] = {"q": deg(scn.work.q), "wrench": scn.work.wrench.tolist()}
    poses = []
    for p in scn.poses:
        entry: dict[str, Any] = {"q": deg(p.q)}
        if p.wrench is not None:
            entry["wrench"] = p.wrench.tolist()
        entry["repeats"] = p.repeats
        poses.append(entry)
    doc["pose"] = poses
    return doc


_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else _toml_string(key)


def _toml_string(s: str) -> str:
    """A TOML basic string; control characters and DEL are escaped as TOML requires."""
    out = ['"']
    for ch in s:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_value(v: Any) -> str:
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"cannot write non-finite number {v} to a scenario")
        return repr(v)  # shortest text that reads back bit-exact
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, (datetime, date)):
        return v.isoformat()  # a TOML date-time literal
    if isinstance(v, Path):
        return _toml_string(v.as_posix())
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(v) > 0 and all(isinstance(x, dict) for x in v)


def _emit(table: dict, path: list[str], lines: list[str]) -> None:
    """Write scalars first, then sub-tables, then arrays of tables (TOML ordering rules)."""
    scalars = [
        (k, v)
        for k, v in table.items()
        if v is not None and not isinstance(v, dict) and not _is_table_array(v)
    ]
    for k, v in scalars:
        lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        if isinstance(v, dict):
            sub = path + [_toml_key(k)]
            has_scalars = any(not isinstance(x, dict) and not _is_table_array(x) for x in v.values())
            if has_scalars or not v:
                lines.extend(["", f"[{'.'.join(sub)}]"])
            _emit(v, sub, lines)
    for k, v in table.items():
        if _is_table_array(v):
            sub = path + [_toml_key(k)]
            for entry in v:
                lines.extend(["", f"[[{'.'.join(sub)}]]"])
                _emit(entry, sub, lines)


def scenario_to_toml(scn_like: dict) -> str:
    """Write a scenario TOML from a plain dict keyed as in docs/contract.md (file units, degrees).

    ``None`` values are omitted. The result is meant to be read back by :func:`parse_scenario`.
    """
    if not isinstance(scn_like, dict):
        raise TypeError("scenario_to_toml expects a dict")
    lines: list[str] = []
    _emit(scn_like, [], lines)
    return "\n".join(lines).lstrip("\n") + "\n"
