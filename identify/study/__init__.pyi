# The public face of calbench.identify.study: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .accuracy import predicted_std
from .campaign import TIMING_COLUMNS, needs_log, simulate_in_memory
from .montecarlo import (
    RUNS_PER_TASK,
    PendingMonteCarlo,
    WorkEstimate,
    check_montecarlo_size,
    estimated_seconds,
    format_summary,
    measure_montecarlo,
    montecarlo_methods,
    prepare_montecarlo,
    run_montecarlo,
    true_theta,
)
from .plots import accuracy_plots, axis_ticks, power_plots
from .run import Pending, StudyOutcome, StudyReport, design_key, prepare, report_study, run_study
from .spec import Study, load_study, scaled
from .store import read_results
from .summary import cell_summaries, format_cells, pooled_by_axis

__all__ = [
    "Pending",
    "PendingMonteCarlo",
    "RUNS_PER_TASK",
    "Study",
    "StudyOutcome",
    "StudyReport",
    "TIMING_COLUMNS",
    "accuracy_plots",
    "axis_ticks",
    "cell_summaries",
    "check_montecarlo_size",
    "design_key",
    "estimated_seconds",
    "measure_montecarlo",
    "WorkEstimate",
    "format_cells",
    "format_summary",
    "load_study",
    "montecarlo_methods",
    "needs_log",
    "pooled_by_axis",
    "power_plots",
    "predicted_std",
    "prepare",
    "prepare_montecarlo",
    "read_results",
    "report_study",
    "run_montecarlo",
    "run_study",
    "scaled",
    "simulate_in_memory",
    "true_theta",
]
