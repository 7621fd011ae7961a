"""Plausibility of the quantities a person types (issue 21): a slipped unit named, not simulated.

A scenario or overlay value far outside what real robots and trackers span is almost surely a
unit written wrong: :class:`~calbench.bench.core.InputError` (exit status 2) naming the file, the
key, the likely mistake and the value probably meant. A value a little outside is odd but
possible: a :class:`PlausibilityWarning` (the command line prints it as one line on stderr).

=========================  ======================  =====================  ==========================
quantity                   quiet                   warning                error (likely mistake)
=========================  ======================  =====================  ==========================
tracker sigma, the ``a``   1 um ... 1 mm           1 nm ... 1 um,         >= 0.1 m (um or mm as m),
of distance / transverse                           1 mm ... 0.1 m         < 1 nm
joint compliance and the   1e-10 ... 1e-4          1e-12 ... 1e-10,       > 1e-2 rad/(N*m): >= 1e3 a
effects' compliances       rad/(N*m)               1e-4 ... 1e-2          stiffness in N*m/rad, else
                                                                          urad/(N*m) as rad/(N*m)
every pose (and work) q    some angle beyond 6.29  one pose only          two poses or more, all
                           deg                                            within +-2 pi: radians
payload mass M             M / robot 1e-2 ... 2    1e-3 ... 1e-2,         < 1e-3 (tonnes as kg),
                                                   2 ... 10               > 10 (grams as kg)
overlay density (kg/m^3)   500 ... 8000            100 ... 500,           < 100 (g/cm^3 as kg/m^3),
                                                   8000 ... 25000         > 25000
offsets, spring lengths,   < the robot's size      1 ... 10 sizes         > 10 sizes (mm as m)
the tracker's distance     (tracker: 30 sizes)     (tracker: 30 ... 300)  (tracker: > 300)
=========================  ======================  =====================  ==========================

The robot's size is the diagonal of the box around its bodies and geoms (with their bounding
spheres; not its sites, whose offsets are typed) at the reference pose (the FANUC: 4.8 m, the KR 270: 4.5 m); its mass the sum
of the MJCF's body masses (no check when zero). Compliance: the shipped robots' joints span 7e-8
... 2e-6 rad/(N*m); 1e-4 rad/(N*m) already turns 1 kN*m into 6 deg.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import mujoco
import numpy as np

from calbench.bench.core import InputError
from calbench.bench.model import MAX_COMPLIANCE, Robot

# rad/(N*m): the quiet band of a compliance; its top is the fit's own bound (bench/model's
# MAX_COMPLIANCE), so a value quoted as plausible here is one a fit can reach
COMPLIANCE_BAND = (1e-10, MAX_COMPLIANCE)
RADIAN_SPAN = 2 * math.pi + 0.01  # a wrist's angles in radians reach +-2 pi (q6 = 270 deg: 4.71)


class PlausibilityWarning(UserWarning):
    """An odd value that may still be meant (the command line prints it on one line)."""


@dataclass(frozen=True)
class Scale:
    """What a value is compared with: the robot's size (m) and mass (kg)."""

    size: float
    mass: float


def robot_scale(robot: Robot) -> Scale:
    """The robot's size and mass (module docstring), at its reference pose (q = 0)."""
    m = robot.model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(m, d)
    solid = m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE  # a floor is infinite: not the robot
    centre, r = d.geom_xpos[solid], m.geom_rbound[solid][:, None]
    allp = np.concatenate([d.xpos[1:], centre + r, centre - r])  # no sites: a typed offset is one
    size = float(np.linalg.norm(allp.max(axis=0) - allp.min(axis=0))) if len(allp) else 1.0
    return Scale(size=max(size, 0.1), mass=float(m.body_mass.sum()))


def warn(file, key: str, message: str) -> None:
    warnings.warn(f"{file}: {key}: {message}", PlausibilityWarning, stacklevel=3)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def check_length(file, key: str, value: float, scale: Scale, what: str = "offset") -> None:
    """A length (m) the person typed against the robot's size: mm for m beyond 10 sizes."""
    if not math.isfinite(value) or value <= scale.size:
        return
    if value > 10 * scale.size:
        raise InputError(
            file,
            key,
            f"an {what} in metres, within the robot's size ({scale.size:.2f} m)",
            f"{_fmt(value)} m: millimetres written as metres? ({_fmt(value / 1000)} m)",
        )
    warn(file, key, f"{what} {_fmt(value)} m is longer than the whole robot ({scale.size:.2f} m)")


def check_sigma(file, key: str, sigma: float) -> None:
    """A tracker's 1-sigma error (m): 1 um ... 1 mm quiet."""
    if sigma >= 0.1:
        raise InputError(
            file,
            key,
            "a tracker's 1-sigma error in metres (1 um ... 1 mm: 20 um is 20e-6)",
            f"{_fmt(sigma)} m: micrometres written as metres? ({_fmt(sigma * 1e-6)} m)",
        )
    if 0 < sigma < 1e-9:
        raise InputError(
            file,
            key,
            "a tracker's 1-sigma error in metres (1 um ... 1 mm: 20 um is 20e-6)",
            f"{_fmt(sigma)} m, finer than any instrument: micrometres converted twice?",
        )
    if 0 < sigma < 1e-6 or sigma > 1e-3:
        warn(file, key, f"tracker error {_fmt(sigma)} m is outside a laser tracker's 1 um ... 1 mm")


def check_compliance(file, key: str, values) -> None:
    """Joint or effect compliances (rad/(N*m)), each nonzero one against COMPLIANCE_BAND."""
    lo, hi = (f"{x:.0e}".replace("e-0", "e-") for x in COMPLIANCE_BAND)
    expected = f"a compliance in rad/(N*m) (a joint's: {lo} ... {hi})"
    for i, c in enumerate(np.asarray(values, float).ravel()):
        k = f"{key}[{i}]"
        if c > 1e3:
            raise InputError(
                file,
                k,
                expected,
                f"{_fmt(c)}: a stiffness in N*m/rad? (compliance = 1 / stiffness = {_fmt(1 / c)})",
            )
        if c > 1e-2:
            raise InputError(
                file,
                k,
                expected,
                f"{_fmt(c)}: urad/(N*m) written as rad/(N*m)? ({_fmt(c * 1e-6)} rad/(N*m))",
            )
        if c > COMPLIANCE_BAND[1] or 0 < c < COMPLIANCE_BAND[0]:
            warn(file, k, f"compliance {_fmt(c)} rad/(N*m) is outside a robot joint's {lo} ... {hi}")


def check_density(file, key: str, rho: float) -> None:
    """A material density (kg/m^3) to fill a robot's geometry with: engineering materials span
    ~100 (foam) ... 22600 (osmium); below 100, g/cm^3 written for kg/m^3 (steel 7.85 for 7850)."""
    if rho < 100.0:
        raise InputError(
            file,
            key,
            "a density in kg/m^3 (steel 7850, aluminium 2700, a robot's average ~1000 ... 3000)",
            f"{_fmt(rho)}: g/cm^3 written as kg/m^3? ({_fmt(rho * 1000)} kg/m^3)",
        )
    if rho > 25000.0:
        raise InputError(
            file,
            key,
            "a density in kg/m^3 (steel 7850, aluminium 2700, a robot's average ~1000 ... 3000)",
            f"{_fmt(rho)} kg/m^3, denser than any metal: g/m^3 or a mass?",
        )
    if rho > 8000.0 or rho < 500.0:
        warn(file, key, f"density {_fmt(rho)} kg/m^3: beyond a robot's materials (500 ... 8000)")


def check_poses(file, angles: list[tuple[str, np.ndarray]]) -> None:
    """Joint angles the file gave in degrees (here rad): all within +-pi deg looks like radians."""
    if not angles:
        return
    top = max(float(np.max(np.abs(q))) if len(q) else 0.0 for _, q in angles)
    if top == 0.0 or top > math.radians(RADIAN_SPAN):
        return
    key, q = angles[0]
    shown = [round(math.degrees(x), 4) for x in q]
    if len(angles) >= 2:
        raise InputError(
            file,
            "pose",
            "joint angles in degrees",
            f"every angle of every pose within +-{RADIAN_SPAN:.2f} ({key} = {shown}): radians written for "
            "degrees? "
            f"({key} = {[round(math.degrees(x), 1) for x in shown]} deg)",
        )
    warn(file, key, f"every angle within +-{RADIAN_SPAN:.2f} deg ({shown}): radians written for degrees?")


def check_mass(file, key: str, mass: float, scale: Scale) -> None:
    """A payload (kg) against the robot's mass."""
    if scale.mass <= 0 or not mass > 0:
        return
    ratio = mass / scale.mass
    expected = f"a payload in kg (the robot's links weigh {scale.mass:.0f} kg)"
    if ratio < 1e-3:
        raise InputError(
            file, key, expected, f"{_fmt(mass)} kg: tonnes written as kg? ({_fmt(mass * 1000)} kg)"
        )
    if ratio > 10:
        raise InputError(
            file, key, expected, f"{_fmt(mass)} kg: grams written as kg? ({_fmt(mass / 1000)} kg)"
        )
    if ratio < 1e-2 or ratio > 2:
        warn(file, key, f"payload {_fmt(mass)} kg against a robot of {scale.mass:.0f} kg")


def check_tracker(file, spec, scale: Scale, base: np.ndarray | None = None) -> None:
    """The ``[tracker]`` table: its noise model's error terms and its distance from the robot."""
    if spec.model == "isotropic":
        check_sigma(file, "tracker.sigma", float(spec.sigma))
    else:
        check_sigma(file, "tracker.distance[0]", float(spec.distance[0]))
        check_sigma(file, "tracker.transverse[0]", float(spec.transverse[0]))
    if base is None:
        return
    far = float(np.linalg.norm(np.asarray(spec.position, float) - base))
    if far > 300 * scale.size:
        raise InputError(
            file,
            "tracker.position",
            f"a position in metres, within tens of metres of the robot (its size: {scale.size:.2f} m)",
            f"{_fmt(far)} m from the robot: millimetres written as metres? ({_fmt(far / 1000)} m)",
        )
    if far > 30 * scale.size:
        warn(file, "tracker.position", f"the tracker stands {_fmt(far)} m from the robot")


def check_scenario(scn, robot: Robot) -> None:
    """Every typed quantity of a scenario (bench.scenario.Scenario) against ``robot``."""
    scale = robot_scale(robot)
    f = scn.path
    base = _base(robot)
    check_tracker(f, scn.tracker, scale, base)
    check_compliance(f, "truth.compliance", scn.compliance)
    for name, s in scn.compensators.items():
        key = "truth.compensator" if name == "compensator" and "[truth.compensator]" in scn.text else None
        key = key or f"truth.compensators.{name}"
        check_length(f, f"{key}.preload", float(s.preload), scale, "spring length")
    for name, table in scn.effects.items():
        if "compliance" in table:
            check_compliance(f, f"truth.effects.{name}.compliance", table["compliance"])
    check_campaign(scn, scale)


def check_campaign(scn, scale: Scale) -> None:
    """What a scenario and a plan share: the poses and the payload."""
    angles = [(f"pose[{i}].q", p.q) for i, p in enumerate(scn.poses)]
    if scn.work is not None:
        angles.append(("work.q", scn.work.q))
    check_poses(scn.path, angles)
    if any(p.wrench is None for p in scn.poses):  # the payload hangs at some pose
        check_mass(scn.path, "load.mass", float(scn.load_mass), scale)


def check_plan(plan, robot: Robot) -> None:
    """A plan (bench.scenario.Plan): the tracker's noise, the poses, the payload."""
    scale = robot_scale(robot)
    check_tracker(plan.path, plan.tracker, scale, _base(robot) if plan.tracker_placed else None)
    check_campaign(plan, scale)


def _base(robot: Robot) -> np.ndarray:
    """Where the robot stands: the anchor of its first actuated joint at the reference pose."""
    d = mujoco.MjData(robot.model)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(robot.model, d)
    return d.xanchor[robot.act_joint[0]].copy()


__all__ = [
    "PlausibilityWarning",
    "Scale",
    "robot_scale",
    "check_length",
    "check_sigma",
    "check_compliance",
    "check_density",
    "check_poses",
    "check_mass",
    "check_tracker",
    "check_scenario",
    "check_campaign",
    "check_plan",
]
