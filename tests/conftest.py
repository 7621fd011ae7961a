"""Shared test constants and helpers.

The tests folder is put on sys.path so that tests can import these constants
(``from conftest import PAPER, MJCF, K_TRUE``) and the small helpers beside them
(tests/rerun_cli.py).
"""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"  # Table 5 + four lateral pulls, 700 kg
MJCF = ROOT / "mjcf" / "m900ib700.xml"
# the default truth of the shipped scenarios (docs/model.md, "Default truth values"), rad/(N*m)
K_TRUE = np.array([0.25, 0.12, 0.07, 0.35, 0.40, 0.60]) * 1e-6
# the paper's Table 5 (q1..q6, degrees, the controller's convention: q3 = crank), in rad
TABLE5 = np.radians(
    [
        [0, 0, -30, -45, 30, 135],
        [0, 0, -30, 45, -30, 35],
        [90, 0, 30, -45, -30, -45],
        [90, 0, 30, 45, -30, 45],
        [180, 35, -30, 135, -30, -45],
        [-180, 35, -30, -45, 30, 135],
        [-90, 35, 30, 135, 30, 135],
        [-90, 35, 30, -45, -30, -45],
        [0, 120, -30, -135, 30, -135],
        [0, 120, -30, 135, -30, -45],
        [180, 120, 30, -135, 30, -135],
        [-180, 120, 30, 135, 30, 135],
    ]
)


def fanuc_params(compliance, stiffness: float, preload: float):
    """Params of the FANUC model (its one compensator tendon, named "compensator")."""
    from calbench.bench.model import Params, Spring

    return Params(
        np.asarray(compliance, dtype=float), {"compensator": Spring(float(stiffness), float(preload))}
    )


def fanuc_truth(scn):
    """The scenario's truth as Params of the FANUC model (bench.campaign.truth_params)."""
    from calbench.bench.campaign import truth_params
    from calbench.bench.model import Robot

    return truth_params(scn, Robot.from_file(MJCF))


# -- MuJoCo's warnings ------------------------------------------------------------------------
# MuJoCo warns (and, left to itself, writes MUJOCO_LOG.TXT into the working folder) when it is
# handed an unstable state. calbench never should hand it one: the whole suite runs with a
# recording handler, and a test during which MuJoCo warned fails (bench/statics/equilibrium.py: MJ_MAXVAL).
MUJOCO_WARNINGS: list[str] = []


def wait_for_lock(out: Path, proc: subprocess.Popen, seconds: float = 60.0) -> None:
    """Wait until the calbench run ``proc`` holds the lock of its output ``out`` (the lock file
    ``.NAME.lock`` beside it names the run's PID: bench/core/outputs.py); kill it and fail when
    it has not within ``seconds``."""
    lock = out.with_name(f".{out.name}.lock")
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if lock.exists() and lock.read_text().strip() == str(proc.pid):
            return
        time.sleep(0.05)
    proc.kill()
    pytest.fail(f"the first run never took its lock {lock.name}")

    import mujoco

    mujoco.set_mju_user_warning(MUJOCO_WARNINGS.append)


import pytest  # noqa: E402


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    MUJOCO_WARNINGS.clear()


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item):
    if MUJOCO_WARNINGS:
        said = sorted(set(MUJOCO_WARNINGS))
        MUJOCO_WARNINGS.clear()
        raise AssertionError(f"MuJoCo warned during {item.nodeid}: {said}")
