"""A chain to a calbench MJCF and back: the UR10 (or a calibrated arm) for every other verb.

:func:`chain_mjcf` writes nested bodies, one per joint: body k at P_k (``pos``/``quat``), a hinge
about its local z, its mass at its centre of mass; the flange body carries the probe site and
two auxiliary reflector sites 50 mm off it (check-robot wants three reflectors not on a line;
a series of the probe measures only ``probe``), and the payload site at the probe. Joint
stiffness is 1 / compliance where one is given, else calbench's placeholder. MuJoCo's body frames
compose exactly as :class:`chain.Chain` does (parent @ Tr(pos) R(quat) Rz(q)); the tests check its
forward kinematics and its gravity forces against the chain's.

:func:`chain_from_mjcf` reads a serial arm back (any calbench MJCF whose actuated hinges form one
chain without loops): joint axes and joint positions are folded into the frames so that every
axis becomes a local z through the frame's origin.

Units: SI (m, kg).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import InputError
from calbench.bench.robots import PLACEHOLDER_STIFFNESS

from .chain import Chain, translation

AUX = 0.05  # m, the auxiliary reflectors' offset from the probe along flange x and y
INERTIA = 1e-3  # kg*m^2, a small diagonal inertia (statics needs masses, not inertias)


def _quat(r: np.ndarray) -> str:
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, float).ravel())
    return " ".join(f"{v:.17g}" for v in q)


def _vec(v) -> str:
    return " ".join(f"{float(x):.17g}" for x in v)


def chain_mjcf(
    chain: Chain,
    tool: np.ndarray,
    name: str = "arm",
    compliance=None,
    sites: Mapping[str, np.ndarray] | None = None,
    payload: tuple[str, np.ndarray] | None = None,
) -> str:
    """The chain as a calbench MJCF text, the probe at ``tool`` (flange frame). ``sites``: named
    flange points (a calibration's reflectors) in place of the probe and its two auxiliary points
    (two such are added off the first where fewer than three are given); ``payload``: the load's
    site (name, flange point), by default the probe (or the first of ``sites``)."""
    stiff = [PLACEHOLDER_STIFFNESS] * chain.dof
    if compliance is not None:
        stiff = [1.0 / c if c > 0 else PLACEHOLDER_STIFFNESS for c in compliance]
    body, close = [], []
    for k in range(chain.dof):
        f = chain.frames[k]
        ind = "  " * (k + 3)
        body.append(f'{ind}<body name="link{k + 1}" pos="{_vec(f[:3, 3])}" quat="{_quat(f[:3, :3])}">')
        body.append(
            f'{ind}  <joint name="{chain.joints[k]}" axis="0 0 1" range="-360 360" stiffness="{stiff[k]:.17g}"/>'
        )
        mass = max(float(chain.mass[k]), 1e-6)
        body.append(
            f'{ind}  <inertial pos="{_vec(chain.com[k])}" mass="{mass:.17g}" diaginertia="{INERTIA} {INERTIA} {INERTIA}"/>'
        )
        close.append(f"{ind}</body>")
    f = chain.frames[-1]
    ind = "  " * (chain.dof + 3)
    t = np.asarray(tool, float)
    points = dict(sites) if sites else {"probe": t}
    first, t0 = next(iter(points.items()))
    for axis, off in (("x", [AUX, 0, 0]), ("y", [0, AUX, 0])):
        if len(points) < 3:
            points.setdefault(f"{first}_aux_{axis}", np.asarray(t0, float) + off)
    reflectors = list(points)
    load = payload or (first, t0)
    if load[0] not in points:
        points[load[0]] = load[1]
    body += [
        f'{ind}<body name="flange" pos="{_vec(f[:3, 3])}" quat="{_quat(f[:3, :3])}">',
        f'{ind}  <site name="flange" pos="0 0 0"/>',
        *(f'{ind}  <site name="{n}" pos="{_vec(v)}"/>' for n, v in points.items()),
        f"{ind}</body>",
    ]
    return "\n".join(
        [
            f'<mujoco model="{name}">',
            '  <compiler angle="degree" autolimits="true" inertiafromgeom="false"/>',
            "  <custom>",
            f'    <text name="calbench:actuated" data="{" ".join(chain.joints)}"/>',
            f'    <text name="calbench:reflectors" data="{" ".join(reflectors)}"/>',
            f'    <text name="calbench:payload" data="{load[0]}"/>',
            '    <text name="calbench:flange" data="flange"/>',
            "  </custom>",
            '  <default><geom contype="0" conaffinity="0"/></default>',
            "  <worldbody>",
            '    <body name="base">',
            '      <geom type="cylinder" size="0.075 0.019" pos="0 0 0.019" mass="0"/>',
            *body,
            *reversed(close),
            "    </body>",
            "  </worldbody>",
            "</mujoco>",
            "",
        ]
    )


def write_chain_mjcf(path: str | Path, chain: Chain, tool: np.ndarray, **kw) -> Path:
    """Write :func:`chain_mjcf` to ``path`` (atomically, as every calbench output)."""
    from calbench.bench.core import write_text

    path = Path(path)
    write_text(path, chain_mjcf(chain, tool, **kw))
    return path


@dataclass(frozen=True)
class Arm:
    """A serial calbench MJCF as a chain, with what is needed to place its sites on the flange."""

    chain: Chain
    where: str  # the file (or log attachment) it came from, for messages
    model: mujoco.MjModel
    flange_world: np.ndarray  # (4, 4) the chain's flange frame at q = 0
    last_body: int  # the body the last actuated joint moves
    bodies: tuple[str, ...] = ()  # the bodies the actuated joints turn, in order

    def point(self, site: str) -> np.ndarray:
        """A site's position in the flange frame; InputError unless the last joint carries it."""
        s = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, site)
        if s < 0:
            raise InputError(self.where, f"site {site}", "a site of the robot", None)
        if not _under(self.model, int(self.model.site_bodyid[s]), self.last_body):
            raise InputError(
                self.where,
                f"site {site}",
                "a point the last joint moves (geometry fits a flange point)",
                None,
            )
        d = mujoco.MjData(self.model)
        mujoco.mj_kinematics(self.model, d)
        return (np.linalg.inv(self.flange_world) @ np.append(d.site_xpos[s], 1.0))[:3]


def chain_from_mjcf(path: str | Path) -> Chain:
    """A serial arm from a calbench MJCF: the actuated hinges, in order, along one body chain."""
    return load_arm(path).chain


def load_arm(path: str | Path | None = None, xml: str | None = None, where: str = "") -> Arm:
    """:class:`Arm` of the MJCF at ``path``, or of the MJCF text ``xml`` (``where`` names it)."""
    where = str(path) if path is not None else where
    try:
        model = (
            mujoco.MjModel.from_xml_path(str(path))
            if path is not None
            else mujoco.MjModel.from_xml_string(xml)
        )
    except ValueError as e:
        raise InputError(where, "MJCF", "a model MuJoCo compiles", str(e).splitlines()[0]) from None
    if model.neq:
        raise InputError(where, "equality", "a serial arm (geometry fits no kinematic loop yet)", model.neq)
    if model.ntendon:
        # a compensator's torque is a second gravity-like term the model does not carry yet:
        # fitting without it would hide the spring in the compliances and the geometry
        raise InputError(
            where,
            "tendon",
            "an arm without compensator springs (geometry does not model them yet)",
            model.ntendon,
        )
    names = _text(model, "calbench:actuated").split()
    if not names:
        raise InputError(where, "calbench:actuated", "the actuated joints", None)
    joint_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
    bodies = [int(model.jnt_bodyid[j]) for j in joint_ids]
    for k in range(1, len(bodies)):
        if model.body_parentid[bodies[k]] != bodies[k - 1]:
            raise InputError(
                where, f"joint {names[k]}", f"a child of {names[k - 1]}'s body (a serial chain)", None
            )
    if model.njnt != len(names):
        raise InputError(where, "joints", "only the actuated hinges (no passive joints)", model.njnt)
    d = mujoco.MjData(model)
    mujoco.mj_kinematics(model, d)
    frames, com, mass = [], [], []
    carry = np.eye(4)  # the chain's frame is MuJoCo's world frame
    hinge = np.eye(4)
    for k, (j, b) in enumerate(zip(joint_ids, bodies, strict=True)):
        body_world = _world(d, b)
        hinge = body_world @ translation(model.jnt_pos[j]) @ _align(model.jnt_axis[j])  # at q = 0
        frames.append(carry @ hinge)
        carry = np.linalg.inv(hinge)
        # every body this joint moves but the next joint does not: its mass and centre of mass
        moved = [
            x
            for x in range(model.nbody)
            if _under(model, x, b) and not (k + 1 < len(bodies) and _under(model, x, bodies[k + 1]))
        ]
        m = float(model.body_mass[moved].sum())
        c = sum(model.body_mass[x] * d.xipos[x] for x in moved) / m if m > 0 else body_world[:3, 3]
        mass.append(m)
        com.append((carry @ np.append(c, 1.0))[:3])
    flange_site = _text(model, "calbench:flange").strip()
    flange = hinge
    if flange_site:
        s = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, flange_site)
        flange = np.eye(4)
        flange[:3, :3], flange[:3, 3] = d.site_xmat[s].reshape(3, 3), d.site_xpos[s]
    frames.append(carry @ flange)
    chain = Chain(np.asarray(frames), tuple(names), np.asarray(mass), np.asarray(com))
    body_names = tuple(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body {b}" for b in bodies)
    return Arm(chain, where, model, flange, bodies[-1], body_names)


def _text(model: mujoco.MjModel, name: str) -> str:
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, name)
    if i < 0:
        return ""
    adr, n = model.text_adr[i], model.text_size[i]
    return bytes(model.text_data[adr : adr + n]).decode().rstrip("\x00")


def _world(d: mujoco.MjData, body: int) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = d.xmat[body].reshape(3, 3), d.xpos[body]
    return t


def _under(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return root == 0


def _align(axis: np.ndarray) -> np.ndarray:
    """A rotation (4x4) taking local z onto ``axis``."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    r = np.eye(4)
    r[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    return r
