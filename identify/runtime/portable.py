"""A scenario that travels to a Dask worker: its TOML text and its robot's MJCF text.

Workers need only the installed package, never a checkout or the user's files, so a task
carries the texts (a few tens of kB) instead of paths. :meth:`PortableScenario.scenario`
rebuilds the validated :class:`bench.scenario.Scenario` on whatever machine it runs: the MJCF is
written under its own file name into a folder named by the hash of its text, in the user's
private cache ``$TMPDIR/calbench-<uid>/`` (mode 0700; written atomically, shared by every process
of the user, one file per distinct robot, so even killed workers leave nothing that grows), and
the scenario's ``robot`` key points at it; its ``path``, which messages name, is the user's file.
The texts are the identity: the same
PortableScenario gives the same Scenario values everywhere.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import stat
import tempfile
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from calbench.bench.core import write_text
from calbench.bench.scenario import Scenario, parse_scenario, scenario_to_toml

_ROBOT_LINE = re.compile(r"""^(\s*robot\s*=\s*)(?:"[^"\n]*"|'[^'\n]*')""", re.MULTILINE)


def with_robot(text: str, robot: str) -> str:
    """The scenario text with its top-level ``robot`` set to ``robot`` (comments kept)."""
    quoted = json.dumps(robot, ensure_ascii=False)  # a JSON string is a TOML basic string
    new, n = _ROBOT_LINE.subn(lambda m: m.group(1) + quoted, text, count=1)
    if n == 1 and tomllib.loads(new).get("robot") == robot:
        return new
    doc = tomllib.loads(text)  # an unusual spelling: rewrite the whole document
    doc["robot"] = robot
    return scenario_to_toml(doc)


@functools.lru_cache(maxsize=1)
def _cache() -> Path:
    """The user's private folder for robot texts (a fresh one if the shared name is not ours)."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    base = Path(tempfile.gettempdir()) / f"calbench-{uid}"
    try:
        base.mkdir(mode=0o700, exist_ok=True)
        st = base.lstat()
        if stat.S_ISDIR(st.st_mode) and (not hasattr(os, "getuid") or st.st_uid == uid):
            return base
    except OSError:
        pass
    return Path(tempfile.mkdtemp(prefix="calbench-"))


@dataclass(frozen=True)
class PortableScenario:
    """Scenario text (its ``robot`` = ``robot_name``), MJCF text, and the names to show."""

    text: str
    mjcf: str
    robot_name: str  # the MJCF's file name, e.g. m900ib700.xml
    filename: str  # the scenario's file name, for messages and logs
    # where the user's file is, for messages: a slipped unit found on a worker names the user's
    # file, not this process's copy (not part of the identity)
    source: str = field(default="", compare=False)

    @classmethod
    def from_scenario(cls, scn: Scenario) -> PortableScenario:
        robot = Path(scn.robot)
        return cls(
            with_robot(scn.text, robot.name),
            robot.read_text(encoding="utf-8"),
            robot.name,
            Path(scn.path).name,
            str(scn.path),
        )

    @classmethod
    def from_doc(cls, doc: dict, mjcf: str, robot_name: str, filename: str) -> PortableScenario:
        """From a scenario document (bench.scenario file units) and the MJCF text."""
        return cls(scenario_to_toml({**doc, "robot": robot_name}), mjcf, robot_name, filename)

    def robot_folder(self) -> Path:
        """The folder holding this MJCF text under its name (one per robot text)."""
        h = hashlib.sha256(self.robot_name.encode("utf-8") + b"\0" + self.mjcf.encode("utf-8")).hexdigest()
        d = _cache() / h[:32]
        d.mkdir(exist_ok=True)
        return d

    def scenario(self, seed: int | None = None) -> Scenario:
        """The validated scenario, its robot in this process's private folder (InputError as
        bench.scenario.parse_scenario)."""
        d = self.robot_folder()
        robot = d / self.robot_name
        if not robot.is_file() or robot.read_text(encoding="utf-8") != self.mjcf:
            write_text(robot, self.mjcf)
        scn = parse_scenario(self.text, d / self.filename, seed)
        return replace(scn, path=Path(self.source)) if self.source else scn


__all__ = ["PortableScenario", "with_robot"]
