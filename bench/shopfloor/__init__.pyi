# The public face of calbench.bench.shopfloor: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .formats import FORMATS, ReadingsFormat, ReadingsTable
from .logcsv import ImportedReadings, ImportSummary, campaign_readings, export_rows, write_imported_log
from .probe import ProbeSeries, campaign_files, euler_xyz, read_probe_series, read_transform, series_files
from .readings import group, read_readings, readings_csv

__all__ = [
    "series_files",
    "FORMATS",
    "ImportSummary",
    "ProbeSeries",
    "ImportedReadings",
    "ReadingsFormat",
    "ReadingsTable",
    "campaign_files",
    "campaign_readings",
    "euler_xyz",
    "export_rows",
    "group",
    "read_probe_series",
    "read_readings",
    "read_transform",
    "readings_csv",
    "write_imported_log",
]
