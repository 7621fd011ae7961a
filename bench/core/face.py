"""A room's public face, loaded on first use: the names its ``__init__.pyi`` imports.

Every room (a subpackage of ``bench/`` or ``identify/``) declares what code outside it may use
in one stub, ``__init__.pyi``: plain ``from .module import Name`` lines and ``__all__``. Type
checkers and editors read the stub; at run time :func:`lazy_face` reads the same lines and
imports a name's module only when the name is first asked for (PEP 562), so that importing one
small module of a room never pays for the whole room (discovery alone takes ~0.9 s to import,
and a study's worker must not pay it for an identify-only campaign). The stub is the only list:
nothing is written twice.
"""

from __future__ import annotations

import ast
import importlib
import sys
from collections.abc import Callable
from pathlib import Path


def face_exports(stub: Path) -> dict[str, tuple[str, str]]:
    """Public name -> (relative module, attribute) from a face stub's ``from . import`` lines."""
    where: dict[str, tuple[str, str]] = {}
    for node in ast.parse(stub.read_text(encoding="utf-8"), str(stub)).body:
        if isinstance(node, ast.ImportFrom):
            module = "." * node.level + (node.module or "")
            for alias in node.names:
                where[alias.asname or alias.name] = (module, alias.name)
    return where


def lazy_face(
    package: str, init_file: str
) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``__getattr__``, ``__dir__`` and ``__all__`` of the package ``package`` whose
    ``__init__.py`` is ``init_file``, from the ``__init__.pyi`` beside it."""
    where = face_exports(Path(init_file).with_suffix(".pyi"))

    def __getattr__(name: str) -> object:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, attr = where[name]
        value = getattr(importlib.import_module(module, package), attr)
        setattr(sys.modules[package], name, value)  # the next lookup is a plain attribute
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return __getattr__, __dir__, sorted(where)
