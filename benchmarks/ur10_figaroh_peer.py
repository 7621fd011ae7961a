"""FIGAROH's geometric calibration on the split ur10_real_bench.py exports (docs/geometry.md).

Run with a Python that has FIGAROH (``pip install figaroh``, which brings pinocchio); it does not
import calbench. Input: the .npz that ``ur10_real_bench.py --figaroh PYTHON`` writes (the UR10's
frames and masses, the fitted and the held-out joint angles and probe positions, the probe's
nominal point). It writes a URDF of the same nominal UR10, FIGAROH's unified YAML configuration and
its CSV layout next to the .npz, calibrates as FIGAROH's users do (a BaseCalibration whose cost is
the position residual of calc_updated_fkm; the base frame estimated by FIGAROH itself), for its
``full_params`` and ``joint_offset`` models, with and without its joint elasticity
(``include_non_geometric``), and prints JSON: held-out mean/RMS/max (mm) and time per model.

Usage: PYTHON benchmarks/ur10_figaroh_peer.py SPLIT.npz
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np


def rpy(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw (R = Rz(yaw) Ry(pitch) Rx(roll)) of a rotation matrix."""
    pitch = np.arcsin(-np.clip(r[2, 0], -1, 1))
    return float(np.arctan2(r[2, 1], r[2, 2])), float(pitch), float(np.arctan2(r[1, 0], r[0, 0]))


def urdf(frames, joints, mass, com) -> str:
    links = ["base_link"] + [f"link{k + 1}" for k in range(len(joints))] + ["flange"]
    out = ['<robot name="ur10">', '  <link name="base_link"/>']
    for k, name in enumerate(joints):
        f = frames[k]
        out.append(
            f'  <link name="{links[k + 1]}"><inertial><origin xyz="{" ".join(map(str, com[k]))}"/>'
            f'<mass value="{max(mass[k], 1e-6)}"/><inertia ixx="1e-3" iyy="1e-3" izz="1e-3" ixy="0" ixz="0" iyz="0"/>'
            "</inertial></link>"
        )
        out.append(
            f'  <joint name="{name}" type="revolute"><parent link="{links[k]}"/><child link="{links[k + 1]}"/>'
            f'<origin xyz="{" ".join(map(str, f[:3, 3]))}" rpy="{" ".join(map(str, rpy(f[:3, :3])))}"/>'
            '<axis xyz="0 0 1"/><limit lower="-6.2832" upper="6.2832" effort="330" velocity="3.2"/></joint>'
        )
    f = frames[-1]
    out.append('  <link name="flange"/>')
    out.append(
        f'  <joint name="flange_joint" type="fixed"><parent link="{links[len(joints)]}"/><child link="flange"/>'
        f'<origin xyz="{" ".join(map(str, f[:3, 3]))}" rpy="{" ".join(map(str, rpy(f[:3, :3])))}"/></joint>'
    )
    out.append("</robot>")
    return "\n".join(out)


CONFIG = """robot:
  name: "ur10"
  properties:
    joints:
      active_joints: [{joints}]
tasks:
  calibration:
    enabled: true
    type: kinematic_calibration
    parameters:
      calibration_level: "{level}"
      include_non_geometric: {non_geom}
      outlier_threshold: 0.05
    kinematics:
      base_frame: "universe"
      tool_frame: "flange"
    measurements:
      markers:
        - name: "tmac"
          reference_joint: "{last}"
          measurable_dof: [true, true, true, false, false, false]
      poses:
        base_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        tool_pose: [{tool}, 0.0, 0.0, 0.0]
    data:
      source_file: "{csv}"
      number_of_samples: {n}
environment:
  gravity: [0, 0, -9.81]
"""


def main() -> None:
    split = Path(sys.argv[1])
    z = np.load(split)
    work = split.parent
    joints = [str(j) for j in z["joints"]]
    (work / "ur10_figaroh.urdf").write_text(urdf(z["frames"], joints, z["mass"], z["com"]))
    header = "x1,y1,z1," + ",".join(joints)
    np.savetxt(
        work / "fit.csv", np.hstack([z["y_fit"], z["q_fit"]]), delimiter=",", header=header, comments=""
    )

    from figaroh.calibration.base_calibration import BaseCalibration
    from figaroh.calibration.calibration_tools import calc_updated_fkm
    from figaroh.tools.robot import load_robot

    class UR10Probe(BaseCalibration):
        def cost_function(self, var):
            return self.PEE_measured - calc_updated_fkm(
                self.model, self.data, var, self.q_measured, self.calib_config
            )

    robot = load_robot(str(work / "ur10_figaroh.urdf"), load_by_urdf=True)
    results = {}
    for level, non_geom in (("joint_offset", "false"), ("full_params", "false"), ("full_params", "true")):
        cfg = work / f"config_{level}_{non_geom}.yaml"
        cfg.write_text(
            CONFIG.format(
                joints=", ".join(f'"{j}"' for j in joints), level=level, non_geom=non_geom, last=joints[-1],
                tool=", ".join(map(str, z["tool"])), csv=str(work / "fit.csv"), n=len(z["q_fit"]),
            )
        )  # fmt: skip
        name = f"figaroh {level}" + (" + elasticity" if non_geom == "true" else "")
        try:
            with warnings.catch_warnings(), contextlib.redirect_stdout(sys.stderr):  # its report: stderr
                warnings.simplefilter("ignore")
                cal = UR10Probe(robot, str(cfg))
                # the tracker's pose and the probe's point are unknown: FIGAROH estimates both
                cal.calib_config.update(known_baseframe=False, known_tipframe=False)
                t0 = time.perf_counter()
                cal.initialize()
                cal.solve(enable_logging=False)
                seconds = time.perf_counter() - t0
            conf = dict(cal.calib_config, NbSample=len(z["q_val"]))
            pred = calc_updated_fkm(cal.model, cal.data, cal.var_, z["q_val"], conf).reshape(3, -1).T
            d = np.linalg.norm(pred - z["y_val"], axis=1) * 1e3
            results[name] = {
                "mean_mm": float(d.mean()),
                "rms_mm": float(np.sqrt(np.mean(d**2))),
                "max_mm": float(d.max()),
                "parameters": len(cal.var_),
                "seconds": seconds,
            }
        except Exception as e:  # a peer that fails is reported, not hidden
            results[name] = {"failed": f"{type(e).__name__}: {e}"[:300]}
    print(json.dumps(results))


if __name__ == "__main__":
    main()
