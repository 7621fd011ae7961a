"""Loading the robot a file names: the one loader, and its one error text.

A robot comes from an MJCF file that some key of some input names (a scenario's, a plan's or a
job's ``robot``, the command line's ``--model``) or from the MJCF text a campaign log carries.
:func:`load_robot` loads either, and every way it can fail is one InputError naming the input
and the key that named the robot (docs/contract.md's ``FILE: KEY: expected ..., got ...``): no
such file, no MJCF in the log, XML that is unsafe (bench/core/xmlsafe.py, its own key), or an
MJCF that MuJoCo cannot compile or that does not describe a calbench robot.
"""

from __future__ import annotations

from pathlib import Path

from calbench.bench.core import InputError

from .robot import Robot

EXPECTED = "a loadable MJCF of a calbench robot"
LOG_KEY = "robot MJCF attachment"  # the key a log's robot is named by
MODEL_FLAG = ("--model", "model")  # (where, key) of the command line's --model


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def load_robot(where: object, key: str, path: str | Path | None = None, text: str | None = None) -> Robot:
    """The robot of the MJCF file ``path``, or of the MJCF ``text`` a log carries, that ``key``
    of ``where`` names (module docstring): e.g. ``(scenario.path, "robot", path=scenario.robot)``,
    ``(*MODEL_FLAG, path=args.model)``, ``(log.path, LOG_KEY, text=log.mjcf_text)``.
    InputError(where, key, ...) on any failure."""
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise InputError(where, key, "an existing MJCF file", str(path))
        try:
            return Robot.from_file(path)
        except ValueError as exc:  # MuJoCo compile errors, the robot description
            raise InputError(where, key, EXPECTED, f"{path}: {_one_line(exc)}") from None
    if not text:
        raise InputError(where, key, "the robot's MJCF carried in the log (or --model ROBOT.xml)", "none")
    try:
        return Robot.from_xml(text, where=f"{where} ({key})")
    except ValueError as exc:
        hint = ""
        if "calbench:" in str(exc) and "calbench:" not in text:
            # a log written before robots described themselves in their MJCF (docs/contract.md,
            # "Robot description"): its geometry is fine, the description lives in the MJCF now
            hint = (
                "; this log predates the robot description in the MJCF: pass --model with the "
                "robot's described MJCF (for the shipped FANUC: mjcf/m900ib700.xml)"
            )
        raise InputError(where, key, EXPECTED, _one_line(exc) + hint) from None


def log_robot(log, model: str | Path | None = None) -> Robot:
    """The robot of a campaign log (a bench.log.CampaignLog: its ``path`` and the MJCF text it
    carries), or the MJCF file ``model`` the command line's --model gives instead: what every
    reader of a log (identify, discover, view, report) loads. :func:`load_robot`'s errors."""
    if model is not None:
        return load_robot(*MODEL_FLAG, path=model)
    return load_robot(log.path, LOG_KEY, text=log.mjcf_text)


__all__ = ["LOG_KEY", "MODEL_FLAG", "load_robot", "log_robot"]
