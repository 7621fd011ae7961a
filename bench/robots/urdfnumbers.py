"""The numbers of a URDF, checked where its text is first parsed: every attribute the URDF format
defines as numbers (an origin's xyz and rpy, an axis, limits, masses, inertias, geometry sizes,
mimic factors, dynamics) must be that many finite numbers, sizes and masses not negative and an
axis not zero. A URDF is a stranger's file: without this a ``xyz="1 2"`` or ``value="nan"``
surfaced as a traceback in whatever read it first, or reached MuJoCo as a NaN.

Each refusal is an InputError naming the file, the element with its link or joint, and the
attribute (exit 2).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from calbench.bench.core import InputError

# element -> attribute -> (how many numbers, what they must be: "any", "positive" (> 0),
# "nonnegative" (>= 0), "nonzero" (not all zero))
NUMBERS: dict[str, dict[str, tuple[int, str]]] = {
    "origin": {"xyz": (3, "any"), "rpy": (3, "any")},
    "axis": {"xyz": (3, "nonzero")},
    "limit": {
        "lower": (1, "any"),
        "upper": (1, "any"),
        "effort": (1, "nonnegative"),
        "velocity": (1, "nonnegative"),
    },
    "mimic": {"multiplier": (1, "any"), "offset": (1, "any")},
    "dynamics": {"damping": (1, "nonnegative"), "friction": (1, "nonnegative")},
    "safety_controller": {
        "soft_lower_limit": (1, "any"),
        "soft_upper_limit": (1, "any"),
        "k_position": (1, "any"),
        "k_velocity": (1, "any"),
    },
    "mass": {"value": (1, "nonnegative")},
    "inertia": {k: (1, "any") for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")},
    "box": {"size": (3, "positive")},
    "cylinder": {"radius": (1, "positive"), "length": (1, "positive")},
    "sphere": {"radius": (1, "positive")},
    "mesh": {"scale": (3, "positive")},
}
WORDS = {
    "any": "finite",
    "positive": "finite positive",
    "nonnegative": "finite non-negative",
    "nonzero": "finite, not all zero,",
}


def _owner(parents: list[ET.Element]) -> str:
    """The nearest <link> or <joint> around an element, as words."""
    for el in reversed(parents):
        if el.tag in ("link", "joint"):
            return f"{el.tag} {el.get('name', '?')!r} "
    return ""


def check_numbers(path: Path, root: ET.Element) -> None:
    """InputError at the first numeric attribute of the URDF ``root`` (read from ``path``)
    that is not what the format says (module docstring)."""

    def walk(el: ET.Element, parents: list[ET.Element]) -> None:
        rules = NUMBERS.get(el.tag)
        if rules:
            for attr, (n, kind) in rules.items():
                text = el.get(attr)
                if text is not None:
                    _check(path, f"{_owner(parents + [el])}<{el.tag} {attr}>", text, n, kind)
        for child in el:
            walk(child, parents + [el])

    walk(root, [])


def _check(path: Path, key: str, text: str, n: int, kind: str) -> None:
    expected = f"{'a' if n == 1 else n} {WORDS[kind]} number{'s' if n > 1 else ''}"
    parts = text.split()
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    ok = len(values) == n and all(math.isfinite(v) for v in values)
    if ok and kind == "positive":
        ok = all(v > 0 for v in values)
    elif ok and kind == "nonnegative":
        ok = all(v >= 0 for v in values)
    elif ok and kind == "nonzero":
        ok = any(v != 0 for v in values)
    if not ok:
        raise InputError(path, key, expected, text)


__all__ = ["NUMBERS", "check_numbers"]
