# The public face of calbench.identify.design: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .batch_info import BatchInfo
from .candidates import (
    SECONDS_PER_CANDIDATE,
    CandidateFile,
    CandidateSet,
    generate_candidates,
    read_candidates,
)
from .certificate import (
    ALGORITHMS,
    ApproximateDesign,
    Certificate,
    SingularCandidates,
    a_bound,
    approximate_design,
    certify,
    column_scale,
    d_bound,
    normalise_blocks,
    plan_logdet,
)
from .criteria import CRITERIA, criterion_value, information, measures
from .engine import InfoEngine
from .exchange import Exchanger
from .feasibility import (
    EQUILIBRIUM_RULES,
    LOAD_KINDS,
    collision_model,
    excluded_pairs,
    horizontal_clearance,
    lateral_wrench,
    world_parent_pairs,
    wrist_body,
)
from .plan import (
    DesignResult,
    PlanPose,
    design_plan,
    input_plan_measures,
    merge_repeats,
    plan_comment,
    plan_measures,
    plan_scenario_text,
    poses_of_rows,
    result_json,
    scenario_plan_information,
    summary_text,
    work_jacobian,
)
from .run import DesignOutcome, DesignRequest, run_design
from .selection import Selection, select_rows, selection_text
from .settings import DESIGN_KEYS, DesignSettings, load_design_scenario, read_design_settings
from .study import run_study

__all__ = [
    "ALGORITHMS",
    "ApproximateDesign",
    "BatchInfo",
    "CRITERIA",
    "CandidateFile",
    "CandidateSet",
    "Certificate",
    "DESIGN_KEYS",
    "DesignOutcome",
    "DesignRequest",
    "DesignResult",
    "DesignSettings",
    "EQUILIBRIUM_RULES",
    "Exchanger",
    "InfoEngine",
    "LOAD_KINDS",
    "PlanPose",
    "SECONDS_PER_CANDIDATE",
    "Selection",
    "SingularCandidates",
    "a_bound",
    "approximate_design",
    "certify",
    "column_scale",
    "collision_model",
    "criterion_value",
    "d_bound",
    "design_plan",
    "excluded_pairs",
    "generate_candidates",
    "horizontal_clearance",
    "information",
    "input_plan_measures",
    "lateral_wrench",
    "load_design_scenario",
    "measures",
    "merge_repeats",
    "normalise_blocks",
    "plan_comment",
    "plan_logdet",
    "plan_measures",
    "plan_scenario_text",
    "poses_of_rows",
    "read_candidates",
    "read_design_settings",
    "result_json",
    "run_design",
    "run_study",
    "scenario_plan_information",
    "select_rows",
    "selection_text",
    "summary_text",
    "work_jacobian",
    "world_parent_pairs",
    "wrist_body",
]
