# The public face of calbench.identify.design.optimal: what code outside this room may import. At run
# time calbench.bench.core.face reads these lines and loads each name on first use.

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
from .criteria import (
    CRITERIA,
    criterion_value,
    information,
    inverse_information,
    measures,
)
from .exchange import Exchanger
from .selection import Selection, select_rows, selection_text

__all__ = [
    "a_bound",
    "ALGORITHMS",
    "approximate_design",
    "ApproximateDesign",
    "Certificate",
    "certify",
    "column_scale",
    "CRITERIA",
    "criterion_value",
    "d_bound",
    "Exchanger",
    "information",
    "inverse_information",
    "measures",
    "normalise_blocks",
    "plan_logdet",
    "select_rows",
    "Selection",
    "selection_text",
    "SingularCandidates",
]
