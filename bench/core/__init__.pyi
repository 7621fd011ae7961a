# The public face of calbench.bench.core: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .errors import CalbenchError, InputError, StaticsError
from .face import face_exports, lazy_face
from .family import Family, FileFormat
from .memory import available_bytes, check_memory, nbytes_text
from .outputs import (
    WriteError,
    atomic_path,
    check_outputs,
    holding_outputs,
    refused_write,
    write_bytes,
    write_text,
)
from .progress import Progress, ProgressSink, duration, sink, terminal_progress
from .resources import PAPER_SCENARIO, mjcf_path, scenario_path
from .states import STATES
from .tables import Table, describe, frozen_array, parse_toml, read_text
from .units import DISPLAY, unit_display
from .xmlsafe import check_mjcf_text, check_model_file, file_references, parse_xml

__all__ = [
    "face_exports",
    "lazy_face",
    "CalbenchError",
    "DISPLAY",
    "Family",
    "FileFormat",
    "InputError",
    "PAPER_SCENARIO",
    "STATES",
    "Progress",
    "ProgressSink",
    "StaticsError",
    "Table",
    "WriteError",
    "atomic_path",
    "available_bytes",
    "check_memory",
    "check_mjcf_text",
    "check_model_file",
    "check_outputs",
    "describe",
    "file_references",
    "frozen_array",
    "holding_outputs",
    "mjcf_path",
    "nbytes_text",
    "parse_toml",
    "parse_xml",
    "read_text",
    "refused_write",
    "scenario_path",
    "sink",
    "duration",
    "terminal_progress",
    "unit_display",
    "write_bytes",
    "write_text",
]
