"""The one list of identification methods: the built-in table, then those registered at run time.

Every verb reads it and nothing else: `calbench identify --method` offers the methods marked
``offered`` (so does a study's ``campaign.method``), `calbench montecarlo --method` offers
``both`` (the default: the methods marked ``in_both`` that apply to the robot: the one-step and
the paper's two-step, not the 5x slower iterated two-step), ``all`` (every method that applies)
and each method's ``choice`` (its own name, or the group it runs in: ``two-step`` runs both
step-2 variants), and the report's and the
Monte Carlo's loops over methods are loops over :func:`all_methods`. The table's order is the
order the Monte Carlo runs and reports them.

A method from outside calbench (a notebook, a test) is added with :func:`register_method`
before the verb runs; a Dask worker sees it only if the module that registers it is imported
there too.
"""

from __future__ import annotations

from calbench.bench.core import InputError
from calbench.bench.model import Robot

from .base import Method, NotApplicable
from .onestep import ONE_STEP
from .twostep import TWO_STEP, TWO_STEP_WEIGHTED
from .twostep_iterated import TWO_STEP_ITERATED

BUILTIN: tuple[Method, ...] = (ONE_STEP, TWO_STEP, TWO_STEP_WEIGHTED, TWO_STEP_ITERATED)
BOTH = "both"  # `montecarlo --method both` (default): the in_both methods that apply to the robot
ALL = "all"  # `montecarlo --method all`: every method that applies to the robot

_registered: dict[str, Method] = {}


def register_method(method: Method) -> Method:
    """Add ``method`` after the built-in ones; returns it. ValueError when its name (or
    ``both``, ``all``) is taken."""
    if method.name in (BOTH, ALL) or any(m.name == method.name for m in all_methods()):
        raise ValueError(f"an identification method named {method.name!r} exists already")
    _registered[method.name] = method
    return method


def unregister_method(name: str) -> None:
    """Remove a method added by :func:`register_method` (the built-in ones stay)."""
    _registered.pop(name, None)


def all_methods() -> tuple[Method, ...]:
    """Every method, the built-in ones first, in the order the Monte Carlo runs them."""
    return BUILTIN + tuple(_registered.values())


def method_names(offered_only: bool = False) -> tuple[str, ...]:
    """The methods' names (``offered_only``: those `calbench identify --method` offers)."""
    return tuple(m.name for m in all_methods() if m.offered or not offered_only)


def method_named(name: str) -> Method:
    """The method called ``name``; KeyError naming the methods there are."""
    for m in all_methods():
        if m.name == name:
            return m
    raise KeyError(f"no identification method {name!r} (there are {', '.join(method_names())})")


def montecarlo_choices() -> dict[str, tuple[str, ...]]:
    """`montecarlo --method` value -> the methods it runs: ``both`` (those marked in_both),
    ``all`` (all of them), then each method's ``choice`` in table order."""
    out: dict[str, tuple[str, ...]] = {
        BOTH: tuple(m.name for m in all_methods() if m.in_both),
        ALL: method_names(),
    }
    for m in all_methods():
        out[m.choice] = out.get(m.choice, ()) + (m.name,)
    return out


def identify_help() -> str:
    """`identify --method`'s help: each offered method's name and summary."""
    return "; ".join(f"{m.name}: {m.summary}" for m in all_methods() if m.offered)


def check_method(method: Method, robot: Robot, source, flag: str) -> None:
    """InputError (``source``: the robot's file, ``flag``: the option that chose the method)
    naming what the method needs, when the robot is outside it."""
    try:
        method.check(robot)
    except NotApplicable as exc:
        raise InputError(source, flag, method.requirement, str(exc)) from None


def select_methods(choice: str, robot: Robot, source) -> tuple[str, ...]:
    """The methods `montecarlo --method choice` runs on ``robot``: for ``both`` and ``all``
    those of theirs that apply to it; for any other choice all of its methods, InputError (naming ``source``) when one does
    not apply."""
    out = []
    for name in montecarlo_choices()[choice]:
        m = method_named(name)
        if choice in (BOTH, ALL):
            try:
                m.check(robot)
            except NotApplicable:
                continue
        else:
            check_method(m, robot, source, f"--method {choice}")
        out.append(name)
    return tuple(out)


__all__ = [
    "BUILTIN",
    "BOTH",
    "ALL",
    "register_method",
    "unregister_method",
    "all_methods",
    "method_names",
    "method_named",
    "montecarlo_choices",
    "identify_help",
    "check_method",
    "select_methods",
]
