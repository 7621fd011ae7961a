"""calbench.bench.model.effects: the hidden physical effects, one file each, and their registry."""

from calbench.bench.core import lazy_face

from .registry import load_members

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
load_members(__name__, __file__)  # every effect registers itself, in the bench's order
