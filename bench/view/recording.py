"""`calbench view`: a Rerun recording of a campaign, its measurements and (optionally) its
identification, laid out so that a first-time user reads it without the README.

It opens at pose 0 with the camera on the robot, its tool and the tracker; the side panels are
collapsed; the 3D view's title states the magnification once. Colours mean one thing
throughout: orange measured, blue model, green truth, magenta residual (violet: after
discovery), grey noise and lines of sight. Numbers are in the per-pose text panel (and on
hover), not on the arrows.

Entity paths (metres, world frame; ``x<F>`` is the magnification, default 200)
------------------------------------------------------------------------------
The ``pose`` timeline (a sequence: the plan's pose index) steps through the configurations.

``robot/<body>/<geom>``
    The robot from its MJCF geoms (bench/model/geoms.py), static in body frames; ``robot/<body>`` a
    ``Transform3D`` per pose at the commanded angles (bench/view/scene.py says why).
    ``robot/<reflector body>/reflectors/<name>`` a post and a ball per reflector site;
    ``robot/tendon/<name>`` the compensator spring; ``robot/payload`` the load of the pose's
    loaded state (a steel block of the payload's mass, or an arrow for a pull).
``tracker``, ``tracker/line_of_sight``
    The laser tracker (head on a tripod, static) and per pose its lines of sight to the
    reflectors it saw unloaded.
``measured/unloaded``, ``measured/loaded``
    Measured reflectors, mean of the repeats (:func:`bench.tracker.mean_reading`, as
    identification averages them); the reflector names are on hover.
``deflection/x<F>/measured``, ``deflection/x<F>/uncertainty_3sigma``
    The measured deflection (loaded - unloaded) of every reflector seen in both states, an arrow
    from its unloaded position magnified by F; its 3-sigma ellipsoid, magnified alike, at the tip.
``plots/deflection_mm/<reflector>``, ``info/pose``
    Per pose: the measured deflection's length in mm, and a markdown page with every number
    (per reflector, the load, the sag) and the legend.
``truth/...`` (a simulated log only; hide it to see exactly what a real campaign shows)
    ``truth/deformed_x<F>/<body>/<geom>`` the ghost: the true loaded robot with its joint
    deflections magnified by F, translucent green; ``truth/reflectors/<state>``,
    ``truth/deflection/x<F>``.

With ``--identified ID.json`` (:class:`bench.idreport.IdentificationReport`):

``parameters/chart/...``, ``parameters/table``
    Every parameter by name, estimate ±1 std beside the truth, one block per quantity in display
    units (bench/view/params.py), and a markdown table of the same.
``model/deformed_x<F>/<body>/<geom>``
    The identified model's ghost (translucent blue), from the exact statics with the report's
    estimates (bench/view/scene.py), when the report holds the base parameters only.
``deflection/x<F>/model``, ``residual/x<R>/model``, ``residual/x<R>/noise_3sigma``,
``plots/residual_um/...``
    When the report carries per-observation predictions (``observations``): the model's
    deflection as an arrow; the residual (the log's measured deflection minus the predicted one)
    magnified by R = 10 F (x2000 by default: residuals are 15-90 um), drawn to end at the
    measured arrow's tip, with the noise's 3-sigma ellipsoid magnified by R around that tip;
    and the residual RMS per pose in um beside what noise alone leaves.

`calbench discover` writes its own recording (:func:`write_discovery_recording`): the same
scene, with ``residual/x<R>/before`` (the user's model) and ``residual/x<R>/after`` (with the
named effects) and their per-pose RMS, the verdict on top of every pose's page, and the final
model's parameters.

Output: ``--rrd OUT.rrd`` writes a file. Without it the viewer is spawned when there is a
display; without a display (or with CI set) the recording goes to ``<log dir>/<log stem>.rrd``
and the command prints how to open it.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import InputError, atomic_path, check_outputs
from calbench.bench.log import STATES, CampaignLog, IdentificationReport, read_log
from calbench.bench.model import GeomShape, ReflectorPost, Robot, geom_shapes, log_robot, reflector_posts

from . import params as viewparams
from . import text as viewtext
from .scene import (
    PoseScene,
    RobotPose,
    framing,
    mean_measurements,
    model_deflections,
    pose_scenes,
    true_deflections,
)

DEFAULT_MAGNIFY = 200.0
RESIDUAL_FACTOR = 10.0  # residuals are drawn 10x larger than the deflections
APP_ID = "calbench"
STEEL_DENSITY = 7850.0  # kg/m^3: the payload block's size from its mass
SLING = 0.35  # m from the payload site down to the block

# one meaning per colour (RGBA)
MEASURED = (255, 130, 0, 255)
MODEL = (60, 140, 255, 255)
TRUTH = (60, 200, 90, 255)
RESIDUAL = (230, 40, 200, 255)
RESIDUAL_AFTER = (150, 110, 255, 255)
NOISE = (170, 170, 170, 60)
SIGHT = (150, 150, 150, 140)
UNLOADED_POINT = (150, 150, 150, 255)
TRACKER = (215, 55, 55, 255)  # mid red: visible on dark and light themes
PAYLOAD = (120, 120, 130, 255)
TENDON = (150, 150, 160, 255)
GHOST_ALPHA = 80
GHOST_MIN_SHIFT = 0.01  # m: a ghost body closer than this to the robot is not drawn
CHART = {
    "estimate": MODEL,
    "truth": TRUTH,
    "text": (150, 150, 160, 255),
    "grid": (128, 128, 128, 70),
    "axis": (140, 140, 150, 255),
}


MARKERS = ("circle", "square", "diamond", "up", "cross", "down", "asterisk", "plus")


def _shades(rgb, n: int) -> list[tuple[int, int, int, int]]:
    """n shades of one colour, light to dark: plot lines of one kind, one per reflector."""
    if n <= 1:
        return [tuple(rgb)]  # type: ignore[list-item]
    out = []
    for t in np.linspace(-0.6, 0.45, n):
        c = np.array(rgb[:3], float)
        c = c + (255 - c) * -t if t < 0 else c * (1 - t)
        out.append((*[int(round(x)) for x in c], 255))
    return out


# ---------------------------------------------------------------------------------------------
# inputs
# ---------------------------------------------------------------------------------------------


def measured_deflections(log: CampaignLog) -> dict[int, dict[str, np.ndarray]]:
    """pose -> reflector -> measured deflection (3,) in the world frame, metres: mean of the
    loaded repeats minus mean of the unloaded repeats. Reflectors seen in both states only."""
    names = list(log.header.get("reflectors") or [])
    means = mean_measurements(log, names)
    out: dict[int, dict[str, np.ndarray]] = {}
    for p in log.complete_poses:
        if (p, "unloaded") not in means or (p, "loaded") not in means:
            continue
        d = means[(p, "loaded")].position - means[(p, "unloaded")].position
        out[p] = {nm: d[i] for i, nm in enumerate(names) if np.all(np.isfinite(d[i]))}
    return out


@dataclass(frozen=True)
class Discovery:
    """What `calbench discover` found, for its view: the user's model as it is (``before``)
    and with the named effects (``after``), both fitted, each with per-observation predictions;
    ``named`` the effects it added ("link_compliance (forearm)"; empty when none was needed)."""

    before: IdentificationReport
    after: IdentificationReport
    named: tuple[str, ...] = ()


@dataclass
class ViewPlan:
    """Everything the recording shows, computed before anything is logged."""

    log: CampaignLog
    robot: Robot
    names: list[str]
    scenes: list[PoseScene]
    magnify: float
    identified: IdentificationReport | None = None
    discovery: Discovery | None = None
    ghost_note: str = ""
    residuals: dict[str, dict[int, dict[str, np.ndarray]]] = field(default_factory=dict)
    predicted: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    chart: viewparams.Chart | None = None

    @property
    def tag(self) -> str:
        return magnify_tag(self.magnify)

    @property
    def residual_magnify(self) -> float:
        return RESIDUAL_FACTOR * self.magnify

    @property
    def has_truth(self) -> bool:
        return any(s.truth for s in self.scenes) or any("truth" in s.ghosts for s in self.scenes)

    def has_ghost(self, source: str) -> bool:
        return any(source in s.ghosts for s in self.scenes)

    def legend(self) -> str:
        return viewtext.legend(
            viewtext.Legend(
                self.magnify,
                self.residual_magnify,
                self.has_ghost("truth"),
                self.has_ghost("model"),
                self.ghost_note,
                self.has_truth,
                bool(self.predicted) and self.discovery is None,
                self.discovery is not None,
                viewtext.colour_name(
                    np.array([g.rgba for g in geom_shapes(self.robot.model)]).reshape(-1, 4)
                ),
            )
        )


def _residuals_of(
    scenes: list[PoseScene], names: list[str], predicted: dict[int, dict[str, tuple]]
) -> dict[int, dict[str, np.ndarray]]:
    """pose -> reflector -> the log's measured deflection minus ``predicted`` (m)."""
    out: dict[int, dict[str, np.ndarray]] = {}
    for s in scenes:
        d, _, ok = s.deflection()
        pred = predicted.get(s.index, {})
        row = {
            names[i]: d[i] - np.asarray(pred[names[i]], float) for i in np.flatnonzero(ok) if names[i] in pred
        }
        if row:
            out[s.index] = row
    return out


def plan_view(
    log: CampaignLog,
    identified: IdentificationReport | None = None,
    magnify: float = DEFAULT_MAGNIFY,
    discovery: Discovery | None = None,
) -> ViewPlan:
    """Compute what the recording shows (raises InputError on a log it cannot draw)."""
    robot = log_robot(log)
    log.tracker_spec()
    names = list(log.header.get("reflectors") or [])
    ghosts = {}
    truth = true_deflections(log)
    if truth:
        ghosts["truth"] = truth
    note = ""
    if discovery is not None:
        identified = discovery.after
    elif identified is not None:
        model, note = model_deflections(log, log.mjcf_text or "", identified)
        if model:
            ghosts["model"] = model
    scenes = pose_scenes(log, robot, names, magnify, ghosts)
    plan = ViewPlan(log, robot, names, scenes, magnify, identified, discovery, note)
    if identified is not None:
        import rerun as rr

        plan.chart = viewparams.chart(rr, identified, CHART)
    if discovery is not None:
        for key, rep in (("before", discovery.before), ("after", discovery.after)):
            plan.residuals[key] = _residuals_of(scenes, names, rep.predictions())
    elif identified is not None and identified.observations:
        pred = identified.predictions()
        plan.predicted = {p: {r: np.asarray(v, float) for r, v in refl.items()} for p, refl in pred.items()}
        plan.residuals["model"] = _residuals_of(scenes, names, pred)
    return plan


# ---------------------------------------------------------------------------------------------
# archetypes
# ---------------------------------------------------------------------------------------------


def _xyzw(wxyz) -> list[float]:
    w, x, y, z = (float(v) for v in wxyz)
    return [x, y, z, w]


def _rgba(rgba) -> tuple[int, int, int, int]:
    return tuple(int(round(255 * min(max(float(c), 0.0), 1.0))) for c in rgba)  # type: ignore


def geom_archetype(rr, shape: GeomShape, color=None):
    """The rerun archetype drawing one geom (bench/model/geoms.py) in its body's frame, solid, in its
    MJCF colour or ``color`` (RGBA 0..255; a ghost's is translucent)."""
    size, pos, quat = shape.size, shape.pos, shape.quat
    color = _rgba(shape.rgba) if color is None else color
    fill = rr.components.FillMode.Solid
    q = rr.Quaternion(xyzw=_xyzw(quat))
    if shape.kind == "box":
        return rr.Boxes3D(half_sizes=[size], centers=[pos], quaternions=[q], colors=[color], fill_mode=fill)
    if shape.kind == "capsule":
        # MuJoCo: centred, axis z, half-length size[1]; rerun: starts at translation, along +z
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, quat)
        start = pos - R.reshape(3, 3)[:, 2] * size[1]
        return rr.Capsules3D(
            lengths=[2 * size[1]],
            radii=[size[0]],
            translations=[start],
            quaternions=[q],
            colors=[color],
            fill_mode=fill,
        )
    if shape.kind == "cylinder":
        return rr.Cylinders3D(
            lengths=[2 * size[1]],
            radii=[size[0]],
            centers=[pos],
            quaternions=[q],
            colors=[color],
            fill_mode=fill,
        )
    if shape.kind == "ellipsoid":
        return rr.Ellipsoids3D(
            half_sizes=[size], centers=[pos], quaternions=[q], colors=[color], fill_mode=fill
        )
    if shape.kind == "mesh":
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, quat)
        verts = shape.vertices @ R.reshape(3, 3).T + pos
        return rr.Mesh3D(vertex_positions=verts, triangle_indices=shape.faces, albedo_factor=color)
    return None


def _part(name: str) -> str:
    """A name as one entity path part (spaces, slashes... escaped)."""
    import rerun as rr

    return rr.escape_entity_path_part(name)


def _body_names(model: mujoco.MjModel) -> list[str]:
    return [_part(model.body(b).name or f"body{b}") for b in range(model.nbody)]


def magnify_tag(magnify: float) -> str:
    """Entity path part naming the magnification: 200 -> 'x200', 2.5 -> 'x2.5'."""
    return f"x{magnify:g}"


def _ellipsoid(cov: np.ndarray, k: float) -> tuple[np.ndarray, np.ndarray]:
    """Half-axes k*sqrt(eigenvalues) and the xyzw quaternion of the principal axes."""
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    if np.linalg.det(V) < 0:
        V[:, 0] = -V[:, 0]
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(V).ravel())
    return k * np.sqrt(np.clip(w, 0.0, None)), np.array(_xyzw(q))


def _ellipsoids(rr, covs, centers, k: float, color, fill=None):
    hs, qs = [], []
    for c in covs:
        h, q = _ellipsoid(c, k)
        hs.append(h)
        qs.append(rr.Quaternion(xyzw=q))
    return rr.Ellipsoids3D(
        half_sizes=hs,
        centers=centers,
        quaternions=qs,
        colors=[color],
        fill_mode=fill or rr.components.FillMode.Solid,
    )


def _post_archetype(rr, post: ReflectorPost):
    """A reflector on its post: a thin grey rod and a 1.5-inch ball (a tracker's usual SMR)."""
    return [
        rr.LineStrips3D([[post.start, post.end]], radii=[0.012], colors=[PAYLOAD]),
        rr.Ellipsoids3D(
            half_sizes=[[0.019] * 3],
            centers=[post.end],
            colors=[(200, 200, 205)],
            fill_mode=rr.components.FillMode.Solid,
        ),
    ]


def _tracker_archetypes(rr, position: np.ndarray) -> list:
    """The tracker: a head on a tripod standing on the floor (z = 0)."""
    p = np.asarray(position, float)
    legs = []
    if p[2] > 0:
        for a in (0.0, 2.1, 4.2):
            foot = p + np.array([0.45 * np.cos(a), 0.45 * np.sin(a), -p[2]])
            legs.append([p - [0, 0, 0.15], foot])
    return [
        rr.Ellipsoids3D(
            half_sizes=[[0.14, 0.14, 0.16]],
            centers=[p],
            colors=[TRACKER],
            fill_mode=rr.components.FillMode.Solid,
            labels=["laser tracker"],
            show_labels=True,
        ),
        rr.LineStrips3D(legs, radii=[0.015], colors=[TRACKER]),
    ]


def _payload_archetypes(rr, scene: PoseScene) -> list:
    """The load of the loaded state: the outline of a steel block of the payload's mass hung on
    a sling below the payload site (an outline: the arrows and the ghost's tool show through
    it), or for a pull an arrow of 0.4 m per kN from the site."""
    w = scene.wrench
    if w is None or scene.payload is None:
        return [rr.Clear(recursive=True)]
    if w.mass is not None:
        side = (w.mass / STEEL_DENSITY) ** (1 / 3)
        top = scene.payload - [0, 0, SLING]
        return [
            rr.Boxes3D(
                half_sizes=[[side / 2] * 3],
                centers=[top - [0, 0, side / 2]],
                colors=[PAYLOAD],
                fill_mode=rr.components.FillMode.MajorWireframe,
                labels=[f"{w.mass:g} kg payload (loaded state)"],
                show_labels=False,
            ),
            rr.LineStrips3D([[scene.payload, top]], radii=[0.01], colors=[PAYLOAD]),
        ]
    f = np.asarray(w.force, float)
    return [
        rr.Arrows3D(
            origins=[scene.payload],
            vectors=[f * 4e-4],
            colors=[PAYLOAD],
            radii=[0.02],
            labels=[f"pull {np.linalg.norm(f) / 1e3:.2f} kN (loaded state)"],
            show_labels=False,
        ),
        rr.Clear(recursive=False),
    ]


# ---------------------------------------------------------------------------------------------
# the blueprint
# ---------------------------------------------------------------------------------------------


def build_blueprint(plan: ViewPlan):
    """The layout a first-time user meets: the 3D scene (its title states the magnification),
    the pose's page, the plots, and the parameters; opened at pose 0 with the side panels
    collapsed and the camera on the robot, its tool and the tracker."""
    import rerun.blueprint as rrb

    tag = f"×{plan.magnify:g}"
    contents = [
        "+ /robot/**",
        "+ /tracker/**",
        "+ /measured/**",
        "+ /deflection/**",
        "+ /residual/**",
        "+ /model/**",
        "+ /truth/**",
        "- /truth/parameters/**",
    ]
    title = f"Deformation and deflection arrows {tag}"
    if plan.residuals:
        title += f", residuals ×{plan.residual_magnify:g}"
    title += " (colours: see the pose page)"
    eye, target = (
        framing(plan.scenes, plan.log.tracker_spec().position, plan.magnify)
        if plan.scenes
        else (np.array([6.0, -6.0, 4.0]), np.zeros(3))
    )
    # with the model's ghost shown, the true one (nearly on top of it) starts hidden
    hidden = (
        {f"/truth/deformed_{plan.tag}": rrb.EntityBehavior(visible=False)}
        if plan.has_ghost("model") and plan.has_ghost("truth")
        else None
    )
    scene = rrb.Spatial3DView(
        name=title,
        origin="/",
        contents=contents,
        overrides=hidden,
        eye_controls=rrb.EyeControls3D(position=eye, look_target=target, eye_up=(0, 0, 1)),
        line_grid=rrb.LineGrid3D(visible=True, spacing=1.0),
    )
    page = rrb.TextDocumentView(name="This pose: numbers and legend", origin="/info")
    plots = [rrb.TimeSeriesView(name="Deflection (mm)", origin="/plots/deflection_mm")]
    if plan.residuals:
        residual = rrb.TimeSeriesView(name="Residual (µm)", origin="/plots/residual_um")
        plots.insert(0 if plan.discovery else 1, residual)
    if plan.chart is not None:
        params = [
            rrb.Spatial2DView(
                name="Parameters",
                origin="/parameters/chart",
                contents=["+ /parameters/chart/**", "+ /truth/parameters/chart/**"],
                visual_bounds=rrb.VisualBounds2D(x_range=plan.chart.x_range, y_range=plan.chart.y_range),
            ),
            rrb.TextDocumentView(name="Table", origin="/parameters/table"),
        ]
        if plan.identified.has_truth():
            params.append(rrb.TextDocumentView(name="Truth", origin="/truth/parameters/table"))
        plots = plots[:1] + params + plots[1:] if plan.discovery else params + plots
    side = rrb.Vertical(page, rrb.Tabs(*plots) if len(plots) > 1 else plots[0], row_shares=[1, 1])
    return rrb.Blueprint(
        rrb.Horizontal(scene, side, column_shares=[3, 2]),
        rrb.TimePanel(timeline="pose", play_state="paused", state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


# ---------------------------------------------------------------------------------------------
# logging
# ---------------------------------------------------------------------------------------------


@dataclass
class Summary:
    poses: int
    arrows: int
    truth: bool
    predicted: int
    ghost: str  # where the ghost's joint deflections come from
    warnings: list[str] = field(default_factory=list)  # about the --identified report
    completeness: str | None = None  # lost poses, how the log ended (CampaignLog.completeness)


def _log_robot_geoms(rec, rr, shapes: list[GeomShape], bodies: list[str]) -> None:
    """The robot's geoms, static, each in its body's frame under ``robot/<body>``."""
    for shape in shapes:
        arch = geom_archetype(rr, shape)
        if arch is not None:
            body = bodies[shape.body] if shape.body else "world"
            rec.log(f"robot/{body}/{_part(shape.name)}", arch, static=True)


def _log_robot_pose(rec, rr, base: str, pose: RobotPose, bodies: list[str]) -> None:
    for b in range(1, len(bodies)):
        rec.log(
            f"{base}/{bodies[b]}",
            rr.Transform3D(translation=pose.xpos[b], quaternion=rr.Quaternion(xyzw=_xyzw(pose.xquat[b]))),
        )


class _Ghost:
    """A translucent copy of the robot at the ghost's configuration. A body is drawn only where
    it stands off the robot by more than :data:`GHOST_MIN_SHIFT` somewhere on its geoms (the
    base never moves; the turret rarely): where the two coincide, the tint would only recolour
    the robot."""

    def __init__(self, rr, path: str, shapes: list[GeomShape], bodies: list[str], color):
        self.rr, self.path, self.bodies = rr, path, bodies
        self.geoms: dict[int, list[tuple[str, object]]] = {}
        self.reach: dict[int, float] = {}
        for sh in shapes:
            arch = geom_archetype(rr, sh, color)
            if arch is not None and sh.body > 0:
                self.geoms.setdefault(sh.body, []).append((_part(sh.name), arch))
                self.reach[sh.body] = max(
                    self.reach.get(sh.body, 0.0), float(np.linalg.norm(sh.pos) + np.max(sh.size))
                )
        self.shown: set[int] = set()

    def log(self, rec, ghost: RobotPose, robot: RobotPose) -> None:
        rr = self.rr
        for b, geoms in self.geoms.items():
            entity = f"{self.path}/{self.bodies[b]}"
            dot = min(1.0, abs(float(ghost.xquat[b] @ robot.xquat[b])))
            shift = np.linalg.norm(ghost.xpos[b] - robot.xpos[b]) + 2 * math.acos(dot) * self.reach[b]
            if shift < GHOST_MIN_SHIFT:
                if b in self.shown:
                    rec.log(entity, rr.Clear(recursive=True))
                    self.shown.discard(b)
                continue
            rec.log(
                entity,
                rr.Transform3D(
                    translation=ghost.xpos[b], quaternion=rr.Quaternion(xyzw=_xyzw(ghost.xquat[b]))
                ),
            )
            if b not in self.shown:
                for name, arch in geoms:
                    rec.log(f"{entity}/{name}", arch)
                self.shown.add(b)


def _pose_page(plan: ViewPlan, s: PoseScene, header: str) -> str:
    d, cov, ok = s.deflection()
    n = len(plan.names)

    def column(per_pose: dict[int, dict[str, np.ndarray]]) -> np.ndarray:
        row = per_pose.get(s.index, {})
        return np.array([row.get(nm, np.full(3, np.nan)) for nm in plan.names]).reshape(n, 3)

    cols: dict[str, np.ndarray] = {}
    if plan.predicted:
        cols["model deflection"] = column(plan.predicted)
    titles = {"model": "residual", "before": "residual, user's model", "after": "residual, with the effects"}
    for key, per_pose in plan.residuals.items():
        cols[titles[key]] = column(per_pose)
    table = viewtext.pose_table(plan.names, np.where(ok[:, None], d, np.nan), cov, cols)
    return viewtext.pose_page(
        s.index,
        len(plan.log.complete_poses),
        s.command,
        s.wrench,
        s.sag,
        table,
        float(np.linalg.norm(plan.robot.model.opt.gravity)),
        header,
        "**In the 3D view**\n\n" + plan.legend(),
    )


def _discovery_header(plan: ViewPlan) -> str:
    disc = plan.discovery
    if disc is None:
        return ""
    um = 1e6
    b, a = disc.before, disc.after
    named = ", ".join(disc.named) if disc.named else "nothing (the model fits to the noise level)"
    rms = ""
    if None not in (b.residual_rms, a.residual_rms, b.expected_residual_rms, a.expected_residual_rms):
        rms = (
            f" Residual RMS {b.residual_rms * um:.1f} µm → {a.residual_rms * um:.1f} µm per "
            f"axis; noise alone leaves {b.expected_residual_rms * um:.1f} → "
            f"{a.expected_residual_rms * um:.1f} µm."
        )
    worst = _worst(plan)
    return f"**calbench discover: named {named}.**{rms}" + (
        f" Largest disagreements of the user's model: {worst}." if worst else ""
    )


def _import_note(plan: ViewPlan) -> str:
    """One line for a log imported from a tracker's readings (``/campaign/info.imported``):
    where they came from and how the tracker was placed; "" for a simulated log."""
    imp = plan.log.header.get("imported")
    if not isinstance(imp, dict):
        return ""
    src = f"**Imported** from `{imp.get('source', '?')}`"
    if imp.get("rows") is not None:
        src += f" ({imp['rows']} readings in {imp.get('units', '?')})"
    reg = imp.get("registration")
    if imp.get("tracker_pose") == "registered" and isinstance(reg, dict):
        fit = ""
        if isinstance(reg.get("rms"), (int, float)) and isinstance(reg.get("expected_rms"), (int, float)):
            fit = (
                f": residual {reg['rms'] * 1e6:.1f} µm RMS per axis against "
                f"{reg['expected_rms'] * 1e6:.1f} µm expected"
            )
        where = f"; the tracker pose registered to the readings{fit}"
        warn = [w for w in reg.get("warnings") or [] if isinstance(w, str)]
        if warn:
            where += " (warning: " + "; ".join(warn) + ")"
    else:
        where = "; the tracker pose as the plan states it"
    return src + where + "."


def _worst(plan: ViewPlan, k: int = 4) -> str:
    """The k (pose, reflector) residuals of the user's model furthest from noise."""
    cov = {s.index: s.deflection()[1] for s in plan.scenes}
    rows = []
    for p, refl in plan.residuals.get("before", {}).items():
        for nm, r in refl.items():
            c = cov[p][plan.names.index(nm)]
            if np.all(np.isfinite(c)):
                rows.append((viewtext.sigmas(r, c), p, nm))
    rows.sort(reverse=True)
    return ", ".join(f"pose {p} {nm} ({x:.1f}σ)" for x, p, nm in rows[:k])


def log_view(rec, plan: ViewPlan) -> Summary:
    """Log everything of ``plan`` into the RecordingStream (its blueprint goes separately)."""
    import rerun as rr

    model = plan.robot.model
    names, tag = plan.names, plan.tag
    bodies = _body_names(model)
    shapes = geom_shapes(model)
    sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n) for n in names]
    posts = reflector_posts(model, shapes, [s for s in sites if s >= 0])
    spec = plan.log.tracker_spec()
    rk = plan.residual_magnify

    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    _log_robot_geoms(rec, rr, shapes, bodies)
    for post in posts:
        for arch in _post_archetype(rr, post):
            rec.log(f"robot/{bodies[post.body]}/reflectors/{_part(post.name)}", arch, static=True)
    ghost_paths = {"truth": f"truth/deformed_{tag}", "model": f"model/deformed_{tag}"}
    ghosts = {
        src: _Ghost(rr, path, shapes, bodies, (*c[:3], GHOST_ALPHA))
        for (src, path), c in zip(ghost_paths.items(), (TRUTH, MODEL))
        if plan.has_ghost(src)
    }
    for arch in _tracker_archetypes(rr, spec.position):
        rec.log("tracker", arch, static=True)
    for i, (nm, c) in enumerate(zip(names, _shades(MEASURED, len(names)))):
        # shades of one colour tell the kind, a marker per reflector tells them apart
        rec.log(
            f"plots/deflection_mm/{_part(nm)}",
            rr.SeriesLines(colors=[c], names=[nm]),
            rr.SeriesPoints(colors=[c], names=[nm], markers=[MARKERS[i % len(MARKERS)]], marker_sizes=[4.0]),
            static=True,
        )
    series = {
        "model": ("residual, identified model", RESIDUAL),
        "before": ("residual, user's model", RESIDUAL),
        "after": ("residual, with the named effects", RESIDUAL_AFTER),
    }
    for key in plan.residuals:
        rec.log(
            f"plots/residual_um/{key}",
            rr.SeriesLines(colors=[series[key][1]], names=[series[key][0]]),
            static=True,
        )
    if plan.residuals:
        rec.log(
            "plots/residual_um/noise",
            rr.SeriesLines(colors=[NOISE[:3]], names=["noise alone (RMS per axis)"]),
            static=True,
        )
    header = "\n\n".join(h for h in (_import_note(plan), _discovery_header(plan)) if h)

    arrows = n_pred = 0
    for s in plan.scenes:
        rec.set_time("pose", sequence=s.index)
        _log_robot_pose(rec, rr, "robot", s.robot, bodies)
        for tname, pts in s.robot.tendons.items():
            rec.log(f"robot/tendon/{_part(tname)}", rr.LineStrips3D([pts], radii=[0.02], colors=[TENDON]))
        for arch in _payload_archetypes(rr, s):
            rec.log("robot/payload", arch)
        for src, ghost in ghosts.items():  # a source covers every pose or none
            ghost.log(rec, s.ghosts[src], s.robot)
        for state in STATES:
            m = s.measured[state]
            seen = np.flatnonzero(np.all(np.isfinite(m), axis=1))
            rec.log(
                f"measured/{state}",
                rr.Points3D(
                    m[seen],
                    radii=[0.022 if state == "unloaded" else 0.015],
                    colors=[UNLOADED_POINT if state == "unloaded" else MEASURED],
                    labels=[f"{names[i]} {state}" for i in seen],
                    show_labels=False,
                ),
            )
            if state in s.truth:
                t = s.truth[state]
                ok = np.flatnonzero(np.all(np.isfinite(t), axis=1))
                rec.log(
                    f"truth/reflectors/{state}",
                    rr.Points3D(
                        t[ok],
                        radii=[0.012],
                        colors=[TRUTH],
                        labels=[f"{names[i]} {state} (true)" for i in ok],
                        show_labels=False,
                    ),
                )
        mu = s.measured["unloaded"]
        seen_u = np.flatnonzero(np.all(np.isfinite(mu), axis=1))
        rec.log(
            "tracker/line_of_sight",
            rr.LineStrips3D([[spec.position, mu[i]] for i in seen_u], radii=[0.006], colors=[SIGHT]),
        )
        d, cov, ok = s.deflection()
        idx = np.flatnonzero(ok)
        origins = mu[idx]
        tips = origins + plan.magnify * d[idx]
        rec.log(
            f"deflection/{tag}/measured",
            rr.Arrows3D(
                vectors=plan.magnify * d[idx],
                origins=origins,
                colors=[MEASURED],
                radii=[0.03],
                labels=[f"{names[i]} measured {np.linalg.norm(d[i]) * 1e3:.3f} mm" for i in idx],
                show_labels=False,
            ),
        )
        rec.log(
            f"deflection/{tag}/uncertainty_3sigma",
            _ellipsoids(rr, cov[idx], tips, 3.0 * plan.magnify, (*MEASURED[:3], 90)),
        )
        arrows += len(idx)
        for i in idx:
            rec.log(f"plots/deflection_mm/{_part(names[i])}", rr.Scalars(np.linalg.norm(d[i]) * 1e3))
        if "unloaded" in s.truth and "loaded" in s.truth:
            td = s.truth["loaded"] - s.truth["unloaded"]
            tok = np.flatnonzero(np.all(np.isfinite(td), axis=1))
            rec.log(
                f"truth/deflection/{tag}",
                rr.Arrows3D(
                    vectors=plan.magnify * td[tok],
                    origins=s.truth["unloaded"][tok],
                    colors=[TRUTH],
                    radii=[0.014],
                    labels=[f"{names[i]} true {np.linalg.norm(td[i]) * 1e3:.3f} mm" for i in tok],
                    show_labels=False,
                ),
            )
        # the model's prediction
        pred = plan.predicted.get(s.index, {})
        pi = [i for i in idx if names[i] in pred]
        if plan.predicted:
            pv = np.array([pred[names[i]] for i in pi], float).reshape(-1, 3)
            rec.log(
                f"deflection/{tag}/model",
                rr.Arrows3D(
                    vectors=plan.magnify * pv,
                    origins=mu[pi].reshape(-1, 3),
                    colors=[MODEL],
                    radii=[0.02],
                    labels=[f"{names[i]} model {np.linalg.norm(v) * 1e3:.3f} mm" for i, v in zip(pi, pv)],
                    show_labels=False,
                ),
            )
            n_pred += len(pi)
        # residuals, ending at the measured tips, and the noise around each tip
        if plan.residuals:
            tip_of = {names[i]: t for i, t in zip(idx, tips)}
            rows = []
            for key, per_pose in plan.residuals.items():
                res = per_pose.get(s.index, {})
                refl = [nm for nm in names if nm in res and nm in tip_of]
                vec = np.array([rk * res[nm] for nm in refl]).reshape(-1, 3)
                color = RESIDUAL_AFTER if key == "after" else RESIDUAL
                rec.log(
                    f"residual/x{rk:g}/{key}",
                    rr.Arrows3D(
                        vectors=vec,
                        origins=np.array([tip_of[nm] for nm in refl]).reshape(-1, 3) - vec,
                        colors=[color],
                        radii=[0.02],
                        labels=[f"{nm} residual {np.linalg.norm(res[nm]) * 1e6:.0f} um" for nm in refl],
                        show_labels=False,
                    ),
                )
                if res:
                    rec.log(
                        f"plots/residual_um/{key}",
                        rr.Scalars(1e6 * math.sqrt(np.mean(np.square(list(res.values()))))),
                    )
                rows.append(res)
            rec.log(
                f"residual/x{rk:g}/noise_3sigma",
                _ellipsoids(rr, cov[idx], tips, 3.0 * rk, NOISE, rr.components.FillMode.MajorWireframe),
            )
            if len(idx):
                rec.log(
                    "plots/residual_um/noise",
                    rr.Scalars(1e6 * math.sqrt(np.mean([np.trace(c) / 3 for c in cov[idx]]))),
                )
        rec.log("info/pose", rr.TextDocument(_pose_page(plan, s, header), media_type=rr.MediaType.MARKDOWN))
    if plan.identified is not None:
        for path, arch in plan.chart.items:
            rec.log(path, arch, static=True)
        rec.log(
            "parameters/table",
            rr.TextDocument(viewparams.parameter_table(plan.identified), media_type=rr.MediaType.MARKDOWN),
            static=True,
        )
        truth = viewparams.truth_table(plan.identified)
        if truth is not None:
            rec.log(
                "truth/parameters/table",
                rr.TextDocument(truth, media_type=rr.MediaType.MARKDOWN),
                static=True,
            )
    sources = {"truth": "true joint deflections (/truth/joints)", "model": "the identified model"}
    ghost = " and ".join(v for k, v in sources.items() if plan.has_ghost(k)) or "none"
    return Summary(
        len(plan.scenes), arrows, plan.has_truth, n_pred, ghost, completeness=plan.log.completeness()
    )


def log_campaign(
    rec, log: CampaignLog, identified: IdentificationReport | None = None, magnify: float = DEFAULT_MAGNIFY
) -> Summary:
    """Log the whole campaign (and the identification report) into the RecordingStream."""
    return log_view(rec, plan_view(log, identified, magnify))


# ---------------------------------------------------------------------------------------------
# entry points
# ---------------------------------------------------------------------------------------------


def check_magnify(magnify: float) -> float:
    if not (isinstance(magnify, (int, float)) and math.isfinite(magnify) and magnify > 0):
        raise InputError("--magnify", "value", "a positive finite number", magnify)
    return float(magnify)


def recording_stream(log_path: str | os.PathLike):
    import rerun as rr

    rec = rr.RecordingStream(APP_ID)
    rec.send_recording_name(f"campaign {Path(log_path).name}")
    return rec


def _write(plan: ViewPlan, log_path, rrd_path: Path) -> Summary:
    with atomic_path(rrd_path) as tmp:  # a complete recording or none
        rec = recording_stream(log_path)
        rec.save(tmp, default_blueprint=build_blueprint(plan))
        try:
            summary = log_view(rec, plan)
        finally:
            rec.flush()
            rec.disconnect()
    return summary


def write_recording(
    log_path: str | os.PathLike,
    rrd_path: str | os.PathLike,
    identified: str | os.PathLike | None = None,
    magnify: float = DEFAULT_MAGNIFY,
) -> Summary:
    """Write the recording of a campaign log (and report) to ``rrd_path``, with its default
    blueprint. Raises InputError on bad input, before the output file is created."""
    magnify = check_magnify(magnify)
    log = read_log(log_path, include_truth=True)
    ident = IdentificationReport.read(identified) if identified is not None else None
    rrd_path = Path(rrd_path)
    check_outputs({"--rrd": rrd_path}, {"LOG": log_path, "--identified": identified})
    summary = _write(plan_view(log, ident, magnify), log_path, rrd_path)
    summary.warnings = [f"{ident.source}: {w}" for w in (ident.read_warnings if ident else ())]
    return summary


class ViewerUnavailable(RuntimeError):
    """The Rerun viewer could not be spawned (no viewer binary, it could not start)."""


def spawn_recording(
    log_path: str | os.PathLike,
    identified: str | os.PathLike | None = None,
    magnify: float = DEFAULT_MAGNIFY,
) -> Summary:
    """Send the recording of a campaign log (and report) to a Rerun viewer it spawns, with its
    default blueprint. ViewerUnavailable (saying why) when the viewer cannot be spawned: nothing
    has been sent then, and the caller may write a file instead (:func:`write_recording`)."""
    magnify = check_magnify(magnify)
    log = read_log(log_path, include_truth=True)
    ident = IdentificationReport.read(identified) if identified is not None else None
    plan = plan_view(log, ident, magnify)
    rec = recording_stream(log_path)
    try:
        rec.spawn(default_blueprint=build_blueprint(plan))
    except Exception as e:  # noqa: BLE001  no viewer binary, cannot start
        raise ViewerUnavailable(str(e)) from None
    summary = log_view(rec, plan)
    rec.flush()
    return summary


def write_discovery_recording(
    log_path: str | os.PathLike,
    rrd_path: str | os.PathLike,
    discovery: Discovery,
    magnify: float = DEFAULT_MAGNIFY,
) -> Summary:
    """The view of `calbench discover`: where the user's model disagreed with the measurements
    and how much of it the named effects removed, on the robot (see the module doc)."""
    log = read_log(log_path, include_truth=True)
    return _write(plan_view(log, None, check_magnify(magnify), discovery), log_path, Path(rrd_path))


def has_display() -> bool:
    if os.environ.get("CI"):
        return False
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


WEB_PORT = 9090  # `rerun --web-viewer`'s page (its default)


def open_hint(rrd: Path, display: bool) -> list[str]:
    """How to open a recording (docs/log-and-views.md, "Without a display"): the native viewer
    with a display; without one, Rerun's web viewer served to a browser (port forwarding from
    another machine). Rerun's viewer sends anonymous usage data unless told not to."""
    if display:
        return [f"open it with: rerun {rrd}"]
    return [
        f"open it with: rerun --web-viewer {rrd}  (no display here: Rerun serves its viewer to a browser "
        f"on this machine at http://localhost:{WEB_PORT}; from another machine forward the port "
        f"first: ssh -L {WEB_PORT}:localhost:{WEB_PORT} THIS-HOST)",
        "  the native viewer under Xvfb needs Vulkan (Mesa's lavapipe: WGPU_BACKEND=vulkan); "
        "`rerun analytics disable` turns Rerun's telemetry off",
    ]


def default_rrd_path(log_path: Path) -> Path:
    """Where the recording goes without --rrd and without a display: beside the log."""
    return Path(log_path).with_suffix(".rrd")


__all__ = [
    "write_recording",
    "write_discovery_recording",
    "Discovery",
    "has_display",
    "default_rrd_path",
    "recording_stream",
    "Summary",
    "plan_view",
    "ViewPlan",
    "log_view",
    "log_campaign",
    "measured_deflections",
    "build_blueprint",
    "magnify_tag",
    "DEFAULT_MAGNIFY",
    "RESIDUAL_FACTOR",
]
