"""The campaign as Foxglove's 3D panel draws it: messages with Foxglove's well-known schemas.

Foxglove reads only its own schemas (``foxglove.FrameTransforms``, ``foxglove.SceneUpdate``,
``foxglove.Log``), so the campaign writes them on extra topics beside the contract's
``calbench.*`` ones, JSON-encoded, each channel registered with the official JSON Schema
shipped in ``foxglove_schemas/`` (npm ``@foxglove/schemas``, MIT, notice in its LICENSE).

Topics (fixed frame ``world``; metres)
--------------------------------------
``/foxglove/tf``           per pose: world -> ``tracker``, world -> each body (its MJCF name) and
                           world -> the flange site (calbench:flange) at the commanded angles (rigid closed loop: what a
                           real campaign knows); a first one at log time ~0 at pose 0's command
``/foxglove/robot``        one message: the robot's MJCF geoms as primitives, each body's in its
                           own frame (frame-locked, so the tf above poses them), and the tracker
``/foxglove/scene``        per pose: the measured reflectors (mean of the repeats, grey unloaded,
                           orange loaded), the measured deflections as arrows x``MAGNIFY`` from the
                           unloaded reflector, the lines of sight, the compensator spring
``/foxglove/log``          one line per pose: command, deflections in µm
``/truth/foxglove/tf``     per pose: world -> ``true_<state>/<body>`` and ``true_<flange>_<state>``
                           at the true unloaded and loaded equilibria
``/truth/foxglove/robot``  one message: the robot as translucent ghosts in those frames
``/truth/foxglove/scene``  per pose: the true reflectors, the true deflections x``MAGNIFY``, the
                           true joint deflections (µrad, entity metadata)

The static drawings sit alone on their topics because a player that seeks may replay only the
last message of each topic before the new time. Everything true lives under ``/truth/`` only, so
:func:`bench.logformat.strip_truth` leaves what a real campaign would have
(tests/test_foxglove.py checks that no true position is on the other topics). The messages of
pose p are written just before its ``pose_done`` marker (crash tolerance: they share its
chunk), right after its last reading on the log's clock (bench/scenario/timeline.py), and every Foxglove
``time`` stamp is its message's log time. Coordinates are rounded to 0.1 µm and unit quantities to 1e-9,
far below what a 3D view shows: it halves the bytes. docs/foxglove-layout.json opens a 3D panel
on these topics beside a Log panel.

The builders below are pure functions of arrays; :class:`FoxgloveWriter` is the glue the
campaign calls.
"""

from __future__ import annotations

from functools import cache
from importlib.resources import files

import mujoco
import numpy as np

from calbench.bench.core import STATES
from calbench.bench.model import GeomShape, geom_shapes, tendon_sites
from calbench.bench.tracker import TrackerSpec, mean_reading, tracker_rotation

MAGNIFY = 200.0
WORLD, TRACKER = "world", "tracker"
TF, ROBOT, SCENE, LOG = "/foxglove/tf", "/foxglove/robot", "/foxglove/scene", "/foxglove/log"
TRUTH_TF, TRUTH_ROBOT, TRUTH_SCENE = "/truth/foxglove/tf", "/truth/foxglove/robot", "/truth/foxglove/scene"
TOPICS = {
    TF: "foxglove.FrameTransforms",
    ROBOT: "foxglove.SceneUpdate",
    SCENE: "foxglove.SceneUpdate",
    LOG: "foxglove.Log",
    TRUTH_TF: "foxglove.FrameTransforms",
    TRUTH_ROBOT: "foxglove.SceneUpdate",
    TRUTH_SCENE: "foxglove.SceneUpdate",
}
LOG_INFO = 2  # foxglove.LogLevel INFO

GREY, ORANGE, GREEN = (0.55, 0.55, 0.55, 1.0), (1.0, 0.55, 0.0, 1.0), (0.15, 0.75, 0.3, 1.0)
SIGHT = (0.6, 0.6, 0.6, 0.5)
TRACKER_COLOR = (0.1, 0.45, 0.9, 1.0)  # a mid blue: visible on dark and light backgrounds
TENDON_COLOR = (0.1, 0.6, 0.9, 1.0)
GHOST_ALPHA = 0.35
REFLECTOR_DIAMETER = 0.04


@cache
def schema_text(name: str) -> str:
    """The official JSON Schema of Foxglove message ``name`` (e.g. ``foxglove.SceneUpdate``)."""
    return files("calbench.bench.log").joinpath("foxglove_schemas", f"{name}.json").read_text()


# ---------------------------------------------------------------------------------------------
# primitives (pure)
# ---------------------------------------------------------------------------------------------


def stamp(t_ns: int) -> dict:
    """Foxglove ``time`` of a log time in ns."""
    return {"sec": int(t_ns) // 1_000_000_000, "nsec": int(t_ns) % 1_000_000_000}


def _m(x) -> float:
    return round(float(x), 7)


def _u(x) -> float:
    return round(float(x), 9)


def vec(p) -> dict:
    return {"x": _m(p[0]), "y": _m(p[1]), "z": _m(p[2])}


def quat(wxyz) -> dict:
    return {"x": _u(wxyz[1]), "y": _u(wxyz[2]), "z": _u(wxyz[3]), "w": _u(wxyz[0])}


IDENTITY = (1.0, 0.0, 0.0, 0.0)


def pose(p, wxyz=IDENTITY) -> dict:
    return {"position": vec(p), "orientation": quat(wxyz)}


def color(rgba) -> dict:
    r, g, b, a = (round(float(c), 3) for c in rgba)
    return {"r": r, "g": g, "b": b, "a": a}


def transform(t_ns: int, parent: str, child: str, p, wxyz) -> dict:
    return {
        "timestamp": stamp(t_ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": vec(p),
        "rotation": quat(wxyz),
    }


def entity(
    t_ns: int,
    id: str,
    frame_id: str = WORLD,
    metadata: dict | None = None,
    frame_locked: bool = False,
    **primitives: list,
) -> dict:
    """A ``foxglove.SceneEntity``: every primitive list present (the schema requires them),
    lifetime 0 (kept until an entity with the same id replaces it); ``frame_locked`` entities
    follow their frame as it moves."""
    e = {
        "timestamp": stamp(t_ns),
        "frame_id": frame_id,
        "id": id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": bool(frame_locked),
        "metadata": [{"key": str(k), "value": str(v)} for k, v in (metadata or {}).items()],
    }
    for kind in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        e[kind] = primitives.pop(kind, [])
    if primitives:
        raise ValueError(f"unknown primitive lists {sorted(primitives)}")
    return e


def scene_update(entities: list[dict]) -> dict:
    return {"deletions": [], "entities": entities}


def sphere(center, diameter, rgba, wxyz=IDENTITY) -> dict:
    d = np.broadcast_to(np.asarray(diameter, float), (3,))
    return {"pose": pose(center, wxyz), "size": vec(d), "color": color(rgba)}


def _x_to(u: np.ndarray) -> np.ndarray:
    """wxyz rotation taking +x onto the unit vector u (Foxglove arrows point along +x)."""
    w = 1.0 + u[0]
    if w < 1e-12:  # u = -x: half a turn about z
        return np.array([0.0, 0.0, 0.0, 1.0])
    q = np.array([w, 0.0, -u[2], u[1]])
    return q / np.linalg.norm(q)


def arrow(origin, vector, rgba, shaft_diameter=0.012) -> dict | None:
    """An arrow from ``origin`` along ``vector`` (its full length, head included); None when
    the vector is zero."""
    v = np.asarray(vector, float)
    n = float(np.linalg.norm(v))
    if not n > 0:
        return None
    head = min(0.3 * n, 0.06)
    return {
        "pose": pose(origin, _x_to(v / n)),
        "shaft_length": _m(n - head),
        "shaft_diameter": _m(shaft_diameter),
        "head_length": _m(head),
        "head_diameter": _m(2.5 * shaft_diameter),
        "color": color(rgba),
    }


def line_list(segments, rgba, thickness=2.0) -> dict:
    """Segments (k, 2, 3) as one LINE_LIST, ``thickness`` in screen pixels."""
    pts = [vec(p) for seg in segments for p in seg]
    return {
        "type": 2,
        "pose": pose((0, 0, 0)),
        "thickness": thickness,
        "scale_invariant": True,
        "points": pts,
        "color": color(rgba),
        "colors": [],
        "indices": [],
    }


def polyline(points, rgba, thickness=0.03) -> dict:
    """A LINE_STRIP through ``points``, ``thickness`` in metres."""
    return {
        "type": 0,
        "pose": pose((0, 0, 0)),
        "thickness": _m(thickness),
        "scale_invariant": False,
        "points": [vec(p) for p in points],
        "color": color(rgba),
        "colors": [],
        "indices": [],
    }


def text(position, string, rgba, font_size=14.0) -> dict:
    return {
        "pose": pose(position),
        "billboard": True,
        "font_size": font_size,
        "scale_invariant": True,
        "color": color(rgba),
        "text": string,
    }


def _rot(wxyz) -> np.ndarray:
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(wxyz, float))
    return R.reshape(3, 3)


def geom_primitives(
    shapes: list[GeomShape], pos: np.ndarray, quats: np.ndarray, rgba=None, alpha: float | None = None
) -> dict[str, list]:
    """Primitive lists drawing ``shapes`` at world poses ``pos`` (n,3), ``quats`` (n,4 wxyz).

    Boxes -> cubes; cylinders -> cylinders (both lie along z in MuJoCo and Foxglove);
    ellipsoids and spheres -> spheres of the three diameters; capsules -> a cylinder and its
    two end spheres; meshes -> a triangle list. ``rgba`` replaces the MJCF colours, ``alpha``
    only their opacity.
    """
    out: dict[str, list] = {"cubes": [], "cylinders": [], "spheres": [], "triangles": []}
    for s, p, q in zip(shapes, pos, quats):
        c = np.array(s.rgba if rgba is None else rgba, float)
        if alpha is not None:
            c[3] = alpha
        if s.kind == "box":
            out["cubes"].append({"pose": pose(p, q), "size": vec(2 * s.size), "color": color(c)})
        elif s.kind in ("cylinder", "capsule"):
            r, h = s.size
            out["cylinders"].append(
                {
                    "pose": pose(p, q),
                    "size": vec([2 * r, 2 * r, 2 * h]),
                    "bottom_scale": 1.0,
                    "top_scale": 1.0,
                    "color": color(c),
                }
            )
            if s.kind == "capsule":
                axis = _rot(q)[:, 2] * h
                out["spheres"] += [sphere(p + axis, 2 * r, c), sphere(p - axis, 2 * r, c)]
        elif s.kind == "ellipsoid":
            out["spheres"].append(sphere(p, 2 * s.size, c, q))
        elif s.kind == "mesh":
            tri = s.vertices[s.faces.reshape(-1)]
            out["triangles"].append(
                {
                    "pose": pose(p, q),
                    "points": [vec(v) for v in tri],
                    "color": color(c),
                    "colors": [],
                    "indices": [],
                }
            )
    return out


def frame_transforms(transforms: list[dict]) -> dict:
    return {"transforms": transforms}


def log_message(t_ns: int, message: str, level: int = LOG_INFO) -> dict:
    return {
        "timestamp": stamp(t_ns),
        "level": level,
        "message": message,
        "name": "calbench simulate",
        "file": "",
        "line": 0,
    }


# ---------------------------------------------------------------------------------------------
# campaign pieces (pure)
# ---------------------------------------------------------------------------------------------


def tracker_entity(t_ns: int, spec: TrackerSpec) -> dict:
    """The laser tracker in its own frame: a head sphere on a stand down to the floor."""
    h = float(spec.position[2])
    cyl = (
        []
        if h <= 0
        else [
            {
                "pose": pose((0, 0, -h / 2)),
                "size": vec([0.05, 0.05, h]),
                "bottom_scale": 1.0,
                "top_scale": 1.0,
                "color": color(TRACKER_COLOR),
            }
        ]
    )
    return entity(
        t_ns,
        "tracker",
        TRACKER,
        {"position_world_m": list(map(_m, spec.position))},
        frame_locked=True,
        spheres=[sphere((0, 0, 0), 0.2, TRACKER_COLOR)],
        cylinders=cyl,
        texts=[text((0, 0, 0.25), "laser tracker", TRACKER_COLOR)],
    )


def measured_entities(
    t_ns: int,
    names: list[str],
    unloaded: np.ndarray,
    loaded: np.ndarray,
    tracker_position,
    magnify: float = MAGNIFY,
) -> list[dict]:
    """Measured reflectors of both states, deflection arrows x magnify, lines of sight."""
    d = loaded - unloaded
    ok = np.all(np.isfinite(d), axis=1)
    meta = {nm: f"{np.linalg.norm(d[i]) * 1e6:.1f} um" for i, nm in enumerate(names) if ok[i]}
    arrows = [a for i in np.flatnonzero(ok) if (a := arrow(unloaded[i], magnify * d[i], ORANGE))]
    out = []
    for state, pts, rgba in (("unloaded", unloaded, GREY), ("loaded", loaded, ORANGE)):
        seen = np.flatnonzero(np.all(np.isfinite(pts), axis=1))
        out.append(
            entity(
                t_ns,
                f"measured/{state}",
                metadata={names[i]: "seen" for i in seen},
                spheres=[sphere(pts[i], REFLECTOR_DIAMETER, rgba) for i in seen],
            )
        )
    out.append(
        entity(
            t_ns,
            f"deflection_x{magnify:g}",
            metadata={"magnification": f"{magnify:g}", **meta},
            arrows=arrows,
        )
    )
    seen_u = np.flatnonzero(np.all(np.isfinite(unloaded), axis=1))
    out.append(
        entity(
            t_ns,
            "line_of_sight",
            lines=[line_list([(tracker_position, unloaded[i]) for i in seen_u], SIGHT)]
            if len(seen_u)
            else [],
        )
    )
    return out


def truth_entities(
    t_ns: int, names: list[str], unloaded: np.ndarray, loaded: np.ndarray, magnify: float = MAGNIFY
) -> list[dict]:
    """True reflectors of both states and the true deflections x magnify (/truth/ only)."""
    d = loaded - unloaded
    meta = {nm: f"{np.linalg.norm(d[i]) * 1e6:.1f} um" for i, nm in enumerate(names)}
    return [
        entity(
            t_ns, "true_reflectors/unloaded", spheres=[sphere(p, REFLECTOR_DIAMETER, GREEN) for p in unloaded]
        ),
        entity(
            t_ns, "true_reflectors/loaded", spheres=[sphere(p, REFLECTOR_DIAMETER, GREEN) for p in loaded]
        ),
        entity(
            t_ns,
            f"true_deflection_x{magnify:g}",
            metadata={"magnification": f"{magnify:g}", **meta},
            arrows=[a for u, v in zip(unloaded, d) if (a := arrow(u, magnify * v, GREEN, 0.008))],
        ),
    ]


# ---------------------------------------------------------------------------------------------
# the glue the campaign calls
# ---------------------------------------------------------------------------------------------


class FoxgloveRobot:
    """One robot model posed with ``mj_kinematics`` in its own MjData.

    Its geoms are drawn once, static, each body's geoms as one entity in the body's frame
    (``<prefix><body name>``, frame-locked); every pose then only moves the frames (world ->
    body transforms), which is how Foxglove animates a robot and costs a fraction of the bytes
    of redrawing it. ``flange_site`` -1: the model names no flange."""

    def __init__(self, model: mujoco.MjModel, prefix: str = "", flange_site: int = -1):
        self.model, self.data = model, mujoco.MjData(model)
        self.prefix = prefix
        self.shapes = geom_shapes(model)
        self.tendons = tendon_sites(model)
        self.flange = int(flange_site)
        self.bodies = sorted({s.body for s in self.shapes} - {0})

    def frame(self, body: int) -> str:
        if body == 0:
            return WORLD
        return self.prefix + (self.model.body(body).name or f"body{body}")

    def entities(
        self, t_ns: int, rgba=None, alpha: float | None = None, metadata: dict | None = None
    ) -> list[dict]:
        """The static drawing: one frame-locked entity per body, its geoms in its frame."""
        out = []
        for b in sorted({s.body for s in self.shapes}):
            mine = [s for s in self.shapes if s.body == b]
            prims = geom_primitives(
                mine, np.array([s.pos for s in mine]), np.array([s.quat for s in mine]), rgba, alpha
            )
            out.append(entity(t_ns, self.frame(b), self.frame(b), metadata, frame_locked=True, **prims))
        return out

    def at(self, t_ns: int, qpos: np.ndarray, flange_name: str) -> tuple[list[dict], list[np.ndarray]]:
        """World -> body (and -> flange) transforms at ``qpos``, and the tendon polylines."""
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        d = self.data
        tfs = [transform(t_ns, WORLD, self.frame(b), d.xpos[b], d.xquat[b]) for b in self.bodies]
        if self.flange >= 0:
            fq = np.empty(4)
            mujoco.mju_mat2Quat(fq, d.site_xmat[self.flange])
            tfs.append(transform(t_ns, WORLD, flange_name, d.site_xpos[self.flange], fq))
        return tfs, [d.site_xpos[sites].copy() for _, sites in self.tendons]


def tendon_entity(t_ns: int, id: str, tendons: list[np.ndarray], rgba=TENDON_COLOR) -> dict:
    """The compensator spring(s) as polylines in the world frame (they span two bodies)."""
    return entity(t_ns, id, lines=[polyline(p, rgba) for p in tendons])


class FoxgloveWriter:
    """Writes the Foxglove topics of one campaign through :class:`bench.logformat.LogWriter`'s
    extra-channel hook (``add_channel``, ``next_time``, ``write``). ``nominal`` is the robot as
    the log's MJCF describes it, drawn at the commanded angles; ``truth`` the simulated robot,
    drawn at its equilibria on /truth/ topics only. Both are :class:`bench.robot.Robot`."""

    def __init__(self, log, nominal, truth, spec: TrackerSpec, names: list[str], magnify: float = MAGNIFY):
        self.log, self.spec, self.names, self.magnify = log, spec, list(names), float(magnify)
        self.rigid_qpos = nominal.rigid_qpos
        self.flange_name = nominal.description.flange or ""  # the frame of the flange site
        self.nominal = FoxgloveRobot(nominal.model, "", nominal.flange_site)
        self.truth = {s: FoxgloveRobot(truth.model, f"true_{s}/", truth.flange_site) for s in STATES}
        for topic, name in TOPICS.items():  # validity: tests/test_foxglove.py, every message
            log.add_channel(topic, name, schema_text(name), check=False)
        self._yaw = np.empty(4)
        mujoco.mju_mat2Quat(self._yaw, tracker_rotation(spec).ravel())
        self._truth_drawn = False

    def _put(self, topic: str, build, nominal_time: int = 0) -> int:
        """Write ``build(t)`` at the next log time t (>= nominal_time); returns t."""
        t = self.log.next_time(nominal_time)
        self.log.write(topic, build(t), t)
        return t

    def _tf(self, t: int, q: np.ndarray) -> tuple[dict, list[np.ndarray]]:
        tfs, tendons = self.nominal.at(t, self.rigid_qpos(q), self.flange_name)
        return frame_transforms([transform(t, WORLD, TRACKER, self.spec.position, self._yaw)] + tfs), tendons

    def start(self, n_poses: int, q0: np.ndarray) -> None:
        """Before the first pose: the frames at the first command, the static drawing of the
        robot and the tracker, and a first log line."""
        self._put(TF, lambda t: self._tf(t, q0)[0])
        self._put(
            ROBOT,
            lambda t: scene_update(
                self.nominal.entities(t, metadata={"drawn_at": "commanded angles, rigid loop"})
                + [tracker_entity(t, self.spec)]
            ),
        )
        self._put(
            LOG, lambda t: log_message(t, f"campaign of {n_poses} poses; deflection arrows x{self.magnify:g}")
        )

    def pose(
        self,
        index: int,
        q: np.ndarray,
        readings: tuple[list, list],
        truth_qpos: tuple[np.ndarray, np.ndarray],
        truth_reflectors: np.ndarray,
        truth_deflection: tuple[np.ndarray, np.ndarray],
    ) -> None:
        """All Foxglove messages of one pose: ``readings`` the tracker readings (the repeats)
        of the unloaded and the loaded state; then the truth for the /truth/ topics: the
        equilibrium qpos and the motor-space deflection (6,) rad of each state, and the true
        reflectors (2, n, 3) in the world frame."""
        qdeg = ", ".join(f"{x:.3f}" for x in np.degrees(q))
        tendons: list = []

        def tf(t):
            msg, tl = self._tf(t, q)
            tendons[:] = tl
            return msg

        self._put(TF, tf)
        mu, ml = (mean_reading(self.spec, r).position for r in readings)
        self._put(
            SCENE,
            lambda t: scene_update(
                [tendon_entity(t, "compensator", tendons)]
                + measured_entities(t, self.names, mu, ml, self.spec.position, self.magnify)
            ),
        )
        d = ml - mu
        seen = [
            f"{nm} {np.linalg.norm(d[i]) * 1e6:.0f}"
            for i, nm in enumerate(self.names)
            if np.all(np.isfinite(d[i]))
        ]
        self._put(
            LOG,
            lambda t: log_message(
                t,
                f"pose {index}: q = [{qdeg}] deg; measured deflection (µm): "
                f"{', '.join(seen) or 'no reflector seen in both states'}",
            ),
        )
        # ---- the truth: /truth/ topics only ----
        true_tendons: dict[str, list] = {}

        def truth_tf(t):
            out = []
            for s, state in enumerate(STATES):
                tfs, true_tendons[state] = self.truth[state].at(
                    t, truth_qpos[s], f"true_{self.flange_name}_{state}"
                )
                out += tfs
            return frame_transforms(out)

        self._put(TRUTH_TF, truth_tf)
        if not self._truth_drawn:  # the static ghosts, once, after their first frames
            self._put(
                TRUTH_ROBOT,
                lambda t: scene_update(
                    self.truth["unloaded"].entities(t, alpha=GHOST_ALPHA)
                    + self.truth["loaded"].entities(t, ORANGE, GHOST_ALPHA)
                ),
            )
            self._truth_drawn = True
        urad = {
            f"joint_deflection_urad_{state}": ", ".join(f"{x * 1e6:.1f}" for x in dfl)
            for state, dfl in zip(STATES, truth_deflection)
        }
        self._put(
            TRUTH_SCENE,
            lambda t: scene_update(
                [entity(t, "true_deflection_joints", metadata={"pose": index, **urad})]
                + [tendon_entity(t, f"true_compensator/{s}", true_tendons[s]) for s in STATES]
                + truth_entities(t, self.names, truth_reflectors[0], truth_reflectors[1], self.magnify)
            ),
        )


__all__ = [
    "FoxgloveWriter",
    "FoxgloveRobot",
    "TOPICS",
    "MAGNIFY",
    "schema_text",
    "stamp",
    "entity",
    "scene_update",
    "frame_transforms",
    "transform",
    "geom_primitives",
    "measured_entities",
    "truth_entities",
    "tracker_entity",
    "log_message",
    "arrow",
]
