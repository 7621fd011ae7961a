"""The robot importer family: what turns a robot file of another format into a calbench MJCF
(:class:`RobotImporter`), what it returns (:class:`Conversion`), and the registry of importers.

An importer says which files it accepts (:attr:`RobotImporter.suffixes`, the ends of their names)
and converts one, given the overlay of what the format cannot say (bench/robots/overlay.py: the
actuated joints, reflectors, payload, compensators, loops), into the MJCF text and a report.
``calbench from-urdf FILE --overlay O --out M`` hands FILE to the importer that accepts it
(:func:`import_robot`; a file no importer claims by its name goes to the URDF importer, as every
file did before there were importers). The URDF importer (bench/robots/urdf.py) is the one shipped; a module
listed in :data:`BUILTIN` is found on first use (its ``IMPORTER``), and
:data:`IMPORTERS`'s ``register`` adds one from outside (a test, a notebook).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path

from calbench.bench.core import Family, FileFormat

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
    notes: tuple[str, ...] = ()  # what was derived (a balancer cylinder's spring, a loop)
    assumed: tuple[str, ...] = ()  # links whose masses are ASSUMED (the overlay's [inertials])


class RobotImporter(FileFormat, ABC):
    """One robot file format (its ``name``, ``summary`` and ``suffixes``: FileFormat)."""

    @abstractmethod
    def convert(self, path: Path, overlay: Overlay) -> Conversion:
        """The checked calbench MJCF of the robot in ``path`` with ``overlay``; InputError naming
        the file and the element for what cannot be converted."""


# the importers by name (IMPORTERS.members(), .register(...), .unregister(name), .for_path(path))
IMPORTERS: Family[RobotImporter] = Family("robot importer", BUILTIN, "IMPORTER", DEFAULT)


def import_robot(path: str | Path, overlay: Overlay) -> Conversion:
    """The calbench MJCF of the robot file ``path`` with ``overlay``, by the importer that
    accepts it (``IMPORTERS.for_path``; a file none accepts goes to the :data:`DEFAULT` one)."""
    return IMPORTERS.for_path(path).convert(Path(path), overlay)
