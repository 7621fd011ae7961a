"""`calbench compensate --rrd`: a Rerun recording of the job's path.

Drawn in the world frame, on a timeline ``point`` (one step per job point): the robot (the
identified model) at the compensated command under the job's load; the path of targets (a line
through every point's target); the loaded tool uncompensated (at the nominal command) and
compensated, each as target + magnify x (tool - target), so that micrometres show beside the
metre-long robot; the current point's two errors as arrows. With ``--truth`` the tool positions
are the TRUE robot's and the targets its own (the numbers of the JSON's true_error_* fields);
without, the identified model's (its compensated tool is on target to 1e-8 m).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calbench.bench.core import atomic_path
from calbench.bench.model import geom_shapes
from calbench.bench.view import DEFAULT_MAGNIFY, geom_archetype

from .run import Compensation
from .solve import Compensator
from .toolpoint import tool_pose, with_tool
from .truth import TruthBench, true_robot

TARGET = (40, 120, 255)
BEFORE = (230, 60, 40)
AFTER = (40, 190, 80)
MAX_ROBOT_POSES = 500  # a long job draws the robot at every k-th point only


def path_positions(res: Compensation) -> dict[str, np.ndarray]:
    """(n, 3) world positions: ``target``, ``before`` (loaded, nominal command), ``after``
    (loaded, compensated command; NaN where not reached), from the truth when the compensation
    was applied to one, else from the identified model; and the model's loaded ``qpos`` at each
    command (n, nq)."""
    comp = Compensator(
        with_tool(res.robot, res.job.tool),
        res.identified.params(res.robot),
        res.identified.covariance,
        res.target,
    )
    bench = None
    if res.scenario is not None:
        bench = TruthBench(true_robot(res.scenario, res.job, res.robot), res.target)
    n = len(res.points)
    out = {k: np.full((n, 3), np.nan) for k in ("target", "before", "after")}
    out["qpos"] = np.full((n, comp.robot.model.nq), np.nan)
    for i, (pt, r) in enumerate(zip(res.job.points, res.points)):
        q = np.asarray(pt.q)
        if bench is not None:
            load = bench.load(pt)
            out["target"][i] = bench.target(q)[0]
            out["before"][i] = bench.pose(q, load)[0]
            if r.converged:
                out["after"][i] = bench.pose(r.command, load)[0]
        else:
            out["target"][i] = r.target_position
            load = comp.load(pt)
            out["before"][i] = tool_pose(comp.robot, comp.site, comp.equilibrium(q, load).qpos)[0]
        if r.converged:
            eq = comp.equilibrium(r.command, comp.load(pt))
            out["qpos"][i] = eq.qpos
            if bench is None:
                out["after"][i] = tool_pose(comp.robot, comp.site, eq.qpos)[0]
    return out


def write_path_recording(res: Compensation, rrd: str | Path, magnify: float = DEFAULT_MAGNIFY) -> Path:
    """Write the recording (atomically: a complete file or none)."""
    import mujoco
    import rerun as rr

    pos = path_positions(res)
    model = res.robot.model
    data = mujoco.MjData(model)
    bodies = [model.body(b).name for b in range(model.nbody)]
    shapes = geom_shapes(model)
    tgt = pos["target"]
    before = tgt + magnify * (pos["before"] - tgt)
    after = tgt + magnify * (pos["after"] - tgt)
    stride = max(1, len(res.points) // MAX_ROBOT_POSES)
    src = "truth" if res.scenario is not None else "model"
    rrd = Path(rrd)
    with atomic_path(rrd) as tmp:
        rec = rr.RecordingStream("calbench")
        rec.send_recording_name(f"compensation {res.job.path.name}")
        rec.save(tmp)
        try:
            rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
            for shape in shapes:
                arch = geom_archetype(rr, shape)
                if arch is not None:
                    rec.log(
                        f"robot/{bodies[shape.body] if shape.body else 'world'}/"
                        + rr.escape_entity_path_part(shape.name or str(shape.geom)),
                        arch,
                        static=True,
                    )
            rec.log("path/target", rr.LineStrips3D([tgt], radii=[0.004], colors=[TARGET]), static=True)
            rec.log(
                f"path/{src}_uncompensated_x{magnify:g}",
                rr.LineStrips3D([before], radii=[0.004], colors=[BEFORE]),
                static=True,
            )
            ok = np.all(np.isfinite(after), axis=1)
            rec.log(
                f"path/{src}_compensated_x{magnify:g}",
                rr.Points3D(after[ok], radii=[0.006], colors=[AFTER]),
                static=True,
            )
            for i, r in enumerate(res.points):
                rec.set_time("point", sequence=i)
                vecs = [before[i] - tgt[i]] + ([after[i] - tgt[i]] if ok[i] else [])
                rec.log(
                    "path/current",
                    rr.Arrows3D(
                        origins=[tgt[i]] * len(vecs),
                        vectors=vecs,
                        colors=[BEFORE, AFTER][: len(vecs)],
                        radii=[0.005],
                    ),
                )
                if i % stride == 0 and np.all(np.isfinite(pos["qpos"][i])):
                    data.qpos[:] = pos["qpos"][i]
                    mujoco.mj_kinematics(model, data)
                    for b in range(1, model.nbody):
                        rec.log(
                            f"robot/{bodies[b]}",
                            rr.Transform3D(
                                translation=data.xpos[b],
                                quaternion=rr.Quaternion(xyzw=np.roll(data.xquat[b], -1)),
                            ),
                        )
                state = "not reached: " + (r.reason or "") if not r.converged else "compensated"
                rec.log("path/status", rr.TextDocument(f"point {i}: {state}"))
        finally:
            rec.flush()
            rec.disconnect()
    return rrd


__all__ = ["path_positions", "write_path_recording"]
