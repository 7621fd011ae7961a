"""The effect registry: every effect by name, with everything its registration declares.

Adding an effect = one new file in bench/model/effects/ holding one factory function (keyword
options -> :class:`~.base.Effect`) decorated with :func:`register_effect`, which carries everything
about it:

* ``truth``: the keys of its scenario table ``[truth.effects.NAME]`` (a tuple of
  :class:`~.base.Field`: type, unit, range, required or not), with ``from_truth`` mapping the
  checked table (SI) to (factory options, parameters). The scenario parser reads the tables of
  every registered effect that has one, and only those (bench/scenario/parse.py); an effect
  without ``truth`` cannot be hidden in a scenario (the compensator: the truth gives it in
  ``[truth.compensator]``);
* ``discover``: the structural options discovery tries (a list, or a function of the robot;
  none = a truth-only effect), on the readings ``readings`` names: ``deflections`` (loaded minus
  unloaded, `calbench discover`) or ``absolute`` (the geometric effects, which deflections cancel
  to first order: `calbench discover --geometry`, identify/discover/geometric.py);
* ``priors``: its parameters' priors where the per-unit defaults (:data:`~.base.UNIT_PRIORS`)
  do not fit.

Nothing else in the project needs to change. The package imports its modules on first use,
the built-in effects in :data:`BUILTIN`'s order and then any other by name: that order is the
order the bench applies a truth's effects (and lists them in the log) and discovery tries them.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from calbench.bench.model import Robot

from .base import UNIT_PRIORS, Effect, Field, Prior

# the built-in effects' modules (each named for its physics; the factory and the registry carry
# the effect's name): link_compliance, base_compliance, tool_compliance, joint_nonlinearity,
# compensator, tracker_drift
BUILTIN = ("link_springs", "base_tilt", "tool_mount", "cubic_drive", "spring_compensator", "drift")

REGISTRY: dict[str, Callable[..., Effect]] = {}
# effect -> the keys of its [truth.effects.NAME] table, and the map of that table to (options, params)
TRUTH_SCHEMAS: dict[str, tuple[Field, ...]] = {}
_FROM_TRUTH: dict[str, Callable[[dict], tuple[dict, np.ndarray]]] = {}
# effect -> the structural options discovery tries on a robot (a function of the Robot)
DISCOVERY_OPTIONS: dict[str, Callable[[Robot], list[dict]]] = {}
# the same for discovery on absolute readings (discover --geometry)
GEOMETRY_OPTIONS: dict[str, Callable[[Robot], list[dict]]] = {}
READINGS = ("deflections", "absolute")
_PRIORS: dict[str, dict[str, Prior]] = {}  # effect -> parameter name -> prior override


def register_effect(
    name: str,
    *,
    truth: tuple[Field, ...] | None = None,
    from_truth: Callable[[dict], tuple[dict, np.ndarray]] | None = None,
    discover: list[dict] | Callable[[Robot], list[dict]] | None = None,
    priors: dict[str, Prior] | None = None,
    readings: str = "deflections",
):
    """Decorator: add an effect factory (keyword options -> Effect) to the library.

    truth declares the keys of the effect's scenario table (bench.scenario checks them) and
    from_truth maps the checked table (SI values) to (factory options, parameters): both or
    neither. discover gives the structural options (factory keyword arguments) that discovery
    tries as candidates: a list, or a function of the robot returning one (e.g. one per
    actuated joint); None keeps the effect out of discovery (truth only). priors overrides
    :data:`UNIT_PRIORS` for named parameters. readings: the readings discovery tries the effect
    on (``deflections`` or ``absolute``, the module docstring)."""
    if name in REGISTRY:
        raise ValueError(f"effect {name!r} is already registered")
    if readings not in READINGS:
        raise ValueError(f"effect {name!r}: readings must be one of {READINGS}, got {readings!r}")
    if (truth is None) != (from_truth is None):
        raise ValueError(f"effect {name!r}: give both truth (its table's keys) and from_truth, or neither")
    if truth is not None:
        keys = [f.key for f in truth]
        if not keys or len(set(keys)) != len(keys):
            raise ValueError(f"effect {name!r}: truth must name at least one key, each once, got {keys}")

    def deco(factory: Callable[..., Effect]) -> Callable[..., Effect]:
        REGISTRY[name] = factory
        if truth is not None:
            TRUTH_SCHEMAS[name] = tuple(truth)
            _FROM_TRUTH[name] = from_truth
        if discover is not None:
            fixed = None if callable(discover) else tuple(dict(o) for o in discover)
            table = DISCOVERY_OPTIONS if readings == "deflections" else GEOMETRY_OPTIONS
            table[name] = discover if fixed is None else (lambda robot: [dict(o) for o in fixed])
        if priors:
            _PRIORS[name] = dict(priors)
        return factory

    return deco


def unregister_effect(name: str) -> None:
    """Remove an effect registered at run time (a test's toy, a notebook's experiment)."""
    for table in (REGISTRY, TRUTH_SCHEMAS, _FROM_TRUTH, DISCOVERY_OPTIONS, GEOMETRY_OPTIONS, _PRIORS):
        table.pop(name, None)


def load_members(package: str, path: str) -> None:
    """Import every effect module of the package (each registers itself): the built-in ones in
    :data:`BUILTIN`'s order, then the others by name."""
    others = sorted(m.name for m in pkgutil.iter_modules([str(Path(path).parent)]) if m.name not in BUILTIN)
    for module in (*BUILTIN, *others):
        importlib.import_module(f"{package}.{module}")


def priors(effect: Effect) -> list[Prior]:
    """The prior of each of the effect's parameters: its registered override, else its unit's."""
    own = _PRIORS.get(effect.name, {})
    return [own.get(n) or UNIT_PRIORS[u] for n, u in zip(effect.param_names, effect.units)]


def discovery_library(robot: Robot, readings: str = "deflections") -> list[Effect]:
    """Every discovery candidate on this robot: each registered effect with each of the
    structural options it declares for the robot, on ``readings`` (deflections or absolute)."""
    table = DISCOVERY_OPTIONS if readings == "deflections" else GEOMETRY_OPTIONS
    return [REGISTRY[name](**opts) for name, options in table.items() for opts in options(robot)]


def effect_from_truth(name: str, table: dict) -> tuple[Effect, np.ndarray]:
    """The Effect and its true parameters from one `scn.effects[name]` entry (SI values, as
    :func:`~.base.read_table` returns them)."""
    if name not in _FROM_TRUTH:
        raise KeyError(f"unknown effect {name!r}; known: {sorted(_FROM_TRUTH)}")
    options, params = _FROM_TRUTH[name](table)
    effect = REGISTRY[name](**options)
    return effect, effect._check(params)
