# The public face of calbench.bench.core: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .errors import CalbenchError, InputError, StaticsError
from .face import face_exports, lazy_face
from .outputs import atomic_path, check_outputs, write_text
from .progress import Progress, ProgressSink, duration, sink, terminal_progress
from .resources import PAPER_SCENARIO, mjcf_path, scenario_path
from .tables import Table, describe, frozen_array, parse_toml, read_text
from .units import DISPLAY, unit_display

__all__ = [
    "face_exports",
    "lazy_face",
    "CalbenchError",
    "DISPLAY",
    "InputError",
    "PAPER_SCENARIO",
    "Progress",
    "ProgressSink",
    "StaticsError",
    "Table",
    "atomic_path",
    "check_outputs",
    "describe",
    "frozen_array",
    "mjcf_path",
    "parse_toml",
    "read_text",
    "scenario_path",
    "sink",
    "duration",
    "terminal_progress",
    "unit_display",
    "write_text",
]
