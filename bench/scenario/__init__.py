"""calbench.bench.scenario: campaign files (TOML): their types, their parser, their time line."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
