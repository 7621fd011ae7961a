"""The paper campaign in the world the linear model of eqs. (19)-(22) describes: gravity off,
the compensator off, the 700 kg payload replaced by the same force as an explicit wrench. Left
out of the linear model there is only the loads' own geometric stiffness (H00 of eq. 18 without
gravity: |W| x lever x k ~ 1e-4 of a deflection), so the paper's two-step method must be
unbiased here: a test that a broken two-step fails (tests/test_identify_plans.py,
tests/test_montecarlo.py)."""

from __future__ import annotations

import re
from pathlib import Path

from conftest import MJCF, PAPER

WEIGHT = 700.0 * 9.81  # N: the payload's weight under the MJCF's gravity, now a force


def linear_world(tmp: Path) -> Path:
    """The scenario file (and its gravity-free MJCF) in ``tmp``."""
    mjcf = tmp / "m900ib700_no_gravity.xml"
    text = MJCF.read_text()
    text, n = re.subn(r'gravity="0 0 -9.81"', 'gravity="0 0 0"', text)
    assert n == 1
    mjcf.write_text(text)
    scn = PAPER.read_text().replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{mjcf.as_posix()}"')
    scn = re.sub(
        r"(\[truth\.compensator\](?:(?!^\[).)*?^stiffness\s*=\s*)\S+",
        r"\g<1>0.0",
        scn,
        count=1,
        flags=re.MULTILINE | re.DOTALL,
    )
    head, *poses = scn.split("[[pose]]")
    poses = [
        p if "wrench" in p else p.replace("\n", f"\nwrench = [0.0, 0.0, {-WEIGHT}, 0.0, 0.0, 0.0]\n", 1)
        for p in poses
    ]
    out = tmp / "linear_world.toml"
    out.write_text(head + "".join("[[pose]]" + p for p in poses))
    return out
