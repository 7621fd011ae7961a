"""A design's inputs: the scenario's ``[design]`` settings and the nominal model it starts from.

Parameters and prior guess. theta = the robot's layout (bench/model/params.py; the FANUC's
[k1..k6, K_C, s0]) normalised by a nominal value:
u_i = theta_i / theta0_i. A design needs a prior guess of theta (the information of the nonlinear
model depends on it); a design study uses the scenario's ``[truth]``, which is the natural
nominal (in a real cell: the manufacturer's values or a previous identification).
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calbench.bench.campaign import truth_params
from calbench.bench.core import InputError
from calbench.bench.model import Robot, load_robot
from calbench.bench.scenario import Scenario, check_scenario, parse_scenario

# --------------------------------------------------------------------------- settings


# The wrist-centre rules' defaults scale with the robot (DesignSettings.for_reach): a heavy
# robot's values (the paper's, for the FANUC: 0.5 m and 1 m) at a reach of REFERENCE_REACH or
# more, in proportion below it.
HEAVY_MIN_HEIGHT = 0.5  # m
HEAVY_MIN_RADIUS = 1.0  # m
REFERENCE_REACH = 2.5  # m


@dataclass(frozen=True)
class DesignSettings:
    """The scenario's optional ``[design]`` table (read here from the TOML text).

    ``min_height`` and ``min_radius`` (the wrist centre's height above the floor and distance
    from axis 1) not given in the scenario (None) scale with the robot's reach R
    (identify/design/feasibility.py's ``robot_reach``: an upper bound of the wrist centre's
    distance from axis 1 over every command), in :meth:`for_reach`: min_height = 0.5 m x
    min(1, R / 2.5 m), min_radius = 1 m x min(1, R / 2.5 m). A heavy robot (R >= 2.5 m: the
    FANUC M-900iB 2.87 m, the KR 270 2.70 m, the IRB 6640 2.99 m) keeps the paper's 0.5 m and
    1 m; a UR10 (1.32 m) gets 0.26 m and 0.53 m, where 1 m rejected 90 % of its commands.
    """

    min_height: float | None = None  # m, wrist centre z; None: scaled with the reach
    min_radius: float | None = None  # m, wrist centre from axis 1; None: scaled with the reach
    candidates: int = 10000  # size of the candidate set
    seed: int | None = None  # candidate sampling; default: the scenario's seed
    clearance: float = 0.0  # m, collision margin
    compensator_margin: float = 0.02  # m, §3.3 rule
    # N, horizontal pull of the lateral candidates; not given: this, or the payload's weight if
    # less (read_design_settings: a robot is not pulled harder than it is rated to carry)
    lateral_force: float = 1200.0
    lateral_fraction: float = 0.5  # share of lateral candidates in the set

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    def for_reach(self, reach: float) -> DesignSettings:
        """These settings with min_height and min_radius, where not given, scaled with the
        robot's reach (m; the class docstring's rule); given ones are kept as they are."""
        scale = min(1.0, max(float(reach), 0.0) / REFERENCE_REACH)
        return replace(
            self,
            min_height=HEAVY_MIN_HEIGHT * scale if self.min_height is None else self.min_height,
            min_radius=HEAVY_MIN_RADIUS * scale if self.min_radius is None else self.min_radius,
        )


DESIGN_KEYS = tuple(DesignSettings.__dataclass_fields__)
STANDARD_GRAVITY = 9.81  # m/s^2, MuJoCo's default gravity: a payload's weight


def _design_number(path, key, v, lo=None, hi=None, integer=False):
    what = (
        ("an integer" if integer else "a finite number")
        + (f" >= {lo}" if lo is not None else "")
        + (f" and <= {hi}" if hi is not None else "")
    )
    ok = not isinstance(v, bool) and isinstance(v, int if integer else (int, float))
    if not ok or not math.isfinite(float(v)) or (lo is not None and v < lo) or (hi is not None and v > hi):
        raise InputError(path, f"design.{key}", what, v)
    return int(v) if integer else float(v)


def read_design_settings(path: str | Path, text: str | None = None) -> DesignSettings:
    """Parse the optional ``[design]`` table of a scenario file (InputError naming the key)."""
    path = Path(path)
    text = Path(path).read_text(encoding="utf-8") if text is None else text
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(path, "(syntax)", "valid TOML", str(exc)) from None
    tab = doc.get("design", {})
    if not isinstance(tab, dict):
        raise InputError(path, "design", "a table", type(tab).__name__)
    for k in tab:
        if k not in DESIGN_KEYS:
            raise InputError(path, f"design.{k}", "no such key; allowed keys here: " + ", ".join(DESIGN_KEYS))
    kw = {}
    limits = {
        "min_height": (None, None, False),
        "min_radius": (0, None, False),
        "candidates": (1, None, True),
        "seed": (0, None, True),
        "clearance": (0, None, False),
        "compensator_margin": (0, None, False),
        "lateral_force": (0, None, False),
        "lateral_fraction": (0, 1, False),
    }
    for k, v in tab.items():
        lo, hi, integer = limits[k]
        kw[k] = _design_number(path, k, v, lo, hi, integer)
    load = doc.get("load", {})
    mass = load.get("mass") if isinstance(load, dict) else None
    if "lateral_force" not in kw and isinstance(mass, int | float) and not isinstance(mass, bool):
        weight = float(mass) * STANDARD_GRAVITY  # a 10 kg robot pulled with 98 N, not 1200
        if 0.0 < weight < DesignSettings.lateral_force:
            kw["lateral_force"] = weight
    return DesignSettings(**kw)


_DESIGN_TABLE = re.compile(r"^\[design\][^\n]*\n(?:(?!\s*\[)[^\n]*\n?)*", re.MULTILINE)


def load_design_scenario(path: str | Path) -> tuple[Scenario, DesignSettings]:
    """The scenario (bench.scenario.parse_scenario) and its ``[design]`` settings.

    bench/scenario/parse.py does not (yet) accept a ``[design]`` table, so it is cut out of the text
    before parsing; the Scenario's ``text`` is the file without it.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, "(file)", "a readable UTF-8 scenario file", str(exc)) from None
    settings = read_design_settings(path, text)
    stripped = _DESIGN_TABLE.sub("", text)
    try:
        if "design" in tomllib.loads(stripped):
            raise InputError(path, "design", "a [design] table written as a table header")
    except tomllib.TOMLDecodeError:
        pass  # parse_scenario reports it
    return parse_scenario(stripped, path), settings


def nominal_theta(scn: Scenario, robot: Robot) -> np.ndarray:
    """The prior guess theta0 = the scenario's [truth] (see the module docstring)."""
    return robot.layout.theta(truth_params(scn, robot))


def nominal_robot(scn: Scenario) -> Robot:
    """The design model: the scenario's MJCF with theta0 written in, WITHOUT the hidden
    ``[truth.effects]`` (a design knows the model, not what the model lacks)."""
    robot = load_robot(scn.path, "robot", path=scn.robot)
    robot.set_params(truth_params(scn, robot))
    check_scenario(scn, robot)  # a slipped unit: InputError, or a PlausibilityWarning
    return robot
