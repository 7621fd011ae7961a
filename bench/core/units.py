"""Units for people: what a parameter's SI unit is shown as, and the factor from SI.

SI inside, µrad/(N·m), kN/m and mm in what people read (the terminal table of ``identify``,
the HTML report, the Rerun view). One table, so the three never disagree.
"""

from __future__ import annotations

# SI unit -> (label shown, factor from SI)
DISPLAY = {
    "rad/(N*m)": ("µrad/(N·m)", 1e6),
    "N/m": ("kN/m", 1e-3),
    "m": ("mm", 1e3),
}


def unit_display(unit: str) -> tuple[str, float]:
    """(label, factor from SI) of ``unit``; a unit not in :data:`DISPLAY` is shown as is."""
    return DISPLAY.get(unit, (unit, 1.0))


__all__ = ["DISPLAY", "unit_display"]
