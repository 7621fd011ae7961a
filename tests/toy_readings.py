"""A toy readings format in one file: everything adding a format of tracker readings takes
(docs/architecture.md, "How to add a readings format"). Importing this module registers nothing;
the test registers :data:`FORMAT` (bench.shopfloor.FORMATS.register) and removes it.

The format: JSON lines (``.jsonl``), one object per reading with the CSV's columns as keys,
``{"pose": 0, "state": "unloaded", "point": "refl_a", "x": 1.0, "y": 2.0, "z": 3.0}`` (lengths in
the import's ``--units``). The toy turns the lines into the CSV form and reads that, so every
check of the CSV holds (line k of the file is the CSV's line k + 1: a toy).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from calbench.bench.core import InputError
from calbench.bench.shopfloor import ReadingsFormat, read_readings

COLUMNS = ("pose", "state", "point", "x", "y", "z")


class JsonLinesReadings(ReadingsFormat):
    name = "jsonl"
    summary = "one JSON object per reading, keys pose, state, point, x, y, z"
    suffixes = (".jsonl",)

    def read(self, path: Path, data: bytes, n_poses: int, points, units: str = "mm"):
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(COLUMNS)
        for k, line in enumerate(data.decode("utf-8").splitlines(), start=1):
            try:
                row = json.loads(line)
                w.writerow([row[c] for c in COLUMNS])
            except (ValueError, KeyError, TypeError) as exc:
                raise InputError(
                    path, f"line {k}", "a JSON object with " + ", ".join(COLUMNS), str(exc)
                ) from None
        return read_readings(path, n_poses, points, units, text=buf.getvalue())


FORMAT = JsonLinesReadings()
