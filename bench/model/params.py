"""The elastostatic parameters of a robot and their layout as one vector theta.

Paper eqs. (1) and (8): every actuated hinge i has a virtual spring of compliance k_i
(rad/(N*m)); every gravity-compensator spring has a stiffness K_C (N/m) and a preload length s0
(m, the spring's length at zero force). A robot with N actuated joints and compensator tendons
T_1..T_C has the parameter vector

    theta = [k1 ... kN, K_C(T_1), s0(T_1), ..., K_C(T_C), s0(T_C)]      (SI)

named ``k1 … kN``, ``<T>_stiffness``, ``<T>_preload`` (a tendon named ``compensator`` thus gives
the historical ``compensator_stiffness`` and ``compensator_preload``). :class:`ParamLayout` is
the one place that knows this order, the names, the units, the generic starting values an
estimator may use (never the MJCF's) and the bounds a fit may move in; everything else asks it.

The scenario and the log spell the tendon named :data:`LEGACY_COMPENSATOR` as
``[truth.compensator]`` and ``/truth/parameters.compensator`` (docs/contract.md); any other
tendon T as ``[truth.compensators.T]`` and ``compensators.T``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

LEGACY_COMPENSATOR = "compensator"  # the contract's [truth.compensator] / "compensator" key

COMPLIANCE_UNIT = "rad/(N*m)"
SPRING_UNITS = ("N/m", "m")
# Generic starting values per unit (identify/methods/onestep.py): sizes typical of heavy robots, never
# read from the MJCF. A preload has no generic size: the estimators start it at the spring's
# mean length over the plan (ParamLayout.generic_start), 1 m without geometry.
GENERIC = {COMPLIANCE_UNIT: 1e-7, "N/m": 1e6, "m": 1.0}
# Where a fit may move (identify/discover, the one-step's profiles): a compliance up to
# MAX_COMPLIANCE rad/(N*m) (a cobot's wrist is ~3e-5, a heavy robot's drives 1e-7 ... 2e-6; beyond,
# the plausibility checks warn and, past 1e-2, call it a slipped unit: bench/scenario/plausible.py,
# which quotes this same constant), a spring rate 1 N/m .. 1e9 N/m, a preload length 1 mm .. 10 m.
MAX_COMPLIANCE = 1e-4
BOUNDS = {COMPLIANCE_UNIT: (1e-12, MAX_COMPLIANCE), "N/m": (1.0, 1e9), "m": (1e-3, 10.0)}


@dataclass(frozen=True)
class Spring:
    """One compensator spring (paper eq. 8): K_C in N/m, preload length s0 in m."""

    stiffness: float
    preload: float


@dataclass(frozen=True)
class Params:
    """Elastostatic parameters in SI: the N actuator compliances (rad/(N*m)) and the
    compensator springs by tendon name (description order)."""

    compliance: np.ndarray
    springs: Mapping[str, Spring] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """The ``/truth/parameters`` form (docs/contract.md): ``compliance``, then
        ``compensator`` for the tendon of that name, then ``compensators`` for the others."""
        out: dict = {"compliance": [float(x) for x in self.compliance]}
        others = {}
        for name, s in self.springs.items():
            entry = {"stiffness": float(s.stiffness), "preload": float(s.preload)}
            if name == LEGACY_COMPENSATOR:
                out["compensator"] = entry
            else:
                others[name] = entry
        if others:
            out["compensators"] = others
        return out


def springs_from_message(m: Mapping) -> dict[str, Spring]:
    """The springs of a ``/truth/parameters``-style mapping (inverse of :meth:`Params.as_dict`);
    KeyError, TypeError or ValueError when malformed."""
    out: dict[str, Spring] = {}
    tables = dict(m.get("compensators") or {})
    if "compensator" in m:
        tables = {LEGACY_COMPENSATOR: m["compensator"], **tables}
    for name, t in tables.items():
        out[str(name)] = Spring(float(t["stiffness"]), float(t["preload"]))
    return out


@dataclass(frozen=True)
class ParamLayout:
    """The order, names and units of theta for N actuated joints and the named compensators."""

    n_joints: int
    compensators: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        return self.n_joints + 2 * len(self.compensators)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"k{i + 1}" for i in range(self.n_joints)) + tuple(
            f"{t}_{what}" for t in self.compensators for what in ("stiffness", "preload")
        )

    @property
    def units(self) -> tuple[str, ...]:
        return (COMPLIANCE_UNIT,) * self.n_joints + SPRING_UNITS * len(self.compensators)

    @property
    def compliance(self) -> slice:
        return slice(0, self.n_joints)

    @property
    def stiffness_index(self) -> np.ndarray:
        """Indices of the springs' K_C in theta (description order)."""
        return self.n_joints + 2 * np.arange(len(self.compensators))

    @property
    def preload_index(self) -> np.ndarray:
        """Indices of the springs' s0 in theta (each right after its K_C)."""
        return self.stiffness_index + 1

    @property
    def spring_index(self) -> np.ndarray:
        """Indices of every spring parameter (each K_C, then each s0) in theta: the least linear
        ones, which identify's and discover's profile check walk further (identify/core/profile.py)."""
        return np.r_[self.stiffness_index, self.preload_index].astype(int)

    def spring_of(self, index: int) -> int | None:
        """The compensator (position in ``compensators``) that theta[index] belongs to."""
        return None if index < self.n_joints else (index - self.n_joints) // 2

    # -- conversions ------------------------------------------------------------------------
    def params(self, theta) -> Params:
        """theta -> Params (a copy)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n,):
            raise ValueError(f"theta must have the {self.n} parameters {self.names}, got shape {theta.shape}")
        k = self.n_joints
        return Params(
            theta[:k].copy(),
            {
                t: Spring(float(theta[k + 2 * i]), float(theta[k + 2 * i + 1]))
                for i, t in enumerate(self.compensators)
            },
        )

    def theta(self, params: Params) -> np.ndarray:
        """Params -> theta; ValueError when they do not fit this layout."""
        k = np.asarray(params.compliance, dtype=float)
        if k.shape != (self.n_joints,):
            raise ValueError(f"expected {self.n_joints} compliances, got {k.shape}")
        if set(params.springs) != set(self.compensators):
            raise ValueError(
                f"expected the compensator springs {list(self.compensators)}, got {list(params.springs)}"
            )
        springs = [
            v for t in self.compensators for v in (params.springs[t].stiffness, params.springs[t].preload)
        ]
        return np.concatenate([k, np.asarray(springs, dtype=float)])

    # -- what an estimator may assume ---------------------------------------------------------
    def generic_start(self, preloads: Sequence[float] | None = None) -> np.ndarray:
        """Generic values (:data:`GENERIC`); ``preloads`` (one per compensator) replace the
        generic 1 m preload, e.g. the spring's mean length over a plan."""
        theta = np.array([GENERIC[u] for u in self.units])
        if preloads is not None:
            theta[self.preload_index] = np.asarray(preloads, dtype=float)
        return theta

    @property
    def lower(self) -> np.ndarray:
        return np.array([BOUNDS[u][0] for u in self.units])

    @property
    def upper(self) -> np.ndarray:
        return np.array([BOUNDS[u][1] for u in self.units])


def display_name(name: str) -> str:
    """A parameter's name for people: ``<T>_preload`` (the contract's name, kept in every JSON
    and log) is the spring's free length s0, shown as ``<T> free length`` (a length in mm, which
    "preload" would have an engineer read as a force); others unchanged."""
    return name[: -len("_preload")] + " free length" if name.endswith("_preload") else name


def free_length_note(names) -> str | None:
    """The line under a table that shows free lengths, naming what the JSON calls them."""
    pre = [n for n in names if n.endswith("_preload")]
    if not pre:
        return None
    return (
        f"{display_name(pre[0])}: the spring's free length s0 (eq. 8), a length, not a force; "
        f"`{pre[0]}` in the JSON (the contract's name)"
    )


__all__ = [
    "display_name",
    "free_length_note",
    "LEGACY_COMPENSATOR",
    "GENERIC",
    "BOUNDS",
    "Spring",
    "Params",
    "ParamLayout",
    "springs_from_message",
]
