"""calbench.identify.study — grids of whole campaigns (issue 15).

spec (the study file and its validated cells), campaign (the task: simulate, identify, discover
one cell's campaigns), store (Parquet results with a crash-safe journal), run (prepare and run a
study on an executor), summary (per-cell statistics), plots (accuracy and power curves).
"""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
