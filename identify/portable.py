"""A scenario that travels to a Dask worker: its TOML text and its robot's MJCF text.

Workers need only the installed package, never a checkout or the user's files, so a task
carries the texts (a few tens of kB) instead of paths. :meth:`PortableScenario.scenario`
rebuilds the validated :class:`bench.scenario.Scenario` on whatever machine it runs: the MJCF is
written under its own file name into a private temporary folder of the process (once per
process and robot, removed at exit) and the scenario's ``robot`` key points at it. The texts
are the identity: the same PortableScenario gives the same Scenario values everywhere.
"""
from __future__ import annotations

import atexit
import hashlib
import json
import re
import shutil
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path

from calbench.bench.outputs import write_text
from calbench.bench.scenario import Scenario, parse_scenario, scenario_to_toml

_ROBOT_LINE = re.compile(r"""^(\s*robot\s*=\s*)(?:"[^"\n]*"|'[^'\n]*')""", re.MULTILINE)
_DIRS: dict[str, Path] = {}


def with_robot(text: str, robot: str) -> str:
    """The scenario text with its top-level ``robot`` set to ``robot`` (comments kept)."""
    quoted = json.dumps(robot, ensure_ascii=False)      # a JSON string is a TOML basic string
    new, n = _ROBOT_LINE.subn(lambda m: m.group(1) + quoted, text, count=1)
    if n == 1 and tomllib.loads(new).get("robot") == robot:
        return new
    doc = tomllib.loads(text)           # an unusual spelling: rewrite the whole document
    doc["robot"] = robot
    return scenario_to_toml(doc)


def _workdir(digest: str) -> Path:
    d = _DIRS.get(digest)
    if d is None or not d.is_dir():
        d = Path(tempfile.mkdtemp(prefix="calbench-task-"))
        if not _DIRS:
            atexit.register(lambda: [shutil.rmtree(p, ignore_errors=True) for p in _DIRS.values()])
        _DIRS[digest] = d
    return d


@dataclass(frozen=True)
class PortableScenario:
    """Scenario text (its ``robot`` = ``robot_name``), MJCF text, and the names to show."""

    text: str
    mjcf: str
    robot_name: str           # the MJCF's file name, e.g. m900ib700.xml
    filename: str             # the scenario's file name, for messages and logs

    @classmethod
    def from_scenario(cls, scn: Scenario) -> "PortableScenario":
        robot = Path(scn.robot)
        return cls(with_robot(scn.text, robot.name), robot.read_text(encoding="utf-8"), robot.name,
                   Path(scn.path).name)

    @classmethod
    def from_doc(cls, doc: dict, mjcf: str, robot_name: str, filename: str) -> "PortableScenario":
        """From a scenario document (bench.scenario file units) and the MJCF text."""
        return cls(scenario_to_toml({**doc, "robot": robot_name}), mjcf, robot_name, filename)

    def robot_folder(self) -> Path:
        """This process's private folder holding the MJCF (one per robot text)."""
        h = hashlib.sha256(self.robot_name.encode("utf-8") + b"\0" + self.mjcf.encode("utf-8")).hexdigest()
        return _workdir(h)

    def scenario(self, seed: int | None = None) -> Scenario:
        """The validated scenario, its robot in this process's private folder (InputError as
        bench.scenario.parse_scenario)."""
        d = self.robot_folder()
        robot = d / self.robot_name
        if not robot.is_file():
            write_text(robot, self.mjcf)
        return parse_scenario(self.text, d / self.filename, seed)


__all__ = ["PortableScenario", "with_robot"]
