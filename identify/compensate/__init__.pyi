# The public face of calbench.identify.compensate: what code outside this room may import. At run
# time calbench.bench.core.face reads these lines and loads each name on first use.

from .batch import compensate_batch
from .criterion import job_design_jacobian
from .fingerprint import robot_sha256
from .identified import IdentifiedParams, identified_from_report, read_identified
from .job import Job, JobPoint, Tool, check_job, load_job, parse_job
from .run import Z_EXCEEDED, Compensation, CompensationRequest, run_compensate
from .solve import TARGETS, Compensator, PointResult
from .toolpoint import tool_jacobian, tool_pose, with_tool
from .truth import TruePoint, apply_to_truth
from .view import path_positions, write_path_recording

__all__ = [
    "Compensation",
    "CompensationRequest",
    "Compensator",
    "IdentifiedParams",
    "Job",
    "JobPoint",
    "PointResult",
    "TARGETS",
    "Tool",
    "TruePoint",
    "Z_EXCEEDED",
    "apply_to_truth",
    "check_job",
    "compensate_batch",
    "identified_from_report",
    "job_design_jacobian",
    "load_job",
    "parse_job",
    "path_positions",
    "read_identified",
    "robot_sha256",
    "run_compensate",
    "tool_jacobian",
    "tool_pose",
    "with_tool",
    "write_path_recording",
]
