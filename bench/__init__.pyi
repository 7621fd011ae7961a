# The public face of calbench.bench: what a notebook user calls, each name re-exported from its
# room's face (bench/<room>/__init__.pyi). At run time calbench.bench.core.face reads these lines
# and loads each name on first use. Code inside calbench imports from the rooms' faces instead.

from .campaign import Campaign, plan_campaign, remeasure, run_campaign, simulate, truth_robot
from .core import (
    PAPER_SCENARIO,
    CalbenchError,
    InputError,
    StaticsError,
    mjcf_path,
    scenario_path,
    terminal_progress,
)
from .log import (
    CampaignLog,
    CorruptLogError,
    IdentificationReport,
    ParameterEstimate,
    read_log,
    recover_log,
    strip_truth,
)
from .model import Params, Robot, Spring
from .robots import check_robot, convert, load_overlay
from .scenario import Scenario, load_scenario, parse_scenario, scenario_variant
from .shopfloor import export_rows, read_readings, readings_csv
from .statics import BatchStatics, Equilibrium, Load, StaticsSolver
from .tracker import TrackerSpec
from .view import write_recording

__all__ = [
    "Campaign",
    "remeasure",
    "simulate",
    "BatchStatics",
    "CalbenchError",
    "CampaignLog",
    "CorruptLogError",
    "Equilibrium",
    "IdentificationReport",
    "InputError",
    "Load",
    "PAPER_SCENARIO",
    "ParameterEstimate",
    "Params",
    "Robot",
    "Scenario",
    "Spring",
    "StaticsError",
    "StaticsSolver",
    "TrackerSpec",
    "check_robot",
    "convert",
    "export_rows",
    "load_overlay",
    "load_scenario",
    "mjcf_path",
    "parse_scenario",
    "plan_campaign",
    "read_log",
    "read_readings",
    "readings_csv",
    "recover_log",
    "run_campaign",
    "scenario_path",
    "scenario_variant",
    "strip_truth",
    "terminal_progress",
    "truth_robot",
    "write_recording",
]
