"""Study results: one Parquet file (pyarrow), one row per campaign, resumable after any crash.

A Parquet file is only readable once its footer is written, so finished campaigns go first to a
journal beside it, ``RESULTS.parquet.parts/``: one small Parquet file per finished task, each
written atomically (temporary name, then rename; bench/core/outputs.py). Every 30 s (run.py's
CONSOLIDATE_S), on Ctrl-C and at the end, the journal is merged into RESULTS.parquet (again atomically: the file
is always either the previous complete version or the new one) and the merged parts are removed.
A crash at any moment therefore loses at most the campaigns still running; re-running the same
command reads both, skips every (cell, replicate) already there, and runs the rest.

Rows are kept sorted by (cell, replicate), so a study that was interrupted and resumed ends as
the same file as one run in one go (up to the timing and worker columns). The file's metadata
holds the study text, the calbench version and the designed plans (design:<c>:<M> cells).
"""

from __future__ import annotations

import json
import uuid
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from calbench.bench.core import InputError, atomic_path, write_text

PARTS = ".parts"


def _version() -> str:
    try:
        return version("calbench")
    except PackageNotFoundError:  # pragma: no cover
        return "unknown"


class ResultStore:
    """RESULTS.parquet and its journal folder, for one schema."""

    def __init__(self, out: str | Path, schema: pa.Schema, study_text: str):
        self.out = Path(out)
        self.parts = self.out.with_name(self.out.name + PARTS)
        self.schema = schema
        self.study_text = study_text
        self.plans: dict[str, list] = {}
        self._merged_parts: list[Path] = []

    # -- reading ------------------------------------------------------------------------------
    def _read(self, path: Path) -> pa.Table:
        try:
            t = pq.read_table(path)
        except (OSError, pa.ArrowInvalid) as exc:
            raise InputError(path, "--out", "a Parquet file of study results", str(exc)) from None
        if t.schema.remove_metadata() != self.schema.remove_metadata():
            mine, theirs = set(self.schema.names), set(t.schema.names)
            diff = sorted(mine ^ theirs) or ["column types"]
            raise InputError(
                self.out,
                "--out",
                "results of this study (same columns) or a new file",
                "columns differ: " + ", ".join(diff[:6]),
            )
        meta = t.schema.metadata or {}
        if b"calbench.plans" in meta:
            self.plans.update(json.loads(meta[b"calbench.plans"]))
        return t.replace_schema_metadata(None)

    def load(self) -> pa.Table:
        """Everything finished so far (the file and the journal), one row per (cell_id, replicate)."""
        tables = []
        if self.out.exists():
            tables.append(self._read(self.out))
        self._merged_parts = sorted(self.parts.glob("part-*.parquet")) if self.parts.is_dir() else []
        tables += [self._read(p) for p in self._merged_parts]
        for p in sorted(self.parts.glob("plan-*.json")) if self.parts.is_dir() else []:
            self.plans.update(json.loads(p.read_text(encoding="utf-8")))
        if not tables:
            return self.schema.empty_table()
        t = pa.concat_tables(tables)
        last: dict = {}
        for i, key in enumerate(zip(t.column("cell_id").to_pylist(), t.column("replicate").to_pylist())):
            last[key] = i  # a row merged twice counts once
        return t.take(sorted(last.values()))

    # -- writing ------------------------------------------------------------------------------
    def add(self, rows: list[dict]) -> None:
        """Journal the rows of one finished task (durable when this returns)."""
        if not rows:
            return
        self.parts.mkdir(parents=True, exist_ok=True)
        table = pa.Table.from_pylist(rows, schema=self.schema)
        with atomic_path(self.parts / f"part-{uuid.uuid4().hex}.parquet") as tmp:
            pq.write_table(table, tmp)

    def add_plan(self, key: str, poses: list) -> None:
        """Keep a designed plan (so a resumed study does not design it again)."""
        self.plans[key] = poses
        self.parts.mkdir(parents=True, exist_ok=True)
        write_text(self.parts / f"plan-{key}.json", json.dumps({key: poses}))

    def consolidate(self, cell_index: dict[str, int], complete: bool) -> pa.Table:
        """Merge the journal into RESULTS.parquet (rows renumbered by the study's cells, sorted);
        remove the merged parts, and the journal folder when the study is ``complete``. Returns
        the merged table."""
        t = self.load()
        merged = list(self._merged_parts)
        cells = pa.array([cell_index[c] for c in t.column("cell_id").to_pylist()], pa.int64())
        t = t.set_column(t.schema.get_field_index("cell"), "cell", cells)
        t = t.sort_by([("cell", "ascending"), ("replicate", "ascending")])
        meta = {
            "calbench.study": self.study_text,
            "calbench.version": _version(),
            "calbench.plans": json.dumps(self.plans),
        }
        t = t.replace_schema_metadata(meta)
        with atomic_path(self.out) as tmp:
            pq.write_table(t, tmp)
        for p in merged:
            p.unlink(missing_ok=True)
        if complete and self.parts.is_dir():
            for p in self.parts.glob("plan-*.json"):
                p.unlink()
            try:
                self.parts.rmdir()
            except OSError:
                pass
        return t


def read_results(path: str | Path) -> tuple[pa.Table, dict]:
    """A study's results and its metadata (study text, version, plans)."""
    t = pq.read_table(path)
    meta = {k.decode(): v.decode() for k, v in (t.schema.metadata or {}).items()}
    return t.replace_schema_metadata(None), meta


__all__ = ["ResultStore", "read_results", "PARTS"]
