# The public face of calbench.identify.discover: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .aliasing import aliasing_report
from .decide import ALPHA_EFFECT, MIN_EXPLAINED, compare, lr_spread, lr_threshold, near_ties
from .exposure import effect_exposure, exposure_report, worst_case
from .fit import (
    DISCOVERY_EFFECTS,
    AugmentedForward,
    build,
    effect_priors,
    fit_augmented,
    label,
    library,
    whitened,
)
from .geometric import (
    Candidate,
    Readings,
    discover_geometry,
    global_base,
    group,
    reduced,
    redundancies,
    start_fit,
    with_candidate,
)
from .geometric import library as geometric_library
from .geometric_run import (
    discover_geometry_json,
    format_discover_geometry,
    geometric_problem,
    run_discover_geometry,
)
from .narrative import alias_lines, base_lines, exposure_lines, tie_lines
from .search import fit_candidate, polish, unabsorbed_norms
from .stats import ALPHA_FIT
from .uncertainty import MAX_RELATIVE_STD, Determination, determination, split_by_ties
from .workflow import (
    AMBIGUOUS,
    UNEXPLAINED,
    alias_columns,
    augmented_mjcf,
    base_exposure,
    base_fit,
    clean,
    discover,
    discover_observations,
    story,
)

__all__ = [
    "ALPHA_EFFECT",
    "ALPHA_FIT",
    "Candidate",
    "Readings",
    "discover_geometry",
    "discover_geometry_json",
    "format_discover_geometry",
    "geometric_library",
    "geometric_problem",
    "global_base",
    "group",
    "redundancies",
    "reduced",
    "run_discover_geometry",
    "start_fit",
    "with_candidate",
    "AMBIGUOUS",
    "AugmentedForward",
    "DISCOVERY_EFFECTS",
    "Determination",
    "MAX_RELATIVE_STD",
    "MIN_EXPLAINED",
    "UNEXPLAINED",
    "alias_columns",
    "alias_lines",
    "base_lines",
    "exposure_lines",
    "tie_lines",
    "aliasing_report",
    "augmented_mjcf",
    "base_exposure",
    "base_fit",
    "build",
    "clean",
    "compare",
    "determination",
    "discover",
    "discover_observations",
    "effect_exposure",
    "effect_priors",
    "exposure_report",
    "worst_case",
    "fit_augmented",
    "fit_candidate",
    "label",
    "library",
    "lr_spread",
    "lr_threshold",
    "near_ties",
    "polish",
    "split_by_ties",
    "story",
    "unabsorbed_norms",
    "whitened",
]
