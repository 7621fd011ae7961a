# The public face of calbench.bench.campaign: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .plan import PosePlan, check_campaign_size, plan_campaign, pose_load, truth_params, truth_robot
from .run import CampaignInterrupted, run_campaign, simulate_to_log
from .simulation import Campaign, remeasure, simulate

__all__ = [
    "Campaign",
    "CampaignInterrupted",
    "PosePlan",
    "check_campaign_size",
    "plan_campaign",
    "pose_load",
    "remeasure",
    "run_campaign",
    "truth_params",
    "simulate",
    "simulate_to_log",
    "truth_robot",
]
