"""calbench.identify.design — design of experiments (paper §5).

candidates (feasible configurations and their exact information blocks), candidate_file (the
NPZ other tools read and write), criteria (A, D, AD, pose), exchange (the discrete optimiser),
certificate (approximate optimal designs and the bound that certifies a plan), selection (rows
chosen and certified, on any blocks), plan (the whole pipeline and the runnable plan), study
(the paper's Tables 1-4 and Figs. 7-8), threads (BLAS pinning for the small algebra).
"""

from .candidate_file import CandidateFile, read_candidates
from .candidates import CandidateSet, DesignSettings, InfoEngine, generate_candidates, load_design_scenario
from .certificate import ApproximateDesign, Certificate, approximate_design, certify
from .criteria import CRITERIA, criterion_value, information, measures
from .exchange import Exchanger
from .plan import DesignResult, PlanPose, design_plan, plan_scenario_text
from .selection import Selection, select_rows

__all__ = [
    "CandidateSet",
    "DesignSettings",
    "InfoEngine",
    "generate_candidates",
    "load_design_scenario",
    "CandidateFile",
    "read_candidates",
    "ApproximateDesign",
    "Certificate",
    "approximate_design",
    "certify",
    "CRITERIA",
    "criterion_value",
    "information",
    "measures",
    "Exchanger",
    "DesignResult",
    "PlanPose",
    "design_plan",
    "plan_scenario_text",
    "Selection",
    "select_rows",
]
