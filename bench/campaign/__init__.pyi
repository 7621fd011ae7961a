# The public face of calbench.bench.campaign: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .run import (
    CampaignInterrupted,
    PosePlan,
    drifted,
    plan_campaign,
    pose_load,
    reading_drift,
    run_campaign,
    scenario_params,
    simulate,
    truth_robot,
)

__all__ = [
    "CampaignInterrupted",
    "PosePlan",
    "drifted",
    "plan_campaign",
    "pose_load",
    "reading_drift",
    "run_campaign",
    "scenario_params",
    "simulate",
    "truth_robot",
]
