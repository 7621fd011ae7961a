"""`calbench view`: a Rerun recording of a campaign, its measurements and (optionally) its
identification.

What the recording holds (entity paths; everything in metres, world frame)
--------------------------------------------------------------------------
The ``pose`` timeline (a sequence: 0, 1, ... = the pose index of the plan) steps through the
measurement configurations. Both states of a pose live at the same time point and are told
apart by the entity path, so scrubbing ``pose`` shows the unloaded and the loaded robot side
by side (they differ by ~1 mm, so they overlap: unloaded is drawn solid in the MJCF colours,
loaded as an orange wireframe).

``robot/unloaded/<body>``, ``robot/loaded/<body>``
    One ``Transform3D`` (world from body) per pose; the body's geoms are logged once, static,
    in the body frame as children ``<body>/<geom>`` (box, capsule, cylinder, sphere, ellipsoid,
    mesh; planes are skipped). ``robot/<state>/tendon/<name>`` is the compensator spring as a
    line between its sites. Body poses come from ``mj_kinematics`` at:

    * the true equilibrium ``qpos`` of that pose and state (``/truth/joints``) when the log
      carries truth (a simulated campaign);
    * otherwise (a real campaign, or a stripped log) the rigid closed-loop configuration at the
      commanded angles, :meth:`bench.robot.Robot.rigid_qpos`. Then unloaded and loaded draw the
      same robot: the command does not change, and the deflection is only known at the
      reflectors.
``tracker``
    The laser tracker's position (static point), and ``tracker/line_of_sight`` per pose: a line
    to every reflector it saw in the unloaded state.
``measured/<state>``
    Measured reflector positions (mean of the repeats, tracker frame -> world frame with the
    tracker pose of the log header: :func:`bench.tracker.mean_reading`, as identification
    averages them), and ``measured/<state>/uncertainty_3sigma``: ellipsoids
    whose half-axes are 3 sigma of the covariance of that mean (true scale: ~60 um).
``deflection/x<F>/measured``
    The measured deflection (loaded - unloaded, mean of the repeats) of every reflector seen in
    both states, as an arrow from the unloaded position, magnified by F (``--magnify``, default
    200, stated in the path and in each label, which also gives the true-scale size in mm).
    ``deflection/x<F>/uncertainty_3sigma``: the 3-sigma ellipsoid of that deflection, magnified
    by the same F and centred on the arrow's tip: a deflection is significant when its
    ellipsoid is small beside the arrow (it is, ~17 mm against 0.3-0.7 m at x200 and 20 um).
``truth/...`` (only when the log carries truth; hide the whole tree to see what a real
campaign sees)
    ``truth/reflectors/<state>`` the true reflector positions, ``truth/deflection/x<F>`` the
    true deflections, magnified like the measured ones.
``plots/deflection_mm/<reflector>``
    Per-pose scalar series: magnitude of the measured deflection, mm.

With ``--identified ID.json`` (the report of ``calbench identify --json``, or the view report of
``calbench discover``; read as a :class:`bench.idreport.IdentificationReport`):

``parameters/...``
    Static bar charts, bar i = parameter i of the table: ``parameters/compliance/estimate``,
    ``.../std`` and ``.../truth`` (k1..k6 in urad/(N*m)), ``parameters/relative_std_percent``
    (all parameters), ``parameters/z_score`` ((estimate - truth)/std, when truth is known), and
    ``parameters/table``, a markdown table of every parameter with its unit.
``deflection/x<F>/predicted``, ``deflection/x<F>/residual``, ``plots/residual_mm/<reflector>``
    Only when the report carries per-observation predictions, an optional field that this
    viewer reads (the CONTRACT does not require it): a list under ``"observations"`` of objects
    ``{"pose": int, "reflector": str, "predicted": [dx, dy, dz]}``, the model's deflection
    loaded - unloaded of that reflector in the world frame, metres. The residual drawn is the
    log's measured deflection minus the predicted one. Entries that do not fit are skipped
    with a warning; without any, only the bar charts are shown.

The default blueprint shows the 3D scene beside the per-pose plots (and the parameter charts
and table with ``--identified``), with the time panel on the ``pose`` timeline.

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

from .errors import InputError
from .geoms import GeomShape, geom_shapes, tendon_sites
from .idreport import IdentificationReport, ParameterEstimate
from .logformat import STATES, CampaignLog, PerState, read_log
from .outputs import atomic_path, check_outputs
from .robot import Robot
from .scenario import TrackerSpec
from .tracker import MeanReading, mean_reading

DEFAULT_MAGNIFY = 200.0
APP_ID = "calbench"
COMPLIANCE_NAMES = tuple(f"k{i}" for i in range(1, 7))
# one colour per reflector (cycled), and one per kind of arrow
REFLECTOR_COLORS = [(230, 80, 60), (60, 140, 230), (80, 190, 90), (200, 120, 220),
                    (240, 180, 40), (60, 200, 200)]
MEASURED_COLOR = (255, 140, 0)
PREDICTED_COLOR = (40, 120, 255)
RESIDUAL_COLOR = (220, 30, 30)
TRUTH_COLOR = (40, 200, 80)
LOADED_WIRE_COLOR = (255, 140, 0, 255)


# ---------------------------------------------------------------------------------------------
# what the recording is computed from
# ---------------------------------------------------------------------------------------------


@dataclass
class PoseView:
    """One pose, both states: body poses and measured reflectors (world frame)."""

    index: int
    xpos: dict[str, np.ndarray]            # state -> (nbody, 3)
    xquat: dict[str, np.ndarray]           # state -> (nbody, 4) wxyz
    tendons: dict[str, list[np.ndarray]]   # state -> one (k, 3) polyline per tendon
    measured: dict[str, np.ndarray]        # state -> (n, 3) world, NaN where not seen
    measured_cov: dict[str, np.ndarray]    # state -> (n, 3, 3) world, of the mean of repeats
    truth: dict[str, np.ndarray] = field(default_factory=dict)  # state -> (n, 3) world

    def deflection(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Measured deflection (n, 3), its covariance (n, 3, 3), and which rows are valid."""
        d = self.measured["loaded"] - self.measured["unloaded"]
        cov = self.measured_cov["loaded"] + self.measured_cov["unloaded"]
        ok = np.all(np.isfinite(d), axis=1)
        return d, cov, ok


def load_robot(log: CampaignLog) -> Robot:
    if not log.mjcf_text:
        raise InputError(log.path, "robot MJCF attachment (application/xml)",
                         "the robot model carried in the log", "none")
    try:
        return Robot.from_xml(log.mjcf_text)
    except ValueError as e:
        raise InputError(log.path, "robot MJCF attachment", "an MJCF model MuJoCo can load",
                         str(e).splitlines()[0] if str(e) else "a compile error") from None


def mean_measurements(log: CampaignLog, spec: TrackerSpec, names: list[str]) \
        -> dict[tuple[int, str], MeanReading]:
    """(pose, state) -> the mean of its readings in the world frame
    (:func:`bench.tracker.mean_reading`), rows in ``names`` order (readings are matched by
    reflector name)."""
    groups: dict[tuple[int, str], list] = {}
    for m in log.measurements:
        groups.setdefault((m.pose, m.state), []).append(m.in_order(names))
    return {key: mean_reading(spec, readings) for key, readings in groups.items()}


def measured_deflections(log: CampaignLog) -> dict[int, dict[str, np.ndarray]]:
    """pose -> reflector -> measured deflection (3,) in the world frame, metres: mean of the
    loaded repeats minus mean of the unloaded repeats. Reflectors seen in both states only."""
    names = list(log.header.get("reflectors") or [])
    means = mean_measurements(log, log.tracker_spec(), names)
    out: dict[int, dict[str, np.ndarray]] = {}
    for p in log.complete_poses:
        if (p, "unloaded") not in means or (p, "loaded") not in means:
            continue
        d = means[(p, "loaded")].position - means[(p, "unloaded")].position
        out[p] = {nm: d[i] for i, nm in enumerate(names) if np.all(np.isfinite(d[i]))}
    return out


def _tendon_sites(model: mujoco.MjModel) -> list[tuple[str, list[int]]]:
    return [(_part(name), sites) for name, sites in tendon_sites(model)]


def pose_views(log: CampaignLog, robot: Robot) -> list[PoseView]:
    model, data = robot.model, mujoco.MjData(robot.model)
    names = list(log.header.get("reflectors") or [])
    means = mean_measurements(log, log.tracker_spec(), names)
    tendons = _tendon_sites(model)
    truth_joints = log.truth.joints if log.truth else {}
    truth_refl = log.truth.reflectors if log.truth else {}
    missing = PerState()
    nan = np.full((len(names), 3), np.nan)
    nan_cov = np.full((len(names), 3, 3), np.nan)
    views = []
    for p in log.complete_poses:
        xpos, xquat, tl, meas, cov, truth = {}, {}, {}, {}, {}, {}
        for state in STATES:
            qpos = None
            tj = truth_joints.get(p, missing).get(state)
            if tj is not None and tj.qpos.shape == (model.nq,):
                qpos = tj.qpos
            else:
                q = log.poses.get(p, missing).get(state)
                if q is None:
                    q = log.poses.get(p, missing).unloaded
                if q is None or np.asarray(q).shape != (6,):
                    raise InputError(log.path, f"/campaign/pose (pose {p}, {state})",
                                     "the commanded joint angles q[6] of every complete pose",
                                     None if q is None else np.asarray(q).tolist())
                qpos = robot.rigid_qpos(np.asarray(q, dtype=float))
            data.qpos[:] = qpos
            mujoco.mj_kinematics(model, data)
            xpos[state] = data.xpos.copy()
            xquat[state] = data.xquat.copy()
            tl[state] = [data.site_xpos[s].copy() for _, s in tendons]
            mean = means.get((p, state))
            meas[state], cov[state] = (nan, nan_cov) if mean is None else \
                (mean.position, mean.covariance)
            tr = truth_refl.get(p, missing).get(state)
            if tr is not None:
                pos = np.full((len(names), 3), np.nan)
                for j, nm in enumerate(tr.reflectors):
                    if nm in names:
                        pos[names.index(nm)] = tr.position_world[j]
                truth[state] = pos
        views.append(PoseView(p, xpos, xquat, tl, meas, cov, truth))
    return views


# ---------------------------------------------------------------------------------------------
# logging
# ---------------------------------------------------------------------------------------------


def _xyzw(wxyz) -> list[float]:
    w, x, y, z = (float(v) for v in wxyz)
    return [x, y, z, w]


def _rgba(rgba) -> tuple[int, int, int, int]:
    return tuple(int(round(255 * min(max(float(c), 0.0), 1.0))) for c in rgba)  # type: ignore


def _geom_archetype(rr, shape: GeomShape, wire: bool):
    """The rerun archetype drawing one geom (bench/geoms.py) in its body's frame."""
    size, pos, quat = shape.size, shape.pos, shape.quat
    color = LOADED_WIRE_COLOR if wire else _rgba(shape.rgba)
    fill = rr.components.FillMode.MajorWireframe if wire else rr.components.FillMode.Solid
    q = rr.Quaternion(xyzw=_xyzw(quat))
    if shape.kind == "box":
        return rr.Boxes3D(half_sizes=[size], centers=[pos], quaternions=[q], colors=[color],
                          fill_mode=fill)
    if shape.kind == "capsule":
        # MuJoCo: centred, axis z, half-length size[1]; rerun: starts at translation, along +z
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, quat)
        start = pos - R.reshape(3, 3)[:, 2] * size[1]
        return rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]], translations=[start],
                             quaternions=[q], colors=[color], fill_mode=fill)
    if shape.kind == "cylinder":
        return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], centers=[pos],
                              quaternions=[q], colors=[color], fill_mode=fill)
    if shape.kind == "ellipsoid":
        return rr.Ellipsoids3D(half_sizes=[size], centers=[pos], quaternions=[q], colors=[color],
                               fill_mode=fill)
    if shape.kind == "mesh":
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, quat)
        verts = shape.vertices @ R.reshape(3, 3).T + pos
        faces = shape.faces
        if wire:  # a wireframe of the triangles' edges
            strips = verts[np.concatenate([faces, faces[:, :1]], axis=1)]
            return rr.LineStrips3D(strips, colors=[color], radii=[0.002])
        return rr.Mesh3D(vertex_positions=verts, triangle_indices=faces, albedo_factor=color)
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


def build_blueprint(has_identified: bool, has_truth: bool, magnify: float):
    import rerun.blueprint as rrb
    tag = magnify_tag(magnify)
    contents = ["+ /robot/**", "+ /tracker/**", "+ /measured/**", "+ /deflection/**"]
    if has_truth:
        contents.append("+ /truth/**")
    scene = rrb.Spatial3DView(
        name=f"Robot, reflectors, deflections ({tag} arrows)", origin="/", contents=contents,
        line_grid=rrb.archetypes.LineGrid3D(visible=True))
    plots = rrb.TimeSeriesView(name="Deflection per pose (mm, true scale)", origin="/plots")
    if has_identified:
        charts = rrb.Tabs(
            rrb.BarChartView(name="compliance estimate (urad/(N*m))",
                             origin="/parameters/compliance/estimate"),
            rrb.BarChartView(name="compliance std", origin="/parameters/compliance/std"),
            rrb.BarChartView(name="compliance truth", origin="/parameters/compliance/truth"),
            rrb.BarChartView(name="relative std (%)", origin="/parameters/relative_std_percent"),
            rrb.BarChartView(name="z = (estimate - truth)/std", origin="/parameters/z_score"),
            rrb.TextDocumentView(name="parameter table", origin="/parameters/table"),
        )
        side = rrb.Vertical(plots, charts, row_shares=[1, 1])
    else:
        side = plots
    return rrb.Blueprint(
        rrb.Horizontal(scene, side, column_shares=[3, 2]),
        rrb.TimePanel(timeline="pose", expanded=True),
        collapse_panels=False,
    )


@dataclass
class Summary:
    poses: int
    arrows: int
    truth: bool
    predicted: int
    robot_source: str
    warnings: list[str] = field(default_factory=list)   # about the --identified report


def log_campaign(rec, log: CampaignLog, identified: IdentificationReport | None = None,
                 magnify: float = DEFAULT_MAGNIFY) -> Summary:
    """Log the whole campaign (and the identification report) into the RecordingStream."""
    import rerun as rr

    robot = load_robot(log)
    model = robot.model
    views = pose_views(log, robot)
    spec = log.tracker_spec()
    names = list(log.header.get("reflectors") or [])
    bodies = _body_names(model)
    tag = magnify_tag(magnify)
    has_truth = bool(log.truth and log.truth.joints)
    predicted = identified.predictions() if identified else {}
    refl_colors = [REFLECTOR_COLORS[i % len(REFLECTOR_COLORS)] for i in range(len(names))]

    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    # --- static robot geometry, in body frames -----------------------------------------
    for state in STATES:
        wire = state == "loaded"
        for shape in geom_shapes(model):
            arch = _geom_archetype(rr, shape, wire)
            if arch is None:
                continue
            b = shape.body
            path = f"robot/{state}/{bodies[b]}/{_part(shape.name)}" if b else \
                f"robot/{state}/world/{_part(shape.name)}"
            rec.log(path, arch, static=True)
    tendons = _tendon_sites(model)
    # --- tracker -------------------------------------------------------------------------
    label = f"laser tracker (sigma {spec.sigma * 1e6:.0f} um)"
    rec.log("tracker", rr.Points3D([spec.position], radii=[0.06], colors=[(20, 20, 20)],
                                   labels=[label], show_labels=True), static=True)
    for i, nm in enumerate(names):
        rec.log(f"plots/deflection_mm/{nm}",
                rr.SeriesLines(colors=[refl_colors[i]], names=[f"|d| {nm}"]), static=True)
        if predicted:
            rec.log(f"plots/residual_mm/{nm}",
                    rr.SeriesLines(colors=[refl_colors[i]], names=[f"|residual| {nm}"]),
                    static=True)

    arrows = n_pred = 0
    for v in views:
        rec.set_time("pose", sequence=v.index)
        for state in STATES:
            base = f"robot/{state}"
            for b in range(1, model.nbody):
                rec.log(f"{base}/{bodies[b]}",
                        rr.Transform3D(translation=v.xpos[state][b],
                                       quaternion=rr.Quaternion(xyzw=_xyzw(v.xquat[state][b]))))
            for (tname, _), pts in zip(tendons, v.tendons[state]):
                rec.log(f"{base}/tendon/{tname}",
                        rr.LineStrips3D([pts], radii=[0.015], colors=[(25, 150, 230)]))
            # measured reflectors
            m = v.measured[state]
            seen = np.all(np.isfinite(m), axis=1)
            rec.log(f"measured/{state}", rr.Points3D(
                m[seen], radii=[-4.0 if state == "loaded" else -3.0],
                colors=[MEASURED_COLOR if state == "loaded" else (90, 90, 90)],
                labels=[f"{names[i]} {state}" for i in np.flatnonzero(seen)]))
            hs, qs = [], []
            for i in np.flatnonzero(seen):
                h, q = _ellipsoid(v.measured_cov[state][i], 3.0)
                hs.append(h)
                qs.append(rr.Quaternion(xyzw=q))
            rec.log(f"measured/{state}/uncertainty_3sigma", rr.Ellipsoids3D(
                half_sizes=hs, centers=m[seen], quaternions=qs, colors=[(255, 200, 0, 120)],
                fill_mode=rr.components.FillMode.Solid))
            if state in v.truth:
                t = v.truth[state]
                ok = np.all(np.isfinite(t), axis=1)
                rec.log(f"truth/reflectors/{state}", rr.Points3D(
                    t[ok], radii=[-3.0], colors=[TRUTH_COLOR],
                    labels=[f"{names[i]} {state} (true)" for i in np.flatnonzero(ok)]))
        # lines of sight (unloaded)
        mu = v.measured["unloaded"]
        seen = np.all(np.isfinite(mu), axis=1)
        rec.log("tracker/line_of_sight", rr.LineStrips3D(
            [[spec.position, p] for p in mu[seen]], radii=[-1.0], colors=[(120, 120, 120, 160)]))
        # measured deflections
        d, cov, ok = v.deflection()
        idx = np.flatnonzero(ok)
        origins = v.measured["unloaded"][idx]
        rec.log(f"deflection/{tag}/measured", rr.Arrows3D(
            vectors=magnify * d[idx], origins=origins, colors=[MEASURED_COLOR],
            radii=[0.008],
            labels=[f"{names[i]} {np.linalg.norm(d[i]) * 1e3:.3f} mm ({tag})" for i in idx]))
        arrows += len(idx)
        hs, qs = [], []
        for i in idx:
            h, q = _ellipsoid(cov[i], 3.0 * magnify)
            hs.append(h)
            qs.append(rr.Quaternion(xyzw=q))
        rec.log(f"deflection/{tag}/uncertainty_3sigma", rr.Ellipsoids3D(
            half_sizes=hs, centers=origins + magnify * d[idx], quaternions=qs,
            colors=[(255, 140, 0, 70)], fill_mode=rr.components.FillMode.Solid))
        for i in idx:
            rec.log(f"plots/deflection_mm/{names[i]}", rr.Scalars(np.linalg.norm(d[i]) * 1e3))
        if "unloaded" in v.truth and "loaded" in v.truth:
            td = v.truth["loaded"] - v.truth["unloaded"]
            tok = np.flatnonzero(np.all(np.isfinite(td), axis=1))
            rec.log(f"truth/deflection/{tag}", rr.Arrows3D(
                vectors=magnify * td[tok], origins=v.truth["unloaded"][tok],
                colors=[TRUTH_COLOR], radii=[0.005],
                labels=[f"{names[i]} true {np.linalg.norm(td[i]) * 1e3:.3f} mm ({tag})"
                        for i in tok]))
        # the model's prediction and the residual
        pred = predicted.get(v.index, {})
        pi = [i for i in idx if names[i] in pred]
        if pi:
            pv = np.array([pred[names[i]] for i in pi], dtype=float)
            o = v.measured["unloaded"][pi]
            res = d[pi] - pv
            rec.log(f"deflection/{tag}/predicted", rr.Arrows3D(
                vectors=magnify * pv, origins=o, colors=[PREDICTED_COLOR], radii=[0.006],
                labels=[f"{names[i]} model {np.linalg.norm(p) * 1e3:.3f} mm ({tag})"
                        for i, p in zip(pi, pv)]))
            rec.log(f"deflection/{tag}/residual", rr.Arrows3D(
                vectors=magnify * res, origins=o + magnify * pv, colors=[RESIDUAL_COLOR],
                radii=[0.006],
                labels=[f"{names[i]} residual {np.linalg.norm(r) * 1e6:.0f} um ({tag})"
                        for i, r in zip(pi, res)]))
            for i, r in zip(pi, res):
                rec.log(f"plots/residual_mm/{names[i]}", rr.Scalars(np.linalg.norm(r) * 1e3))
            n_pred += len(pi)
        elif predicted:  # no prediction here: hide the last pose's
            rec.log(f"deflection/{tag}/predicted", rr.Clear(recursive=False))
            rec.log(f"deflection/{tag}/residual", rr.Clear(recursive=False))
    if identified is not None:
        log_parameters(rec, identified)
    return Summary(len(views), arrows, has_truth, n_pred,
                   "true equilibrium qpos (/truth/joints)" if has_truth
                   else "rigid closed-loop configuration at the commanded q")


def log_parameters(rec, ident: IdentificationReport) -> None:
    """Static bar charts and a table of the identified parameters."""
    import rerun as rr

    def z_of(p: ParameterEstimate) -> float | None:
        if p.estimate is None or p.truth is None or not p.std:
            return None
        return (p.estimate - p.truth) / p.std

    by_name = {p.name: p for p in ident.parameters}
    ks = [by_name.get(n) for n in COMPLIANCE_NAMES]
    if any(ks):
        def col(key):
            vals = [(getattr(p, key) if p else None) for p in ks]
            return None if all(x is None for x in vals) else \
                np.array([np.nan if x is None else x * 1e6 for x in vals])
        for key in ("estimate", "std", "truth"):
            vals = col(key)
            if vals is not None:
                rec.log(f"parameters/compliance/{key}",
                        rr.BarChart(np.nan_to_num(vals), color=
                                    {"estimate": PREDICTED_COLOR, "std": (150, 150, 150),
                                     "truth": TRUTH_COLOR}[key]), static=True)
    rel = [abs(p.std / p.estimate) * 100 if p.std is not None and p.estimate else 0.0
           for p in ident.parameters]
    if any(p.std is not None for p in ident.parameters):
        rec.log("parameters/relative_std_percent", rr.BarChart(rel, color=(150, 150, 150)),
                static=True)
    zs = [z_of(p) for p in ident.parameters]
    if any(z is not None for z in zs):
        rec.log("parameters/z_score", rr.BarChart([z or 0.0 for z in zs], color=RESIDUAL_COLOR),
                static=True)

    def fmt(x):
        return "-" if x is None else f"{x:.4g}"
    source = Path(ident.source).name if ident.source else "report"
    lines = [f"**Identified parameters** ({ident.method or 'method not stated'}, "
             f"`{source}`). Bar *i* of every chart is row *i* "
             "(compliance charts: k1..k6 in urad/(N*m)).", "",
             "| # | name | estimate | std | truth | z | unit |",
             "|---|---|---|---|---|---|---|"]
    for i, (p, z) in enumerate(zip(ident.parameters, zs)):
        lines.append(f"| {i} | {p.name} | {fmt(p.estimate)} | {fmt(p.std)} | "
                     f"{fmt(p.truth)} | {'-' if z is None else f'{z:+.2f}'} | {p.unit} |")
    if not ident.observations:
        lines += ["", "The report carries no per-observation predicted deflections, so the "
                  "3D view shows the measured deflections only."]
    rec.log("parameters/table", rr.TextDocument("\n".join(lines),
                                                media_type=rr.MediaType.MARKDOWN), static=True)


# ---------------------------------------------------------------------------------------------
# entry points
# ---------------------------------------------------------------------------------------------


def _check_magnify(magnify: float) -> float:
    if not (isinstance(magnify, (int, float)) and math.isfinite(magnify) and magnify > 0):
        raise InputError("--magnify", "value", "a positive finite number", magnify)
    return float(magnify)


def recording_stream(log_path: str | os.PathLike):
    import rerun as rr
    rec = rr.RecordingStream(APP_ID)
    rec.send_recording_name(f"campaign {Path(log_path).name}")
    return rec


def write_recording(log_path: str | os.PathLike, rrd_path: str | os.PathLike,
                    identified: str | os.PathLike | None = None,
                    magnify: float = DEFAULT_MAGNIFY) -> Summary:
    """Write the recording of a campaign log (and report) to ``rrd_path``, with its default
    blueprint. Raises InputError on bad input, before the output file is created."""
    magnify = _check_magnify(magnify)
    log = read_log(log_path, include_truth=True)
    ident = IdentificationReport.read(identified) if identified is not None else None
    load_robot(log)  # fail before creating the file
    log.tracker_spec()
    rrd_path = Path(rrd_path)
    check_outputs({"--rrd": rrd_path}, {"LOG": log_path, "--identified": identified})
    with atomic_path(rrd_path) as tmp:          # a complete recording or none
        rec = recording_stream(log_path)
        bp = build_blueprint(ident is not None, bool(log.truth), magnify)
        rec.save(tmp, default_blueprint=bp)
        try:
            summary = log_campaign(rec, log, ident, magnify)
        finally:
            rec.flush()
            rec.disconnect()
    summary.warnings = [f"{ident.source}: {w}" for w in (ident.read_warnings if ident else ())]
    return summary


def has_display() -> bool:
    if os.environ.get("CI"):
        return False
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def default_rrd_path(log_path: Path) -> Path:
    """Where the recording goes without --rrd and without a display: beside the log."""
    return Path(log_path).with_suffix(".rrd")


__all__ = ["write_recording", "has_display", "default_rrd_path", "recording_stream", "Summary", "log_campaign", "mean_measurements",
           "measured_deflections", "build_blueprint", "magnify_tag", "DEFAULT_MAGNIFY"]
