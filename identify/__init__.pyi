# The public face of calbench.identify: what a notebook user calls, each name re-exported from its
# room's face (identify/<room>/__init__.pyi; run_demo from identify/demo.py, which sits here). At
# run time calbench.bench.core.face reads these lines and loads each name on first use. Code
# inside calbench imports from the rooms' faces instead.
#
# `discover` is a room here, so its entry is re-exported as `run_discover` (the name of every
# other entry: run_identify, run_montecarlo, run_design, run_study): a public name equal to a room's
# would be replaced by the room itself once it is imported.

from .compensate import Compensation, CompensationRequest, run_compensate
from .core import Observations, from_campaign, from_log
from .demo import run_demo
from .design import DesignOutcome, DesignRequest, run_design
from .discover import discover as run_discover
from .discover import story
from .methods import one_step, two_step, two_step_iterated
from .report import check_failed, format_table, identify, run_identify, write_report
from .shopfloor import import_readings
from .study import format_summary, load_study, prepare, read_results, run_montecarlo, run_study

__all__ = [
    "Compensation",
    "CompensationRequest",
    "DesignOutcome",
    "DesignRequest",
    "Observations",
    "check_failed",
    "format_summary",
    "format_table",
    "from_campaign",
    "from_log",
    "identify",
    "import_readings",
    "load_study",
    "one_step",
    "prepare",
    "read_results",
    "run_compensate",
    "run_demo",
    "run_design",
    "run_discover",
    "run_identify",
    "run_montecarlo",
    "run_study",
    "story",
    "two_step",
    "two_step_iterated",
    "write_report",
]
