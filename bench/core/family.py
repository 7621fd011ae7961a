"""A family of file formats with a registry: members by name, the one that reads a given file.

Robot importers (bench/robots/importer.py) and readings formats (bench/shopfloor/formats.py) are
both "something that accepts a kind of file": a :class:`FileFormat` names itself and the file name
endings it accepts, and a :class:`Family` holds the members, the built-in ones found on first use
(an attribute of each module listed, so that the family's module need not import its members) and
those registered at run time, and picks the member for a file.
"""

from __future__ import annotations

import importlib
import threading
from pathlib import Path
from typing import ClassVar, Generic, TypeVar


class FileFormat:
    """A member of a family of file formats: ``name`` (short, e.g. "urdf"), ``summary`` (one line
    for people) and ``suffixes``, the file name endings it accepts (lower case, e.g. ``(".urdf",)``;
    override :meth:`accepts` to look inside the file instead)."""

    name: ClassVar[str]
    summary: ClassVar[str]
    suffixes: ClassVar[tuple[str, ...]]

    def accepts(self, path: Path) -> bool:
        """Is the file at ``path`` one of this format's (by the end of its name)?"""
        return Path(path).name.lower().endswith(self.suffixes)


M = TypeVar("M", bound=FileFormat)


class Family(Generic[M]):
    """The members of one family by name: ``attribute`` of each module in ``builtin`` (imported
    on first use), then those registered at run time; a file no member accepts goes to
    ``default``."""

    def __init__(self, what: str, builtin: tuple[str, ...], attribute: str, default: str):
        self.what, self.builtin, self.attribute, self.default = what, builtin, attribute, default
        self._members: dict[str, M] = {}
        self._loaded = False
        self._lock = threading.Lock()

    def members(self) -> dict[str, M]:
        """Every member by name, the built-in ones first."""
        with self._lock:
            if not self._loaded:
                builtin = [getattr(importlib.import_module(m), self.attribute) for m in self.builtin]
                added = dict(self._members)
                self._members = {m.name: m for m in builtin} | added
                self._loaded = True
            return dict(self._members)

    def register(self, member: M) -> None:
        """Add a member (ValueError when one of that name is registered)."""
        if member.name in self.members():
            raise ValueError(f"a {self.what} named {member.name!r} is already registered")
        self._members[member.name] = member

    def unregister(self, name: str) -> None:
        """Remove a member registered at run time."""
        self._members.pop(name, None)

    def for_path(self, path: str | Path) -> M:
        """The member that accepts ``path`` (the first, built-in ones first), else the default."""
        members = self.members()
        return next((m for m in members.values() if m.accepts(Path(path))), None) or members[self.default]
