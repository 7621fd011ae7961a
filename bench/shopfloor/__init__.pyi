# The public face of calbench.bench.shopfloor: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .formats import FORMATS, ReadingsFormat, ReadingsTable
from .logcsv import ImportSummary, Readings, campaign_readings, export_rows, write_imported_log
from .readings import group, read_readings, readings_csv

__all__ = [
    "FORMATS",
    "ImportSummary",
    "Readings",
    "ReadingsFormat",
    "ReadingsTable",
    "campaign_readings",
    "export_rows",
    "group",
    "read_readings",
    "readings_csv",
    "write_imported_log",
]
