"""Applying effects: the robot's MJCF edited by a list of (effect, parameters), compiled.

The edited model is valid MJCF, loadable on its own (:meth:`EffectRobot.to_xml`), every number
exact; loading it gives the same model.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import check_mjcf_text, check_model_file
from calbench.bench.model import Robot

from .base import Effect


class EffectRobot(Robot):
    """A Robot compiled from an edited spec; keeps the effects and the edited MJCF."""

    def __init__(self, model, xml: str, effects, source: Path | None = None):
        super().__init__(model, source)
        self.xml = xml
        self.effects = list(effects)

    def to_xml(self) -> str:
        """The augmented MJCF (valid, loadable) with the effects' parameters written in."""
        return self.xml


def load_spec(xml_or_path) -> mujoco.MjSpec:
    """MjSpec from a path (Path, or a str naming an existing file) or from MJCF text."""
    if isinstance(xml_or_path, mujoco.MjSpec):
        return xml_or_path.copy()
    if isinstance(xml_or_path, Path) or (isinstance(xml_or_path, str) and "<mujoco" not in xml_or_path):
        check_model_file(xml_or_path)  # safe XML, files inside its folder (bench/core/xmlsafe.py)
        return mujoco.MjSpec.from_file(str(xml_or_path))
    check_mjcf_text(xml_or_path)  # text (a log's robot) reads no file
    return mujoco.MjSpec.from_string(xml_or_path)


def apply_effects(xml_or_path, effects: list[tuple[Effect, np.ndarray]]) -> EffectRobot:
    """Load the MJCF, apply each (effect, params) in order, compile, wrap in a Robot.

    The returned robot's `to_xml()` is the edited MJCF (spec.to_xml()); loading it gives the
    same model. Raises ValueError (MuJoCo compile errors, unknown links/joints)."""
    spec = load_spec(xml_or_path)
    for effect, params in effects:
        effect.apply(spec, params)
    model = spec.compile()
    source = (
        Path(xml_or_path)
        if isinstance(xml_or_path, Path) or (isinstance(xml_or_path, str) and "<mujoco" not in xml_or_path)
        else None
    )
    return EffectRobot(model, augmented_xml(spec, effects), effects, source)


def augmented_xml(spec: mujoco.MjSpec, effects: list[tuple[Effect, np.ndarray]]) -> str:
    """The edited spec as MJCF, every number exact (compiler savecompiled="false"; the default
    saves compiled values rounded to ~6 digits), headed by a comment naming the effects."""
    lines = [
        f"  {e.name} {e.options}: "
        + ", ".join(f"{n} = {float(v)!r} {u}" for n, v, u in zip(e.param_names, np.atleast_1d(p), e.units))
        for e, p in effects
    ]
    if lines:
        spec.comment = "\n  Augmented by calbench (bench/model/effects/) with:\n" + "\n".join(lines) + "\n"
    spec.compiler.savecompiled = False
    return spec.to_xml()
