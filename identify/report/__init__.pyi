# The public face of calbench.identify.report: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .html import Z95, design_section, discovery_section, html_report, profile_interval, write_report
from .identification import (
    Z_CHECK,
    check_failed,
    format_table,
    identification_report,
    identify,
    run_identify,
    truth_vector,
)
from .selfcheck import self_check

__all__ = [
    "html_report",
    "discovery_section",
    "profile_interval",
    "identification_report",
    "Z95",
    "Z_CHECK",
    "check_failed",
    "design_section",
    "format_table",
    "identify",
    "run_identify",
    "self_check",
    "truth_vector",
    "write_report",
]
