"""A toy robot importer in one file: everything adding a robot format takes (docs/architecture.md,
"How to add a robot importer"). Importing this module registers nothing; the test registers
:data:`IMPORTER` (bench.robots.IMPORTERS.register) and removes it afterwards.

The format: a URDF compressed with gzip (``.urdf.gz``). The toy unpacks it into a temporary folder
and hands it to the URDF importer, so the MJCF is the one the plain URDF gives (a toy: meshes
beside the file are not found from the temporary folder).
"""

from __future__ import annotations

import gzip
import tempfile
from pathlib import Path

from calbench.bench.robots import IMPORTERS, Conversion, RobotImporter


class GzipUrdfImporter(RobotImporter):
    name = "urdf-gz"
    summary = "a URDF compressed with gzip, and an overlay"
    suffixes = (".urdf.gz",)

    def convert(self, path: Path, overlay) -> Conversion:
        with tempfile.TemporaryDirectory() as tmp:
            plain = Path(tmp) / path.name[: -len(".gz")]
            plain.write_bytes(gzip.decompress(path.read_bytes()))
            return IMPORTERS.members()["urdf"].convert(plain, overlay)


IMPORTER = GzipUrdfImporter()
