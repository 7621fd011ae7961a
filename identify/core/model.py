"""The robot model identification and discovery fit: the user's MJCF (``--model``) or the one
the log carries, checked to name every site the observations use. Geometry only: every
elastic value in it is overwritten by the estimator's own parameters."""

from __future__ import annotations

from pathlib import Path

import mujoco

from calbench.bench.core import InputError
from calbench.bench.model import Robot

from .observations import Observations


def load_model(log, model: str | Path | None) -> Robot:
    """The robot for identification: --model, else the MJCF carried by the log."""
    try:
        if model is not None:
            path = Path(model)
            if not path.is_file():
                raise InputError(path, "--model", "an existing MJCF file", "no such file")
            return Robot.from_file(path)
        if not log.mjcf_text:
            raise InputError(
                log.path, "robot model", "an MJCF attachment in the log (or --model ROBOT.xml)", "none"
            )
        return Robot.from_xml(log.mjcf_text)
    except ValueError as exc:  # MuJoCo compile errors, missing named joints
        where = str(model) if model is not None else f"{log.path} (MJCF attachment)"
        hint = ""
        if model is None and "calbench:" in str(exc) and "calbench:" not in (log.mjcf_text or ""):
            # a log written before robots described themselves in their MJCF (docs/contract.md,
            # "Robot description"): its geometry is fine, the description lives in the MJCF now
            hint = (
                "; this log predates the robot description in the MJCF: pass --model with the "
                "robot's described MJCF (for the shipped FANUC: mjcf/m900ib700.xml)"
            )
        raise InputError(
            where, "robot model", "a loadable MJCF of the calbench robot", str(exc) + hint
        ) from None


def check_sites(robot: Robot, obs: Observations, where) -> None:
    for p in obs.poses:
        for name in (p.site, *p.reflectors):
            if mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, name) < 0:
                raise InputError(where, f"site {name!r}", "a site of this name in the robot model", "none")


__all__ = ["load_model", "check_sites"]
