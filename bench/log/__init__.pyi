# The public face of calbench.bench.log: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .foxglove import FoxgloveWriter
from .idreport import IdentificationReport, ObservationFit, Outlier, ParameterEstimate
from .mcapscan import Cut, Damage, scan
from .read import (
    KEEP_READINGS,
    CorruptLogError,
    LogReadings,
    message_problems,
    read_log,
    showing_progress,
)
from .records import STATES, CampaignLog, PerState, WrenchRecord
from .recover import recover_log
from .schema import SCHEMAS, checker, findings, problems
from .writer import (
    TRUTH_PREFIX,
    CampaignTruth,
    LogHeader,
    LogWriter,
    SignalGuard,
    has_truth,
    redact_truth,
    strip_truth,
)

__all__ = [
    "showing_progress",
    "message_problems",
    "LogReadings",
    "KEEP_READINGS",
    "problems",
    "findings",
    "checker",
    "CampaignLog",
    "CampaignTruth",
    "CorruptLogError",
    "Cut",
    "Damage",
    "FoxgloveWriter",
    "IdentificationReport",
    "LogHeader",
    "LogWriter",
    "ObservationFit",
    "Outlier",
    "ParameterEstimate",
    "PerState",
    "SCHEMAS",
    "STATES",
    "SignalGuard",
    "TRUTH_PREFIX",
    "WrenchRecord",
    "has_truth",
    "read_log",
    "recover_log",
    "redact_truth",
    "scan",
    "strip_truth",
]
