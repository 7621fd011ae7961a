"""Registering the tracker: where it stood and how it was turned, from the readings themselves.

Nobody measures a tracker's pose relative to the robot's base to a few micrometres, so
``calbench import`` estimates the full rigid transform, tracker frame to robot world
(world = R tracker + t), by fitting the readings to the reflector positions the nominal model
predicts at the commanded poses.

What the model predicts: the unloaded robot is not rigid. Gravity bends it: on the paper robot
the stiff compensator alone sags J2 by up to 1.8 deg, tens of mm at the tool, so a rigid fit
against rigid kinematics is turned by ~2e-3 rad, and deflections rotated by as little as 1e-4 rad
already move the one-step estimates by up to 0.02 sigma (measured on the paper campaign). The
prediction must include the sag, by the exact statics, with elastic parameters that no plan and
no MJCF may supply (a plan has no truth; the MJCF's stiffness is never read: the truth
firewall). Nor do the deflections alone fix them well enough: the sag is dominated by the
compensator's static force K_C (L - s0), and the deflections leave s0 uncertain by ~50 mm (the
paper plan), i.e. degrees of J2 sag. The unloaded positions themselves pin it down. So the
registration is the joint maximum-likelihood fit of the tracker's pose AND the elastic
parameters to every reading of the poses seen in both states (unloaded and loaded mean per
reflector, in the tracker frame, with their covariances):

    y_s = R^T (x_s(theta) - t) + noise,   x_0 = unloaded equilibrium, x_1 = x_0 + dp(theta)

(identify/core/forward.py's exact statics and Jacobians; identify/core/leastsq.py's Levenberg-Marquardt,
parameters the data cannot determine, e.g. k1 under vertical loads, held). It starts from the
closed-form rigid fit (identify/core/rigid.py: against rigid kinematics) and the
one-step estimate from the deflections so rotated, and needs a handful of evaluations. The
pose's uncertainty is the [rotation, position] block of the inverse Fisher information (the
elastic parameters marginalised), scaled by sqrt(chi2/dof) when the misfit exceeds the noise.
The elastic parameters found here only serve the sag; ``calbench identify`` estimates them from
the deflections in the log, as for any log.

The residual then says how well the nominal GEOMETRY fits. Real robots have mm-level geometric
errors; a pose's error is the same in its two states, so it cancels from the deflection (to
first order: docs/performance.md quantifies what remains) but not from the positions, where, weighted by
the tracker's micrometres, it would drag the elastic parameters (and through them the sag and
the pose) to wherever they best hide millimetres. So the misfit is estimated as a variance
component: after a fit, the common mode of each point's two residuals, beyond what the readings
explain, gives the per-axis variance g^2 of the geometric misfit (:func:`geometry_variance`);
the fit is repeated with g^2 I added to both states' covariance and between them (correlated:
the deflections keep their full weight), until g^2 settles (two or three fits). The first fit's
chi2 per degree of freedom beyond 1 + GEOMETRY_CHI2 sqrt(2/dof) (4 standard deviations of the
chi2 distribution) draws a warning naming g; the pose's uncertainty then includes the misfit. Beyond ABSURD_RMS, even with the rigid fit alone, the readings cannot be those
of the plan's poses (wrong pose indices, point names or unit): InputError naming the worst row.

With no pose measured in both states nothing says how much the robot sags: the rigid
registration of the unloaded readings is kept, with a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.campaign import pose_load
from calbench.bench.core import InputError
from calbench.bench.model import Robot, load_robot
from calbench.bench.scenario import Plan
from calbench.bench.shopfloor import ImportedReadings, ReadingsTable, first_time
from calbench.bench.tracker import TrackerSpec, mean_reading, tracker_rotation
from calbench.identify.core import (
    RANK_TOL,
    ForwardModel,
    Observations,
    PoseObservation,
    RigidFit,
    analyze,
    covariance,
    design_from_observations,
    fit_rigid,
    levenberg_marquardt,
    non_collinear,
    pose_observation,
    rotation_exp,
)
from calbench.identify.methods import (
    dtheta_dphi,
    generic_start,
    one_step,
    sanitize_start,
    to_phi,
    to_theta,
    valid_phi,
)

GEOMETRY_CHI2 = 4.0  # warn when chi2/dof > 1 + GEOMETRY_CHI2 sqrt(2/dof)
GEOMETRY_ROUNDS = 5  # fits to settle the geometric misfit's variance (2-3 suffice)
ABSURD_RMS = 0.2  # m per axis of the rigid fit: beyond, not the plan's poses
POSE_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")
POSE_SCALE = 1e-3  # rad and m: the size of the correction the joint fit makes to the start


@dataclass(frozen=True)
class PointData:
    """The registration's data: per (pose, reflector) seen, the mean reading in each state
    (tracker frame) and its covariance; ``obs`` holds the poses seen in both states (its dp
    in the tracker frame) and fixes the row order of ``y``."""

    obs: Observations | None
    y: np.ndarray  # (2, M, 3) m: unloaded, loaded, rows of obs
    cov: np.ndarray  # (2, M, 3, 3) m^2
    lines: list[int]  # a CSV line of each row (for messages)
    unloaded: tuple[list[tuple[int, str]], np.ndarray, np.ndarray, list[int]]  # every unloaded point


@dataclass
class TrackerRegistration:
    """The registered tracker pose and how it was found."""

    fit: RigidFit
    evaluations: int
    converged: bool
    sag: str  # how the prediction includes the sag
    theta: np.ndarray | None  # the elastic parameters of the sag (SI), None when rigid
    names: tuple[str, ...] = ()  # their names (the robot's parameter layout)
    geometry_rms: float = 0.0  # m per axis: the nominal geometry's misfit, estimated
    misfit_chi2: float | None = None  # chi2 of the fit weighted by the readings' errors alone
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        """The ``registration`` record of ``/campaign/info.imported`` (SI)."""
        f = self.fit
        return {
            "method": "tracker pose fitted to the readings against the nominal model at the commanded "
            "poses (identify/shopfloor/tracker_pose.py); sag: " + self.sag,
            "points": f.n_points,
            "evaluations": self.evaluations,
            "converged": self.converged,
            "rotation": f.rotation.tolist(),
            "position": f.position.tolist(),
            "rms": f.rms,
            "expected_rms": f.expected_rms,
            "chi2_per_dof": f.chi2_per_dof,
            "rotation_std": f.rotation_std.tolist(),
            "position_std": f.position_std.tolist(),
            "uncertainty_scaled_by": f.scale,
            "geometry_rms": self.geometry_rms,
            "sag_parameters": None
            if self.theta is None
            else {n: float(v) for n, v in zip(self.names, self.theta)},
            "warnings": list(self.warnings),
        }


def point_data(
    plan: Plan,
    robot: Robot,
    readings: ImportedReadings,
    table: ReadingsTable,
    names: list[str],
    tracker: TrackerSpec,
) -> PointData:
    """Mean readings per state in the tracker frame (bench.tracker.mean_reading with the
    tracker at the origin, unrotated). Their covariance is that of the readings' independent
    error, plus, for a correlated tracker, its shared error's at the readings' mean time
    (TrackerModel.correlated_marginal: iso10360's field and drift): the fit treats the points as
    independent, so each is weighted by all of its error (a systematic field is, for a fit of
    absolute positions, error like any other)."""
    at_origin = tracker.placed(np.zeros(3), np.eye(3))
    error_model = tracker.error_model
    t_first = first_time(readings)

    def mean(reps):
        m = mean_reading(at_origin, reps)
        if error_model.correlated and m.seen.any():
            t = np.mean([r.time for r in reps]) - t_first
            c = m.covariance.copy()
            c[m.seen] += error_model.correlated_marginal(
                tracker, m.position[m.seen], np.full(int(m.seen.sum()), t)
            )
            m = replace(m, covariance=c)
        return m

    def first_line(p: int, name: str) -> int:
        """The file's first unloaded row of ``name`` in pose ``p``."""
        rows = table.rows(p, "unloaded")
        return int(table.line[rows][np.array(table.points)[table.point[rows]] == name].min())

    poses, ys, covs, lines = [], [], [], []
    u_keys, u_y, u_c, u_lines = [], [], [], []
    for p in dict.fromkeys(p for p, _ in readings):
        u, ld = readings[(p, "unloaded")], readings[(p, "loaded")]
        if u:
            m0 = mean(u)
            for i in np.flatnonzero(m0.seen):
                u_keys.append((p, names[i]))
                u_y.append(m0.position[i])
                u_c.append(m0.covariance[i])
                u_lines.append(first_line(p, names[i]))
        if not u or not ld:
            continue
        load, _ = pose_load(robot, plan, plan.poses[p])
        ob = pose_observation(
            p,
            plan.poses[p].q,
            load.force,
            load.moment,
            robot.model.site(load.site).name,
            names,
            u,
            ld,
            at_origin,
            ([r.time - t_first for r in u], [r.time - t_first for r in ld]),
        )
        if not len(ob.reflectors):
            continue
        poses.append(ob)
        m1 = mean(ld)
        rows = [names.index(r) for r in ob.reflectors]
        ys.append(np.stack([m0.position[rows], m1.position[rows]]))
        covs.append(np.stack([m0.covariance[rows], m1.covariance[rows]]))
        lines += [first_line(p, r) for r in ob.reflectors]
    obs = Observations(poses, at_origin, float(tracker.sigma), len(plan.poses)) if poses else None
    y = np.concatenate(ys, axis=1) if ys else np.zeros((2, 0, 3))
    cov = np.concatenate(covs, axis=1) if covs else np.zeros((2, 0, 3, 3))
    unloaded = (u_keys, np.array(u_y).reshape(-1, 3), np.array(u_c).reshape(-1, 3, 3), u_lines)
    return PointData(obs, y, cov, lines, unloaded)


def rigid_points(robot: Robot, plan: Plan, keys: list[tuple[int, str]]) -> np.ndarray:
    """World positions of the (pose, reflector) ``keys`` by rigid kinematics at the command."""
    m, d = robot.model, robot.data
    out = np.empty((len(keys), 3))
    for i, (p, name) in enumerate(keys):
        d.qpos[:] = robot.rigid_qpos(plan.poses[p].q)
        mujoco.mj_kinematics(m, d)
        out[i] = d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)]
    return out


class JointModel:
    """The readings predicted in the tracker frame from x = [w (3, rad), t (3, m), phi (p)]:
    f_s = R^T (x_s(theta) - t), R = exp([w]x) R0, theta = onestep.to_theta(phi); each
    (pose, reflector) point's two states whitened together by their 6 x 6 covariance: the mean
    readings' own, plus ``geometry_var`` I in both states and between them (a geometric error of
    the nominal model is the same in both states of a pose: it cancels from the deflection, not
    from the positions)."""

    def __init__(self, fm: ForwardModel, pts: PointData, rot0: np.ndarray, geometry_var: float = 0.0):
        self.fm, self.rot0, self.layout = fm, rot0, fm.layout
        self.n = 6 + self.layout.n
        m = pts.y.shape[1]
        g = geometry_var * np.eye(3)
        cov = np.zeros((m, 6, 6))
        cov[:, :3, :3], cov[:, 3:, 3:] = pts.cov[0] + g, pts.cov[1] + g
        cov[:, :3, 3:] = cov[:, 3:, :3] = g
        self.linv = np.linalg.inv(np.linalg.cholesky(cov))  # (M, 6, 6)
        self.y_w = self._white(pts.y)

    def _white(self, v: np.ndarray) -> np.ndarray:
        """(2, M, 3[, n]) -> whitened (6M[, n])."""
        v6 = np.moveaxis(v, 0, 1).reshape(v.shape[1], 6, *v.shape[3:])
        return np.einsum("mij,mj...->mi...", self.linv, v6).reshape(-1, *v.shape[3:])

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f (2, M, 3) tracker frame, J (2, M, 3, n), x_s world (2, M, 3)) at x. The rotation
        columns are exact at w = 0 (first order in |w| elsewhere: the LM's convergence test is
        on the exact residual, and the covariance is taken at w = 0)."""
        rot = rotation_exp(x[:3]) @ self.rot0
        t, phi = x[3:6], x[6:]
        dp, jdp = self.fm.evaluate(to_theta(phi, self.layout))
        x0, j0 = self.fm.unloaded
        xs = np.stack([x0, x0 + dp])
        js = np.stack([j0, j0 + jdp]) @ dtheta_dphi(phi, self.layout)
        v = xs - t
        f = v @ rot
        jac = np.empty((*f.shape, self.n))
        jac[..., :3] = np.einsum("ji,smjk->smik", rot, _skews(v))
        jac[..., 3:6] = -rot.T
        jac[..., 6:] = np.einsum("ji,smjk->smik", rot, js)
        return f, jac, xs

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f, jac, _ = self.predict(x)
        return self._white(f), self._white(jac)


def geometry_variance(resid: np.ndarray, cov: np.ndarray) -> float:
    """The per-axis variance of the model's geometric misfit that residuals ``resid`` (2, M, 3:
    readings minus prediction, both states) show beyond the readings' own covariances ``cov``
    (2, M, 3, 3): from their common mode m = (r_0 + r_1) / 2, whose expected |m|^2 is
    tr(C_0 + C_1) / 4 + 3 g (a moment estimate, floored at 0)."""
    m = 0.5 * (resid[0] + resid[1])
    own = np.trace(cov[0] + cov[1], axis1=1, axis2=2) / 4
    return float(max(0.0, np.mean(np.sum(m * m, axis=1) - own) / 3))


def _skews(v: np.ndarray) -> np.ndarray:
    out = np.zeros((*v.shape, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def fit_tracker_pose(
    plan: Plan, model: Path, readings: ImportedReadings, table: ReadingsTable, tracker: TrackerSpec
) -> TrackerRegistration:
    """Register the tracker (module docstring); ``tracker`` gives the noise model."""
    robot = load_robot(plan.path, "robot", path=model)  # as the import loaded it
    names = list(robot.reflector_names)
    pts = point_data(plan, robot, readings, table, names, tracker)
    keys, uy, uc, ulines = pts.unloaded
    if not non_collinear(uy):
        raise InputError(
            table.path,
            "state",
            "unloaded readings of at least three reflector "
            "positions not on one line, to register the tracker",
            f"{len(uy)} points",
        )
    rigid = fit_rigid(uy, rigid_points(robot, plan, keys), uc)
    if rigid.rms > ABSURD_RMS:
        worst = int(np.argmax(np.linalg.norm(rigid.residual, axis=1)))
        raise InputError(
            table.path,
            f"line {ulines[worst]}",
            f"unloaded readings that match the plan's poses (registered rigidly, within "
            f"{ABSURD_RMS * 1e3:.0f} mm RMS; check the pose indices, the point names and "
            "--units)",
            f"{rigid.rms * 1e3:.0f} mm RMS, pose {keys[worst][0]} "
            f"{keys[worst][1]} {np.linalg.norm(rigid.residual[worst]) * 1e3:.0f} mm off",
        )
    if pts.obs is None or not non_collinear(pts.y[0]):
        reg = TrackerRegistration(
            rigid,
            1,
            True,
            "none (rigid kinematics)",
            None,
            (),
            warnings=[
                "no pose was measured in both states at three or more reflector "
                "positions, so the unloaded sag could not be estimated: the tracker is "
                "registered against rigid kinematics"
            ],
        )
        return _judged(reg)
    # the start: the rigid fit, and the one-step estimate from the deflections it rotates
    placed = tracker.placed(rigid.position, rigid.rotation)
    obs_world = Observations(
        [_rotated(p, rigid.rotation) for p in pts.obs.poses], placed, pts.obs.noise_sigma, pts.obs.n_planned
    )
    estimator = load_robot(plan.path, "robot", path=model)
    theta0 = one_step(estimator, obs_world).values
    lay = robot.layout
    theta0, _ = sanitize_start(theta0, generic_start(estimator, obs_world), lay)
    fm = ForwardModel(robot, design_from_observations(robot, pts.obs))
    names = POSE_NAMES + tuple(lay.names)
    rot, x = rigid.rotation, np.concatenate([np.zeros(3), rigid.position, to_phi(theta0, lay)])
    scale = np.concatenate([np.full(6, POSE_SCALE), np.abs(to_phi(theta0, lay))])
    noise_var = float(np.mean(np.trace(pts.cov, axis1=2, axis2=3))) / 3
    # start from the misfit at the start (rigid pose, deflections' estimate): an overestimate
    # (it holds the sag that the fit will remove), which lets the deflections lead the first fit
    f0, _, _ = JointModel(fm, pts, rot).predict(x)
    g2, evaluations = geometry_variance(pts.y - f0, pts.cov), 1
    for _ in range(GEOMETRY_ROUNDS):
        joint = JointModel(fm, pts, rot, g2)
        sol = levenberg_marquardt(
            joint.evaluate,
            joint.y_w,
            x,
            scale,
            valid=lambda z: valid_phi(z[6:]),
            free_fn=lambda jw: analyze(jw, names).identifiable,
            step_tol=1e-6,
            rank_tol=RANK_TOL,
            max_iter=40,
            max_damping=30,
            accept_within_sigma=True,
        )
        evaluations += sol.evaluations
        # re-centre the rotation (w = 0): its Jacobian columns are then exact for the covariance
        rot = rotation_exp(sol.x[:3]) @ rot
        joint.rot0 = rot
        x = np.concatenate([np.zeros(3), sol.x[3:]])
        f, jac, xs = joint.predict(x)
        evaluations += 1
        new = geometry_variance(pts.y - f, pts.cov)
        settled = abs(new - g2) <= 0.1 * new or max(new, g2) < 1e-2 * noise_var
        g2 = new
        if settled:
            break
    jw = joint._white(jac)
    r_w = joint.y_w - joint._white(f)
    misfit_chi2 = float(np.sum(JointModel(fm, pts, rot)._white(pts.y - f) ** 2))  # readings' errors only
    free = analyze(jw * scale, names).identifiable
    cov, rank = covariance(jw * scale, free, scale, RANK_TOL)
    resid = (xs - (pts.y @ rot.T + x[3:6])).reshape(-1, 3)  # predicted - registered, world
    expected = float(np.sqrt(noise_var))
    fit = RigidFit(
        rot,
        x[3:6].copy(),
        np.nan_to_num(cov[:6, :6]),
        resid,
        float(r_w @ r_w),
        resid.shape[0],
        expected,
        n_params=rank,
    )
    theta = to_theta(x[6:], lay)
    reg = TrackerRegistration(
        fit,
        evaluations,
        sol.converged and settled,
        "the exact statics (gravity and load) with the elastic parameters fitted jointly with the pose",
        theta,
        tuple(lay.names),
        geometry_rms=float(np.sqrt(g2)),
        misfit_chi2=misfit_chi2,
        warnings=[] if sol.converged else ["the joint registration did not converge"],
    )
    return _judged(reg)


def check_placed(
    plan: Plan, model: Path, readings: ImportedReadings, table: ReadingsTable, tracker: TrackerSpec
) -> float:
    """With the tracker where the plan puts it, the unloaded readings must be the plan's poses:
    InputError beyond ABSURD_RMS (a wrong yaw, position or unit, poses out of order), naming the
    worst row. Returns the RMS distance per axis to rigid kinematics (m: the sag, the geometry
    and the tracker pose's own error)."""
    robot = load_robot(plan.path, "robot", path=model)  # as the import loaded it
    names = list(robot.reflector_names)
    keys, uy, uc, ulines = point_data(plan, robot, readings, table, names, tracker).unloaded
    resid = rigid_points(robot, plan, keys) - (uy @ tracker_rotation(tracker).T + tracker.position)
    rms = float(np.sqrt(np.mean(resid**2))) if len(resid) else 0.0
    if rms > ABSURD_RMS:
        worst = int(np.argmax(np.linalg.norm(resid, axis=1)))
        raise InputError(
            table.path,
            f"line {ulines[worst]}",
            f"unloaded readings that match the plan's poses seen from its [tracker] "
            f"position and yaw (within {ABSURD_RMS * 1e3:.0f} mm RMS; check them, the pose "
            "indices, the point names and --units; without a position the tracker is "
            "registered)",
            f"{rms * 1e3:.0f} mm RMS, pose {keys[worst][0]} {keys[worst][1]} "
            f"{np.linalg.norm(resid[worst]) * 1e3:.0f} mm off",
        )
    return rms


def _rotated(p: PoseObservation, rot: np.ndarray) -> PoseObservation:
    """A pose's deflections expressed in the frame ``rot`` maps them to."""
    block = None if p.cov_block is None else np.einsum("ia,ranb,jb->rinj", rot, p.cov_block, rot)
    return replace(p, dp=p.dp @ rot.T, cov=rot @ p.cov @ rot.T, cov_block=block)


def _judged(reg: TrackerRegistration) -> TrackerRegistration:
    """Add the geometry warning the residual calls for (module docstring)."""
    fit = reg.fit
    chi2 = fit.chi2 if reg.misfit_chi2 is None else reg.misfit_chi2
    per_dof = chi2 / max(fit.dof, 1)
    if fit.dof > 0 and per_dof > 1 + GEOMETRY_CHI2 * np.sqrt(2 / fit.dof):
        model_rms = reg.geometry_rms or np.sqrt(max(fit.rms**2 - fit.expected_rms**2, 0.0))
        reg.warnings.append(
            f"registration residual {fit.rms * 1e6:.0f} um RMS per axis where the tracker alone "
            f"gives {fit.expected_rms * 1e6:.0f} um (chi2/dof {per_dof:.1f}): the nominal geometry "
            f"is off by ~{model_rms * 1e3:.2f} mm RMS per axis; deflections cancel that to first "
            "order (docs/shop-floor.md), the tracker's registered rotation does not (its "
            "uncertainty includes the misfit)"
        )
    return reg


__all__ = [
    "TrackerRegistration",
    "fit_tracker_pose",
    "check_placed",
    "point_data",
    "rigid_points",
    "JointModel",
    "ABSURD_RMS",
    "GEOMETRY_CHI2",
]
