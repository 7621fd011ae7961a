"""The effect family's interface: what one hidden physical effect is (:class:`Effect`), the keys of
its scenario table (:class:`Field`), and what a fit assumes of its parameters (:class:`Prior`).

An effect is a named edit of the robot's MJCF (mujoco.MjSpec). It knows its parameters (SI), how
to edit a spec (:meth:`Effect.apply`, then compile) and how to write the same values into an
already compiled model without recompiling (:meth:`Effect.set_params`, the fast path for
fitting). Both give the same model. A MEASUREMENT-SIDE effect (`tracker_drift`) changes what the
instrument reports, not the robot: it leaves the spec alone and adds a term to every predicted
deflection instead (:meth:`Effect.deflection_term`, given the :class:`ObservationRows` it applies to).

Effects know no robot by name: what they need comes from the robot description the MJCF carries
(bench/model/description.py: the actuated joints, the payload and reflector sites, the optional
``calbench:links`` and ``calbench:compensator_sites``) or from the model's tree.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from calbench.bench.core import InputError, Table, frozen_array
from calbench.bench.model import Robot


@dataclass(frozen=True)
class ObservationRows:
    """What a measurement-side effect acts on: the observation rows of a campaign, one
    (pose index, reflector name) per measured deflection, and the tracker's orientation
    (world-from-tracker rotation, bench.tracker.tracker_rotation)."""

    rows: tuple[tuple[int, str], ...]
    tracker_rotation: np.ndarray


def no_edit(*_args) -> None:
    """The spec and model edit of a measurement-side effect: none."""


@dataclass(frozen=True)
class Effect:
    """One candidate physical effect: a structural choice (options) and SI parameters.

    name: the docs/contract.md effect name; param_names / units: its parameters, in order;
    options: structural choices (which link, which axes, which joint). A robot-side effect edits
    the spec (``_apply``) and writes its parameters into a compiled model (``_set``), and may
    write nothing but spring stiffnesses and rest lengths there (discovery keeps the springs'
    part of the stiffness matrix analytic, identify/discover/fit.py). A measurement-side effect
    has ``_measure`` instead: params, options, :class:`ObservationRows` -> (M, 3) world-frame term added
    to every deflection.
    """

    name: str
    param_names: tuple[str, ...]
    options: dict
    units: tuple[str, ...] = ()
    _apply: Callable[[mujoco.MjSpec, np.ndarray, dict], None] = field(default=None, repr=False, compare=False)
    _set: Callable[[Robot, np.ndarray, dict], None] = field(default=None, repr=False, compare=False)
    _measure: Callable[[np.ndarray, dict, ObservationRows], np.ndarray] | None = field(
        default=None, repr=False, compare=False
    )

    def _check(self, params) -> np.ndarray:
        p = np.atleast_1d(np.asarray(params, dtype=float))
        if p.shape != (len(self.param_names),):
            raise ValueError(
                f"{self.name}: expected {len(self.param_names)} parameters "
                f"{self.param_names}, got {p.tolist()}"
            )
        if not np.isfinite(p).all():
            raise ValueError(f"{self.name}: parameters must be finite, got {p.tolist()}")
        return p

    def apply(self, spec: mujoco.MjSpec, params) -> None:
        """Edit the spec in place (compile afterwards)."""
        self._apply(spec, self._check(params), self.options)

    def set_params(self, robot: Robot, params) -> None:
        """Write the parameters into a model that `apply` already built (no recompile)."""
        self._set(robot, self._check(params), self.options)

    @property
    def measurement_side(self) -> bool:
        """True when the effect changes the readings, not the robot (no spec edit)."""
        return self._measure is not None

    def deflection_term(self, params, readings: ObservationRows) -> np.ndarray:
        """(M, 3) m, world frame: what a measurement-side effect adds to each measured
        deflection (loaded minus unloaded reading); zeros for a robot-side effect."""
        if self._measure is None:
            return np.zeros((len(readings.rows), 3))
        return np.asarray(self._measure(self._check(params), self.options, readings), dtype=float)

    @property
    def detail(self) -> str:
        """Short human description of the structural choice, e.g. "forearm" or "j3"."""
        if "link" in self.options:
            return str(self.options["link"])
        if "joint" in self.options:
            return f"j{self.options['joint']}"
        return ""


# --------------------------------------------------------------------------- the scenario table

KINDS = ("string", "integer", "number", "vector")


@dataclass(frozen=True)
class Field:
    """One key of an effect's ``[truth.effects.NAME]`` table (docs/contract.md), as its
    registration declares it: the TOML type (``kind``: string, integer, number or vector), the
    SI unit of the value ("" for a name or an index), the range (``lo`` for an integer;
    ``positive`` (> 0), ``nonneg`` (>= 0) or ``max_abs`` for a number or every element of a vector), a
    vector's ``size`` (None: any length >= 1) and whether the key must be present. The file
    speaks SI: what :meth:`read` returns is the value as written (a vector frozen)."""

    key: str
    kind: str
    unit: str = ""
    size: int | None = None
    lo: int | None = None
    positive: bool = False
    nonneg: bool = False
    required: bool = True
    doc: str = ""
    max_abs: float | None = None  # |value| (every element) at most this, in the unit

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"Field {self.key!r}: kind must be one of {KINDS}, got {self.kind!r}")

    def read(self, table: Table) -> Any:
        """The key's value, checked by :class:`~calbench.bench.core.Table` (an InputError names
        the file, the key path and what was expected)."""
        if self.kind == "string":
            return table.string(self.key)
        if self.kind == "integer":
            return table.integer(self.key, self.lo)
        if self.kind == "number":
            value = table.number(self.key, positive=self.positive, nonneg=self.nonneg)
        else:
            value = frozen_array(
                table.vector(self.key, self.size, positive=self.positive, nonneg=self.nonneg)
            )
        if self.max_abs is not None and np.any(np.abs(value) > self.max_abs):
            got = value.tolist() if isinstance(value, np.ndarray) else value
            raise InputError(
                table.file, table.key(self.key), f"values within +-{self.max_abs} {self.unit}", got
            )
        return value


def read_table(schema: tuple[Field, ...], table: Table) -> dict[str, Any]:
    """An effect's scenario table checked against its schema: no key outside it, every required
    key present and valid, the optional ones valid when given. Values by key, in schema order."""
    table.only(tuple(f.key for f in schema))
    return {f.key: f.read(table) for f in schema if f.required or table.has(f.key)}


# --------------------------------------------------------------------------- priors


@dataclass(frozen=True)
class Prior:
    """What a fit assumes of one effect parameter: where it starts (its "absent" value, or a
    generic size where absent makes the others meaningless), its bounds, a typical size
    (finite-difference steps at zero) and whether the deflections are linear in it (then a
    candidate fit needs no multi-start, identify/discover/search.py) and whether discovery's
    first-order (score) test is defined at its start (identify/discover/decide.py: not for a new
    spring, whose free length means nothing while its rate is zero). SI units."""

    start: float
    lower: float
    upper: float
    size: float
    linear: bool = False  # the deflections are linear in it: one start finds the optimum
    first_order: bool = True  # a score test at the current model, the effect at its start, is defined


# Per physical UNIT: the default priors of any effect parameter with that unit. A new effect with
# a new unit adds one line (or passes its own priors to @register_effect).
UNIT_PRIORS: dict[str, Prior] = {
    # compliance: >= 0, and at most 1e-6 rad/(N*m) (a spring softer than any drive of this
    # robot is a broken part, not a compliance); starts at a typical size so that hinges that
    # only move together (upper-arm x and z, braced by the coupler rod) are not locked
    "rad/(N*m)": Prior(start=1e-8, lower=1e-12, upper=1e-6, size=1e-8),
    "N*m/rad^3": Prior(start=0.0, lower=-np.inf, upper=np.inf, size=1e12),  # cubic: none
    "N/m": Prior(start=1e6, lower=1.0, upper=1e9, size=1e6, first_order=False),  # spring rate
    "m": Prior(start=1.0, lower=1e-3, upper=10.0, size=1.0, first_order=False),  # free length
}
