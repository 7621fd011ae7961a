# The public face of calbench.bench.shopfloor: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .logcsv import ImportSummary, Readings, campaign_readings, export_rows, write_imported_log
from .readings import ReadingsTable, group, read_readings, readings_csv

__all__ = [
    "ImportSummary",
    "Readings",
    "ReadingsTable",
    "campaign_readings",
    "export_rows",
    "group",
    "read_readings",
    "readings_csv",
    "write_imported_log",
]
