"""A study file: a base scenario, axes of values for scenario keys, and seeds per cell.

    name = "tracker accuracy"                      # optional (default: the file's stem)
    description = "..."                            # optional
    scenario = "../scenarios/paper_table5.toml"    # the base scenario, relative to this file
    seeds = 20                                     # campaigns (noise seeds) per cell
    seed = 1                                       # optional: the study's seed (default: the scenario's)

    [campaign]                                     # optional: what each campaign runs
    method = "one-step"                            # identify --method (one-step | two-step | two-step-iterated)
    discover = false                               # also run discover on every campaign
    discover_without = []                          # effects removed from the model discover starts
                                                   # from (its user's model lacks them)
    [set]                                          # optional: settings of every cell
    "design.candidates" = 2000

    [[axis]]                                       # the grid is the product of the axes
    key = "tracker.sigma"                          # any scenario key, dotted ([i]: an array element),
    values = [10e-6, 20e-6, 50e-6]                 # or "plan", or "campaign.<key>"

    [[axis]]                                       # cases: settings applied together, named by label
    name = "effect"
    cases = [{label = "none"},
             {label = "forearm", set = {"truth.effects.link_compliance" = {link = "forearm", compliance = [1.8e-7, 0.0, 1.8e-7]}}}]

    [[axis]]                                       # a factor on every float another axis sets
    name = "magnitude"
    values = [0.35, 0.5, 0.75, 1.0]
    scales = "effect"

A ``plan`` value is a scenario file (relative to the study; its ``[[pose]]`` list replaces the
base's) or ``design:<criterion>:<M>``: the M-configuration plan `calbench design` finds for the
cell's scenario (criterion A, D, AD or pose). Keys are checked by the scenario parser itself
(bench/scenario/parse.py), so whatever a scenario may hold an axis may vary: a tracker's sigma or
model, the payload, a truth value, a hidden effect. Every cell's scenario is built and validated
here, before any task is sent: a bad study (unknown key, empty axis, a value the scenario
refuses) is an InputError naming the study file and the axis and key.

The campaign seeds are the study's: campaign r of every cell draws its noise from the seed
derived from (study seed, r), so cells differ by what the axes change and not by their noise
(common random numbers), and two cells with identical inputs are computed once.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calbench.bench.core import InputError
from calbench.bench.scenario import Scenario, load_scenario
from calbench.identify.design.optimal import CRITERIA
from calbench.identify.methods import method_names
from calbench.identify.runtime import PortableScenario

TOP_KEYS = ("name", "description", "scenario", "seeds", "seed", "campaign", "set", "axis")
AXIS_KEYS = ("name", "key", "values", "cases", "scales")
CASE_KEYS = ("label", "set")
CAMPAIGN_KEYS = ("method", "discover", "discover_without")
PLAN = "plan"
FIXED_KEYS = ("robot", "seed")  # one robot per study; the seeds are the study's
_INDEX = re.compile(r"^([^\[\]]+)((?:\[\d+\])*)$")


@dataclass(frozen=True)
class CampaignSettings:
    """What each campaign runs after the simulation: identify (method), optionally discover."""

    method: str = "one-step"
    discover: bool = False
    discover_without: tuple[str, ...] = ()


@dataclass(frozen=True)
class Axis:
    """One axis: its column name, the column value of each entry and what each entry sets."""

    name: str
    column: tuple  # the value shown in the results column, per entry
    settings: tuple[dict, ...]  # per entry: dotted key -> value
    scales: str | None = None  # the axis whose floats this one multiplies
    where: str = ""  # "axis[i]" for messages


@dataclass(frozen=True)
class Cell:
    """One point of the grid: its axis values and everything a campaign there needs."""

    index: int
    values: dict  # axis name -> column value
    doc: dict  # scenario document (file units), poses from the plan
    plan: str  # "" (the base's poses), a plan file path, or design:<c>:<M>
    campaign: CampaignSettings
    inputs: str  # digest of what the campaigns depend on (not the axis labels)
    cell_id: str  # digest of inputs and axis values: the row identity
    expected: str | None = None  # the effect discover should name first (see expected_effect)


@dataclass(frozen=True)
class Study:
    path: Path
    text: str
    name: str
    base: Scenario
    mjcf: str
    robot_name: str
    seeds: int
    seed: int
    campaign: CampaignSettings
    axes: tuple[Axis, ...]
    param_names: tuple[str, ...]  # the robot's parameters (its layout), in order
    cells: tuple[Cell, ...] = field(repr=False)

    def campaign_seed(self, replicate: int) -> int:
        """The scenario seed of campaign ``replicate`` of every cell: from (study seed, replicate)."""
        return int(np.random.SeedSequence([self.seed, replicate]).generate_state(1, np.uint32)[0])

    def portable(self, cell: Cell) -> PortableScenario:
        return PortableScenario.from_doc(
            cell.doc, self.mjcf, self.robot_name, f"{self.path.stem}-cell{cell.index}.toml"
        )


# --------------------------------------------------------------------------- helpers


def canonical(x: Any) -> str:
    """Compact JSON with sorted keys: the identity of a value (floats by repr)."""
    return json.dumps(x, sort_keys=True, separators=(",", ":"), default=str)


def digest(*parts: Any) -> str:
    return hashlib.sha256(canonical(parts).encode("utf-8")).hexdigest()[:20]


def column_value(v: Any) -> Any:
    """What a results column shows for a setting: scalars as they are, arrays and tables as JSON."""
    return canonical(v) if isinstance(v, (list, dict)) else v


def _split(path: Path, where: str, key: str) -> list:
    if not isinstance(key, str) or not key:
        raise InputError(path, f"{where}.key", 'a dotted scenario key, e.g. "tracker.sigma"', key)
    out: list = []
    for part in key.split("."):
        m = _INDEX.match(part)
        if not m:
            raise InputError(path, f"{where}: {key}", "a dotted key of names and [index] suffixes", key)
        out.append(m.group(1))
        out += [int(i) for i in re.findall(r"\[(\d+)\]", m.group(2))]
    return out


def set_key(doc: dict, parts: list, value: Any, path: Path, where: str, key: str) -> None:
    """Set ``doc[parts...] = value``, creating missing tables (an index must exist)."""
    node: Any = doc
    for i, p in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(p, int):
            if not isinstance(node, list) or p >= len(node):
                raise InputError(
                    path, f"{where}: {key}", "an index into an existing array of the scenario", p
                )
            if last:
                node[p] = copy.deepcopy(value)
            else:
                node = node[p]
            continue
        if not isinstance(node, dict):
            raise InputError(
                path, f"{where}: {key}", "a key inside a table of the scenario", ".".join(map(str, parts[:i]))
            )
        if last:
            node[p] = copy.deepcopy(value)
        else:
            node = node.setdefault(p, {})


def scaled(v: Any, factor: float) -> Any:
    """Every float in v (nested in arrays and tables) times factor; integers and strings kept."""
    if isinstance(v, float):
        return v * factor
    if isinstance(v, list):
        return [scaled(x, factor) for x in v]
    if isinstance(v, dict):
        return {k: scaled(x, factor) for k, x in v.items()}
    return v


def _number(path, key, v, lo=None, integer=False):
    ok = not isinstance(v, bool) and isinstance(v, int if integer else (int, float))
    if not ok or not math.isfinite(float(v)) or (lo is not None and v < lo):
        what = ("an integer" if integer else "a finite number") + (f" >= {lo}" if lo is not None else "")
        raise InputError(path, key, what, v)
    return v


# --------------------------------------------------------------------------- parsing


def _campaign(path: Path, tab: Any) -> CampaignSettings:
    from .campaign import REMOVABLE

    if not isinstance(tab, dict):
        raise InputError(path, "campaign", "a table", tab)
    for k in tab:
        if k not in CAMPAIGN_KEYS:
            raise InputError(
                path, f"campaign.{k}", "no such key; allowed keys here: " + ", ".join(CAMPAIGN_KEYS)
            )
    method = tab.get("method", "one-step")
    offered = method_names(offered_only=True)  # those `calbench identify --method` offers
    if method not in offered:
        raise InputError(path, "campaign.method", "one of " + ", ".join(offered), method)
    disc = tab.get("discover", False)
    if not isinstance(disc, bool):
        raise InputError(path, "campaign.discover", "true or false", disc)
    without = tab.get("discover_without", [])
    if not isinstance(without, list) or any(w not in REMOVABLE for w in without):
        raise InputError(
            path,
            "campaign.discover_without",
            "an array of effects discover's model can lack: " + ", ".join(REMOVABLE),
            without,
        )
    return CampaignSettings(method, disc, tuple(without))


def _axis(path: Path, i: int, tab: Any) -> Axis:
    where = f"axis[{i}]"
    if not isinstance(tab, dict):
        raise InputError(path, where, "a table ([[axis]])", tab)
    for k in tab:
        if k not in AXIS_KEYS:
            raise InputError(path, f"{where}.{k}", "no such key; allowed keys here: " + ", ".join(AXIS_KEYS))
    if ("cases" in tab) == ("values" in tab):
        raise InputError(path, where, "either values (with key or scales) or cases")
    name = tab.get("name", tab.get("key"))
    if not isinstance(name, str) or not name:
        raise InputError(path, f"{where}.name", "a column name (a non-empty string)", name)
    if "cases" in tab:
        cases = tab["cases"]
        if not isinstance(cases, list) or not cases:
            raise InputError(path, f"{where}.cases", "a non-empty array of {label, set} tables", cases)
        labels, settings = [], []
        for j, c in enumerate(cases):
            cw = f"{where}.cases[{j}]"
            if not isinstance(c, dict) or not isinstance(c.get("label"), str):
                raise InputError(
                    path, f"{cw}.label", "a string label", None if not isinstance(c, dict) else c.get("label")
                )
            for k in c:
                if k not in CASE_KEYS:
                    raise InputError(
                        path, f"{cw}.{k}", "no such key; allowed keys here: " + ", ".join(CASE_KEYS)
                    )
            s = c.get("set", {})
            if not isinstance(s, dict):
                raise InputError(path, f"{cw}.set", "a table of dotted scenario keys and values", s)
            labels.append(c["label"])
            settings.append(dict(s))
        if len(set(labels)) != len(labels):
            raise InputError(path, f"{where}.cases", "distinct labels", labels)
        return Axis(name, tuple(labels), tuple(settings), None, where)
    values = tab["values"]
    if not isinstance(values, list) or not values:
        raise InputError(path, f"{where}.values", "a non-empty array of values", values)
    if "scales" in tab:
        if "key" in tab:
            raise InputError(path, f"{where}.scales", "either key or scales, not both")
        for v in values:
            _number(path, f"{where}.values", v)
        return Axis(name, tuple(values), tuple({} for _ in values), str(tab["scales"]), where)
    if "key" not in tab:
        raise InputError(path, f"{where}.key", "the scenario key the values are for (or scales, or cases)")
    key = tab["key"]
    _split(path, where, key)
    return Axis(name, tuple(column_value(v) for v in values), tuple({key: v} for v in values), None, where)


def _plan_poses(path: Path, where: str, value: Any) -> tuple[str, list | None]:
    """A plan value: ("design:C:M", None) or (resolved file, its [[pose]] list)."""
    if not isinstance(value, str) or not value:
        raise InputError(path, where, "a scenario file or design:<criterion>:<M>", value)
    if value.startswith("design:"):
        parts = value.split(":")
        ok = len(parts) == 3 and parts[1] in CRITERIA and parts[2].isdigit() and int(parts[2]) >= 1
        if not ok:
            raise InputError(
                path,
                where,
                "design:<criterion>:<M> with criterion " + "|".join(CRITERIA) + " and M >= 1",
                value,
            )
        return value, None
    f = (path.parent / value).resolve()
    try:
        doc = tomllib.loads(f.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(
            path,
            where,
            "a readable scenario file (relative to the study) with [[pose]] tables",
            f"{value}: {exc}",
        ) from None
    if not isinstance(doc.get("pose"), list) or not doc["pose"]:
        raise InputError(path, where, "a scenario file with [[pose]] tables", value)
    return str(f), doc["pose"]


def expected_effect(scn: Scenario, campaign: CampaignSettings) -> str | None:
    """What discover should name first: the one effect the user's model lacks (hidden in the
    truth, or removed from discover's model) as ``name[detail]``; "unexplained" when it is not a
    discovery candidate; "nothing" when nothing is missing; None when several are."""
    from calbench.bench.model.effects import DISCOVERY_OPTIONS, effect_from_truth

    missing = [(n, t) for n, t in scn.effects.items()] + [(n, None) for n in campaign.discover_without]
    if not missing:
        return "nothing"
    if len(missing) > 1:
        return None
    name, table = missing[0]
    if name not in DISCOVERY_OPTIONS:
        return "unexplained"
    detail = effect_from_truth(name, table)[0].detail if table is not None else ""
    return f"{name}[{detail}]" if detail else name


def _apply(doc: dict, campaign: dict, plan: list, path: Path, where: str, key: str, value: Any) -> None:
    """One setting: a scenario key into doc, a campaign key, or the plan."""
    if key == PLAN:
        plan[0] = value
        return
    parts = _split(path, where, key)
    if parts[0] == "campaign":
        if len(parts) != 2 or parts[1] not in CAMPAIGN_KEYS:
            raise InputError(
                path, f"{where}: {key}", "campaign.<key> with key one of " + ", ".join(CAMPAIGN_KEYS)
            )
        campaign[parts[1]] = value
        return
    if parts[0] in FIXED_KEYS:
        raise InputError(
            path,
            f"{where}: {key}",
            "a key other than robot and seed (one robot per study; the "
            "campaign seeds come from the study's seeds and seed)",
        )
    set_key(doc, parts, value, path, where, key)


def _finite(path: Path, doc: Any, key: str = "") -> None:
    """No NaN or infinity anywhere in a study file (TOML allows nan and inf): InputError naming
    the key. Every number of a study ends up in a scenario or a setting, none of which takes one."""
    if isinstance(doc, float) and not math.isfinite(doc):
        raise InputError(path, key, "a finite number", doc)
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        _finite(path, v, f"{key}[{k}]" if isinstance(k, int) else f"{key}.{k}" if key else str(k))


def load_study(path: str | Path) -> Study:
    """Read and validate a study file and every cell of its grid (InputError naming file and key)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
        top = tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, "(file)", "a readable UTF-8 study file", str(exc)) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(path, "(syntax)", "valid TOML", str(exc)) from None
    for k in top:
        if k not in TOP_KEYS:
            raise InputError(path, k, "no such key; allowed keys here: " + ", ".join(TOP_KEYS))
    _finite(path, top)
    if not isinstance(top.get("scenario"), str):
        raise InputError(
            path, "scenario", "the base scenario file, relative to the study", top.get("scenario")
        )
    try:
        base = load_scenario((path.parent / top["scenario"]).resolve())
    except InputError as exc:
        raise InputError(path, "scenario", "a valid base scenario", str(exc)) from None
    seeds = _number(path, "seeds", top.get("seeds"), 1, integer=True)
    seed = _number(path, "seed", top.get("seed", base.seed), 0, integer=True)
    campaign0 = _campaign(path, top.get("campaign", {}))
    fixed = top.get("set", {})
    if not isinstance(fixed, dict):
        raise InputError(path, "set", "a table of dotted scenario keys and values", fixed)
    axes_raw = top.get("axis", [])
    if not isinstance(axes_raw, list):
        raise InputError(path, "axis", "[[axis]] tables", axes_raw)
    axes = tuple(_axis(path, i, a) for i, a in enumerate(axes_raw))
    names = [a.name for a in axes]
    from calbench.bench.model import Robot

    from .campaign import result_columns

    try:
        param_names = tuple(Robot.from_file(base.robot).layout.names)
    except ValueError as exc:
        raise InputError(
            path, "scenario", "a base scenario whose robot loads", f"{base.robot}: {exc}"
        ) from None
    reserved = result_columns(param_names)
    for a in axes:
        if names.count(a.name) > 1 or a.name in reserved:
            raise InputError(
                path, f"{a.where}.name", "a column name used once and by no result column", a.name
            )
        if a.scales is not None and (a.scales not in names or a.scales == a.name):
            raise InputError(path, f"{a.where}.scales", "the name of another axis", a.scales)
        if a.scales is not None:
            target = axes[names.index(a.scales)]
            for col, st in zip(target.column, target.settings):
                if st and scaled(st, 2.0) == st:
                    raise InputError(
                        path,
                        f"{target.where} {target.name} = {col!r}",
                        f"a float for {a.name} to scale (it scales floats only: write 6.0e6, not 6000000)",
                        st,
                    )

    robot = Path(base.robot)
    mjcf = robot.read_text(encoding="utf-8")
    base_doc = tomllib.loads(base.text)
    base_doc.pop("robot", None)
    base_doc["seed"] = seed  # designs use it; each campaign replaces it by its own
    study = Study(
        path,
        text,
        str(top.get("name", path.stem)),
        base,
        mjcf,
        robot.name,
        seeds,
        seed,
        campaign0,
        axes,
        param_names,
        (),
    )
    cells = []
    plans: dict[str, tuple[str, list | None]] = {}
    for index, combo in enumerate(np.ndindex(*[len(a.column) for a in axes]) if axes else [()]):
        doc = copy.deepcopy(base_doc)
        camp = {
            "method": campaign0.method,
            "discover": campaign0.discover,
            "discover_without": list(campaign0.discover_without),
        }
        plan = [""]
        for k, v in fixed.items():
            _apply(doc, camp, plan, path, "set", k, v)
        factors = {a.scales: a.column[j] for a, j in zip(axes, combo) if a.scales is not None}
        for a, j in zip(axes, combo):
            for k, v in a.settings[j].items():
                w = f"{a.where} {a.name} = {a.column[j]!r}"
                _apply(doc, camp, plan, path, w, k, scaled(v, factors[a.name]) if a.name in factors else v)
        where = "plan"
        if plan[0]:
            if plan[0] not in plans:
                plans[plan[0]] = _plan_poses(path, "plan", plan[0])
            spec, poses = plans[plan[0]]
            if poses is not None:
                doc["pose"] = copy.deepcopy(poses)
        else:
            spec = ""
        camp_settings = _campaign(path, camp)
        if spec.startswith("design:pose:") and "work" not in doc:
            raise InputError(
                path,
                _culprit(axes, combo, fixed, "pose", where),
                "a [work] table in the scenario "
                "for a design:pose plan (the deflection variance at the work pose)",
                spec,
            )
        values = {a.name: a.column[j] for a, j in zip(axes, combo)}
        cell = Cell(index, values, doc, spec, camp_settings, "", "")
        try:
            scn = study.portable(cell).scenario()
        except InputError as exc:
            raise InputError(
                path, _culprit(axes, combo, fixed, exc.key, where), exc.expected, exc.got
            ) from None
        inputs = digest(doc, spec, camp_settings.__dict__, hashlib.sha256(mjcf.encode()).hexdigest())
        cells.append(
            Cell(
                index,
                values,
                doc,
                spec,
                camp_settings,
                inputs,
                digest(inputs, values),
                expected_effect(scn, camp_settings),
            )
        )
    return Study(
        path,
        text,
        study.name,
        base,
        mjcf,
        robot.name,
        seeds,
        seed,
        campaign0,
        axes,
        param_names,
        tuple(cells),
    )


def _culprit(axes, combo, fixed: dict, key: str, plan_where: str) -> str:
    """Which setting of the study a scenario error comes from: 'axis[i] NAME = V: KEY' or 'set: KEY'."""

    def related(k: str) -> bool:
        k = k.split("[")[0]
        return key == k or key.startswith(k + ".") or key.startswith(k + "[") or k.startswith(key + ".")

    for a, j in zip(axes, combo):
        for k in a.settings[j]:
            if k != PLAN and related(k):
                return f"{a.where} {a.name} = {a.column[j]!r}: {key}"
            if k == PLAN and key.startswith("pose"):
                return f"{a.where} {a.name} = {a.column[j]!r}: {key}"
    for k in fixed:
        if related(k):
            return f"set: {key}"
    return f"(base scenario) {key}"


__all__ = [
    "Study",
    "Axis",
    "Cell",
    "CampaignSettings",
    "load_study",
    "expected_effect",
    "canonical",
    "digest",
]
