"""The files calbench ships: robot models and scenarios, found the same way in a checkout
(editable install) and in a plain install (package data under site-packages/calbench/)."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def scenario_path(name: str) -> Path:
    """A shipped scenario, e.g. ``scenario_path("paper_table5.toml")``."""
    return Path(str(files("calbench.scenarios").joinpath(name)))


def mjcf_path(name: str) -> Path:
    """A shipped robot model, e.g. ``mjcf_path("m900ib700.xml")``."""
    return Path(str(files("calbench.mjcf").joinpath(name)))


PAPER_SCENARIO = "paper_table5.toml"

__all__ = ["scenario_path", "mjcf_path", "PAPER_SCENARIO"]
