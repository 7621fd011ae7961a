"""One TOML table checked key by key: the one validator of every file a person writes.

Scenarios, robot overlays, study files and design settings are all TOML tables read through
:class:`Table`, so that every mistake gets the same message: the file, the full key path
(``truth.effects.link_compliance.compliance[1]``), what was expected and what was found, as an
:class:`~calbench.bench.core.errors.InputError` (exit status 2, no traceback). :func:`parse_toml`
turns a syntax error into the line it is on; :func:`read_text` an unreadable file into its name.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError


class Table:
    """Typed access to one TOML table, raising InputError with the full key path."""

    def __init__(self, file: Path, table: Any, prefix: str):
        self.file = file
        self.prefix = prefix
        if not isinstance(table, dict):
            raise InputError(file, prefix or "(top level)", "a table", describe(table))
        self.table = table

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def fail(self, name: str, expected: str, got: Any = None) -> InputError:
        return InputError(self.file, self.key(name), expected, got)

    def only(self, allowed: tuple[str, ...]) -> None:
        """Reject keys outside ``allowed`` (catches typos that would silently do nothing)."""
        for name in self.table:
            if name not in allowed:
                raise self.fail(name, "no such key; allowed keys here: " + ", ".join(allowed))

    def has(self, name: str) -> bool:
        return name in self.table

    def raw(self, name: str) -> Any:
        if name not in self.table:
            raise InputError(self.file, self.key(name), "this required key to be present")
        return self.table[name]

    def sub(self, name: str) -> Table:
        value = self.raw(name)
        if not isinstance(value, dict):
            raise self.fail(name, "a table", describe(value))
        return Table(self.file, value, self.key(name))

    def number(self, name: str, *, positive: bool = False, nonneg: bool = False) -> float:
        return number(self.file, self.key(name), self.raw(name), positive, nonneg)

    def integer(self, name: str, lo: int | None = None, hi: int | None = None) -> int:
        value = self.raw(name)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(name, _int_range(lo, hi), describe(value))
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise self.fail(name, _int_range(lo, hi), value)
        return value

    def string(self, name: str, choices: tuple[str, ...] | None = None) -> str:
        value = self.raw(name)
        if not isinstance(value, str):
            raise self.fail(name, "a string", describe(value))
        if choices is not None and value not in choices:
            raise self.fail(name, "one of " + ", ".join(f'"{c}"' for c in choices), value)
        return value

    def vector(self, name: str, n: int | None, *, positive: bool = False, nonneg: bool = False) -> np.ndarray:
        """An array of n numbers (n None: any number >= 1)."""
        value = self.raw(name)
        what = f"an array of {n} numbers" if n is not None else "a non-empty array of numbers"
        if not isinstance(value, list):
            raise self.fail(name, what, describe(value))
        if (n is not None and len(value) != n) or not value:
            raise self.fail(name, what, f"{len(value)} elements")
        key = self.key(name)
        return np.array([number(self.file, f"{key}[{i}]", v, positive, nonneg) for i, v in enumerate(value)])


def describe(value: Any) -> str:
    """Short name of a TOML value's type for error messages."""
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    return f"{type(value).__name__} {value!r}"


def _int_range(lo: int | None, hi: int | None) -> str:
    if lo is not None and hi is not None:
        return f"an integer in {lo}..{hi}"
    if lo is not None:
        return f"an integer >= {lo}"
    return "an integer"


def number(file: Path, key: str, value: Any, positive: bool, nonneg: bool) -> float:
    """A finite real number (bool rejected), optionally > 0 or >= 0."""
    what = "a finite number" + (" > 0" if positive else " >= 0" if nonneg else "")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(file, key, what, describe(value))
    x = float(value)
    if not math.isfinite(x) or (positive and x <= 0) or (nonneg and x < 0):
        raise InputError(file, key, what, value)
    return x


def frozen_array(a: Any) -> np.ndarray:
    """A float copy that cannot be modified (of a value read from a table, say), so that frozen
    dataclasses holding it stay frozen."""
    arr = np.array(a, dtype=float)
    arr.setflags(write=False)
    return arr


_LINE = re.compile(r"line (\d+)")


def parse_toml(text: str, path: Path) -> Table:
    """A TOML document as a checked top-level table (syntax errors name the line)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = _LINE.search(str(exc))
        raise InputError(path, f"line {m.group(1)}" if m else "(syntax)", "valid TOML", str(exc)) from None
    return Table(path, doc, "")


def read_text(path: Path, what: str) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, "(file)", f"a readable UTF-8 {what} file", str(exc)) from None
