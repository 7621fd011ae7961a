"""A small heavy six-axis arm the URDF tests write themselves, with its overlay and a scenario.

``arm_urdf``: base, turret (J1 about z), upper arm (J2 about y), forearm (J3 about y), wrist
(J4 about x, continuous; J5 about y; J6 about x, continuous), a ``tool0`` frame fixed to the last
link. ``compensator=True`` adds nothing to the URDF (the spring lives in the overlay);
``loop=True`` turns it into a quasi-serial arm with an active parallelogram, FANUC style: the
forearm hangs on a passive ``elbow`` and is driven by a ``crank`` coaxial with J2 through a
passive ``rod`` whose end the overlay connects to the forearm's rear; J3 is then the crank
(= the forearm's absolute pitch). Geometry in boxes and cylinders (one cylinder laid along x by
an rpy, to exercise orientations); masses of a ~1.6 t robot; every moving link has an
<inertial> with off-axis centres of mass.
"""

from __future__ import annotations

import numpy as np

# URDF joint: name, type, parent, child, xyz, rpy, axis, (lower, upper) or None
SERIAL = [
    ("joint_1", "revolute", "base_link", "link_1", (0, 0, 0.45), (0, 0, 0), (0, 0, 1), (-170, 170)),
    ("joint_2", "revolute", "link_1", "link_2", (0.3, 0, 0.55), (0, 0, 0), (0, 1, 0), (-60, 100)),
    ("joint_3", "revolute", "link_2", "link_3", (0, 0, 1.1), (0, 0, 0), (0, 1, 0), (-90, 90)),
    ("joint_4", "continuous", "link_3", "link_4", (1.0, 0, 0.2), (0, 0, 0), (1, 0, 0), None),
    ("joint_5", "revolute", "link_4", "link_5", (0.3, 0, 0), (0, 0, 0), (0, 1, 0), (-120, 120)),
    ("joint_6", "continuous", "link_5", "link_6", (0.25, 0, 0), (0, 0, 0), (1, 0, 0), None),
    ("tool0_joint", "fixed", "link_6", "tool0", (0.1, 0, 0), (0.1, -0.2, 0.3), None, None),
]
# The parallelogram: J3 drives a crank on the turret; the forearm hangs on the passive elbow.
LOOP = [
    ("joint_1", "revolute", "base_link", "link_1", (0, 0, 0.45), (0, 0, 0), (0, 0, 1), (-170, 170)),
    ("joint_2", "revolute", "link_1", "link_2", (0.3, 0, 0.55), (0, 0, 0), (0, 1, 0), (-60, 100)),
    ("elbow", "revolute", "link_2", "link_3", (0, 0, 1.1), (0, 0, 0), (0, 1, 0), (-180, 180)),
    ("joint_3", "revolute", "link_1", "crank", (0.3, -0.35, 0.55), (0, 0, 0), (0, 1, 0), (-90, 90)),
    ("rod", "revolute", "crank", "rod", (-0.4, 0, 0), (0, 0, 0), (0, 1, 0), (-180, 180)),
    *SERIAL[3:],
]
# link: mass, com, diagonal inertia, geometry (URDF <geometry> body), geometry origin xyz, rpy
LINKS = {
    "base_link": (
        500.0,
        (0, 0, 0.2),
        (40, 40, 50),
        '<cylinder radius="0.4" length="0.45"/>',
        (0, 0, 0.225),
        (0, 0, 0),
    ),
    "link_1": (600.0, (0.1, 0, 0.3), (90, 110, 100), '<box size="0.7 0.6 0.6"/>', (0.1, 0, 0.3), (0, 0, 0)),
    "link_2": (
        400.0,
        (0.02, 0, 0.55),
        (50, 50, 8),
        '<cylinder radius="0.15" length="0.9"/>',
        (0, 0, 0.55),
        (0, 0, 0),
    ),
    "link_3": (
        300.0,
        (0.4, 0.01, 0.15),
        (6, 45, 45),
        '<cylinder radius="0.13" length="0.8"/>',
        (0.5, 0, 0.2),
        (0, 1.5707963267948966, 0),
    ),
    "link_4": (60.0, (0.12, 0, 0.01), (0.8, 1.5, 1.5), '<box size="0.25 0.2 0.2"/>', (0.12, 0, 0), (0, 0, 0)),
    "link_5": (
        40.0,
        (0.1, 0, 0),
        (0.4, 0.6, 0.6),
        '<cylinder radius="0.1" length="0.22"/>',
        (0.1, 0, 0),
        (1.5707963267948966, 0, 0),
    ),
    "link_6": (
        30.0,
        (0.04, 0, -0.02),
        (0.5, 0.3, 0.3),
        '<box size="0.05 0.36 0.36"/>',
        (0.06, 0, 0),
        (0, 0, 0),
    ),
    "crank": (50.0, (-0.2, 0, 0), (0.2, 1.0, 1.0), '<box size="0.45 0.08 0.08"/>', (-0.2, 0, 0), (0, 0, 0)),
    "rod": (
        30.0,
        (0, 0, 0.55),
        (3.0, 3.0, 0.05),
        '<cylinder radius="0.04" length="1.1"/>',
        (0, 0, 0.55),
        (0, 0, 0),
    ),
}


def _v(x) -> str:
    return " ".join(repr(float(a)) for a in x)


def _link(name: str, inertial: bool = True, extra: str = "") -> str:
    if name == "tool0":
        return '  <link name="tool0"/>\n'
    mass, com, inertia, geom, gxyz, grpy = LINKS[name]
    ine = (
        (
            f'    <inertial><origin xyz="{_v(com)}" rpy="0 0 0"/><mass value="{mass!r}"/>'
            f'<inertia ixx="{inertia[0]!r}" iyy="{inertia[1]!r}" izz="{inertia[2]!r}" ixy="0" ixz="0" iyz="0"/>'
            "</inertial>\n"
        )
        if inertial
        else ""
    )
    return (
        f'  <link name="{name}">\n{ine}'
        f'    <visual><origin xyz="{_v(gxyz)}" rpy="{_v(grpy)}"/><geometry>{geom}</geometry></visual>\n'
        f'    <collision><origin xyz="{_v(gxyz)}" rpy="{_v(grpy)}"/><geometry>{geom}</geometry></collision>\n'
        f"{extra}  </link>\n"
    )


def _joint(j) -> str:
    name, typ, parent, child, xyz, rpy, axis, lim = j
    out = (
        f'  <joint name="{name}" type="{typ}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{_v(xyz)}" rpy="{_v(rpy)}"/>'
    )
    if axis is not None:
        out += f'<axis xyz="{_v(axis)}"/>'
    if lim is not None:
        out += (
            f'<limit lower="{float(np.radians(lim[0]))!r}" upper="{float(np.radians(lim[1]))!r}" effort="50000" '
            'velocity="1.5"/>'
        )
    elif typ == "continuous":
        out += '<limit effort="20000" velocity="2"/>'
    return out + "</joint>\n"


def joints(loop: bool = False) -> list:
    return LOOP if loop else SERIAL


def arm_urdf(
    loop: bool = False,
    no_inertial: str | None = None,
    extra_links: dict | None = None,
    extra_joints: str = "",
) -> str:
    """The arm's URDF text; ``no_inertial`` drops that link's <inertial>; ``extra_links`` maps a
    link to extra XML inside it (e.g. a mesh <collision>); ``extra_joints`` adds raw XML."""
    js = joints(loop)
    names = ["base_link"] + [j[3] for j in js]
    extra_links = extra_links or {}
    body = "".join(_link(n, n != no_inertial, extra_links.get(n, "")) for n in names)
    return (
        f'<?xml version="1.0"?>\n<robot name="{"arm6_loop" if loop else "arm6"}">\n{body}'
        + "".join(_joint(j) for j in js)
        + extra_joints
        + "</robot>\n"
    )


def link_masses(loop: bool = False) -> dict[str, float]:
    return {j[3]: LINKS[j[3]][0] for j in joints(loop) if j[3] in LINKS}


ACTUATED = ["joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6"]

OVERLAY = """actuated = {actuated}

[payload]
link = "tool0"
pos = [0.35, 0.0, -0.15]

[flange]
link = "tool0"
pos = [0.0, 0.0, 0.0]

[reflectors.r1]
link = "link_6"
pos = [0.25, 0.3, 0.25]

[reflectors.r2]
link = "tool0"
pos = [0.15, -0.3, 0.25]

[reflectors.r3]
link = "tool0"
pos = [0.15, 0.0, -0.35]
"""

# Compensator across J2 (paper Fig. 4): l_c = 0.9 m from J2 on the turret, 40 deg behind the
# vertical; l_2 = 0.45 m up the upper arm; both 0.35 m off the arm's plane.
BAL_FROM = f'{{ link = "link_1", pos = [{float(0.3 - 0.9 * np.sin(np.radians(40.0)))!r}, 0.35, {float(0.55 + 0.9 * np.cos(np.radians(40.0)))!r}] }}'
BAL_TO = '{ link = "link_2", pos = [0.0, 0.35, 0.45] }'
COMPENSATOR = f"""
[compensators.balancer]
stiffness = 1.5e6
preload = 0.8
from = {BAL_FROM}
to = {BAL_TO}
"""
# The balancer's two mounts alone, for a model that lacks the spring (discovery tries one there).
MOUNTS = f"compensator_sites = {{ from = {BAL_FROM}, to = {BAL_TO} }}\n"

LOOP_OVERLAY = """
[loops.parallelogram]
passive = ["elbow", "rod"]
site1 = { link = "rod", pos = [0.0, 0.0, 1.1] }
site2 = { link = "link_3", pos = [-0.4, -0.35, 0.0] }
"""


def arm_overlay(
    compensator: bool = False, loop: bool = False, actuated=None, extra: str = "", top: str = ""
) -> str:
    """The overlay; ``top`` adds top-level keys (before the first table), ``extra`` tables."""
    text = OVERLAY.format(actuated="[" + ", ".join(f'"{a}"' for a in (actuated or ACTUATED)) + "]")
    return top + text + (COMPENSATOR if compensator else "") + (LOOP_OVERLAY if loop else "") + extra


# Compliances of a heavy robot's drives (rad/(N*m)), stiff base to soft wrist.
TRUTH_K = [0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6]


def poses(loop: bool = False) -> list[tuple[list[float], list[float] | None]]:
    """A plan over J2 and J3 (or the crank: |q3 - q2| <= 60 deg keeps the parallelogram 30 deg
    from degenerate), wrist angles turning the tool offset through the wrist axes, and lateral
    pulls that load J1 (a vertical load cannot, paper §5.1)."""
    q2s = [-40.0, -10.0, 20.0, 50.0, 80.0]
    out = []
    for i, q2 in enumerate(q2s):
        for k, q3 in enumerate((-30.0, 10.0, 40.0)):
            if loop and abs(q3 - q2) > 60.0:
                q3 = q2 + np.sign(q3 - q2) * 60.0
            q = [
                15.0 * (i - 2),
                q2,
                q3,
                [0.0, 60.0, -90.0][k],
                [30.0, -45.0, 60.0][(i + k) % 3],
                [0.0, 90.0, -45.0][(i + 2 * k) % 3],
            ]
            out.append((q, None))
    for q, w in (
        ([30.0, 20.0, 0.0, 0.0, 30.0, 0.0], [0.0, 5000.0, -3000.0, 0.0, 0.0, 0.0]),
        ([-45.0, 40.0, 20.0, 45.0, -30.0, 90.0], [4000.0, -3000.0, -2000.0, 500.0, 0.0, 0.0]),
        ([60.0, 0.0, -20.0, -60.0, 45.0, -90.0], [-3000.0, -4000.0, -3000.0, 0.0, 600.0, 0.0]),
    ):
        out.append((q, w))
    return out


def scenario(robot: str, compensator: bool = False, loop: bool = False, seed: int = 3) -> str:
    lines = [
        f'name = "urdf arm"\nrobot = "{robot}"\nseed = {seed}\n\n[truth]',
        f"compliance = [{', '.join(repr(k) for k in TRUTH_K)}]",
    ]
    if compensator:
        lines.append("\n[truth.compensators.balancer]\nstiffness = 1.5e6\npreload = 0.8")
    lines.append("\n[tracker]\nsigma = 20e-6\nposition = [4.0, -2.5, 1.8]\n\n[load]\nmass = 400.0\n")
    for q, w in poses(loop):
        lines.append("[[pose]]\nq = [" + ", ".join(repr(float(x)) for x in q) + "]")
        if w is not None:
            lines.append("wrench = [" + ", ".join(repr(float(x)) for x in w) + "]")
        lines.append("")
    return "\n".join(lines)


def convert_arm(folder, urdf: str, overlay: str):
    """``calbench from-urdf`` on ``urdf`` and ``overlay`` written to ``folder`` (arm.urdf, arm.toml):
    (exit status, the MJCF's path arm.xml)."""
    from calbench.identify.cli import main

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "arm.urdf").write_text(urdf, encoding="utf-8")
    (folder / "arm.toml").write_text(overlay, encoding="utf-8")
    out = folder / "arm.xml"
    return main(
        ["from-urdf", str(folder / "arm.urdf"), "--overlay", str(folder / "arm.toml"), "--out", str(out)]
    ), out


# the FANUC M-900iB/700 of ../shared/data (fanuc_m900ib_support): its controller's axes, a payload
# off the J6 axis and three reflectors on link_6 (an overlay's start; tests add masses)
FANUC_TOOL = (
    'actuated = ["joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6"]\n'
    '[payload]\nlink = "link_6"\npos = [0.3, 0.0, -0.15]\n'
    + "".join(
        f'[reflectors.r{i}]\nlink = "link_6"\npos = {p}\n'
        for i, p in enumerate(([0.2, 0.3, 0.2], [0.2, -0.3, 0.2], [0.2, 0.0, -0.3]), 1)
    )
)
