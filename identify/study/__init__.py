"""calbench.identify.study — grids of whole campaigns (issue 15).

spec (the study file and its validated cells), campaign (the task: simulate, identify, discover
one cell's campaigns), store (Parquet results with a crash-safe journal), run (prepare and run a
study on an executor), summary (per-cell statistics), plots (accuracy and power curves).
"""

from .run import Pending, StudyOutcome, prepare, run_study
from .spec import Study, load_study
from .store import read_results
from .summary import cell_summaries, format_cells

__all__ = [
    "Study",
    "load_study",
    "prepare",
    "run_study",
    "Pending",
    "StudyOutcome",
    "read_results",
    "cell_summaries",
    "format_cells",
]
