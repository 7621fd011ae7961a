"""The robot importer family: what turns a robot file of another format into a calbench MJCF
(:class:`RobotImporter`), what it returns (:class:`Conversion`), and the registry of importers.

An importer says which files it accepts (:attr:`RobotImporter.suffixes`, the ends of their names)
and converts one, given the overlay of what the format cannot say (bench/robots/overlay.py: the
actuated joints, reflectors, payload, compensators, loops), into the MJCF text and a report.
``calbench from-urdf FILE --overlay O --out M`` hands FILE to the importer that accepts it
(:func:`import_robot`; a file no importer claims by its name goes to the URDF importer, as every
file did before there were importers). The URDF importer (bench/robots/urdf.py) is the one shipped; a module
listed in :data:`BUILTIN` is found on first use (its ``IMPORTER``), and
:func:`register_importer` adds one from outside (a test, a notebook).
"""

from __future__ import annotations

import importlib
import threading
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from .overlay import Overlay

BUILTIN = ("calbench.bench.robots.urdf",)  # modules whose IMPORTER is registered on first use
# a file no importer claims by its name is read as a URDF, the one format before there were
# importers (its errors say why a file is not one: "(root element): expected <robot>")
DEFAULT = "urdf"


@dataclass(frozen=True)
class Conversion:
    """What an importer made: the MJCF text, the warnings to show, and a summary (the actuated
    and passive joints, the mass of every body that moves in kg, the geoms and inlined meshes)."""

    xml: str
    warnings: tuple[str, ...]
    actuated: tuple[str, ...]
    passive: tuple[str, ...]
    moving_mass: float  # kg, every body that moves
    geoms: int
    meshes: int


class RobotImporter(ABC):
    """One robot file format: ``name`` (short, e.g. "urdf"), ``summary`` (one line for people)
    and ``suffixes``, the file name endings it accepts (lower case, e.g. ``(".urdf",)``)."""

    name: ClassVar[str]
    summary: ClassVar[str]
    suffixes: ClassVar[tuple[str, ...]]

    def accepts(self, path: Path) -> bool:
        """Does this importer read the file at ``path`` (by the end of its name)?"""
        return Path(path).name.lower().endswith(self.suffixes)

    @abstractmethod
    def convert(self, path: Path, overlay: Overlay) -> Conversion:
        """The checked calbench MJCF of the robot in ``path`` with ``overlay``; InputError naming
        the file and the element for what cannot be converted."""


_IMPORTERS: dict[str, RobotImporter] = {}
_LOADED = False
_LOCK = threading.Lock()


def robot_importers() -> dict[str, RobotImporter]:
    """Every importer by name: the built-in ones (loaded on first use), then those registered."""
    global _LOADED
    with _LOCK:
        if not _LOADED:
            builtin = [importlib.import_module(m).IMPORTER for m in BUILTIN]
            added = dict(_IMPORTERS)
            _IMPORTERS.clear()
            _IMPORTERS.update({imp.name: imp for imp in builtin})
            _IMPORTERS.update(added)
            _LOADED = True
        return dict(_IMPORTERS)


def register_importer(importer: RobotImporter) -> None:
    """Add an importer (ValueError when one of that name is registered)."""
    if importer.name in robot_importers():
        raise ValueError(f"a robot importer named {importer.name!r} is already registered")
    _IMPORTERS[importer.name] = importer


def unregister_importer(name: str) -> None:
    """Remove an importer registered at run time."""
    _IMPORTERS.pop(name, None)


def importer_for(path: str | Path) -> RobotImporter:
    """The importer that accepts ``path`` (the first registered, built-in ones first), else the
    :data:`DEFAULT` one."""
    importers = robot_importers()
    return next((imp for imp in importers.values() if imp.accepts(Path(path))), None) or importers[DEFAULT]


def import_robot(path: str | Path, overlay: Overlay) -> Conversion:
    """The calbench MJCF of the robot file ``path`` with ``overlay``, by the importer that
    accepts it (:func:`importer_for`)."""
    return importer_for(path).convert(Path(path), overlay)
