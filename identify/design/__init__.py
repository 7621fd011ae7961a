"""calbench.identify.design — design of experiments (paper §5).

candidates (feasible configurations and their exact information blocks), criteria (A, D, AD,
pose), exchange (the discrete optimiser), plan (the whole pipeline and the runnable plan),
study (the paper's Tables 1-4 and Figs. 7-8).
"""
from .candidates import CandidateSet, DesignSettings, InfoEngine, generate_candidates, load_design_scenario
from .criteria import CRITERIA, criterion_value, information, measures
from .exchange import Exchanger
from .plan import DesignResult, PlanPose, design_plan, plan_scenario_text

__all__ = ["CandidateSet", "DesignSettings", "InfoEngine", "generate_candidates", "load_design_scenario",
           "CRITERIA", "criterion_value", "information", "measures", "Exchanger", "DesignResult",
           "PlanPose", "design_plan", "plan_scenario_text"]
