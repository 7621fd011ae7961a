"""Per-cell statistics of a study: is the calibration as accurate as it claims, and does
discovery find what is hidden?

For each cell, over its campaigns that did not fail, and per identified parameter:
* RMS error, and relative to the truth;
* RMS of error/std (z): the reported std is honest when this is ~1 (its sampling error with n
  campaigns is ~1/sqrt(2n));
* coverage of the +-2 sigma interval: the share of campaigns with |z| <= 2, 95.4 % for honest
  Gaussian errors (binomial sampling error sqrt(p(1-p)/n));
and pooled over the parameters: RMS z and coverage. With discover: the detection rate (the
expected effect named first; spec.expected_effect) and how often each answer was given.
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import pyarrow as pa

from .spec import Study

COVERAGE_K = 2.0


def columns(table: pa.Table, names) -> dict[str, np.ndarray]:
    """Columns as numpy arrays (None -> NaN for numbers, kept for strings and booleans)."""
    out = {}
    for n in names:
        col = table.column(n)
        if pa.types.is_floating(col.type) or pa.types.is_integer(col.type):
            out[n] = np.array([np.nan if x is None else x for x in col.to_pylist()], float)
        else:
            out[n] = np.array(col.to_pylist(), object)
    return out


def _rms(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else None


def _stats(c: dict, rows: np.ndarray, names) -> dict:
    """The statistics of the module docstring over the campaign rows ``rows`` (bool mask)."""
    ok = rows & (c["error"] == "")
    out = {"campaigns": int(rows.sum()), "failed": int((rows & (c["error"] != "")).sum()), "parameters": {}}
    zs = []
    for p in names:
        z = c[f"{p}_z"][ok]
        err = c[f"{p}_error"][ok]
        truth = c[f"{p}_truth"][ok]
        fin = np.isfinite(z)
        if not fin.any():
            out["parameters"][p] = {"identified": 0}
            continue
        zs.append(z[fin])
        rel = err[fin] / truth[fin]
        out["parameters"][p] = {
            "identified": int(fin.sum()),
            "rms_error": _rms(err[fin]),
            "rms_relative_error": _rms(rel),
            "rms_z": _rms(z[fin]),
            "mean_z": float(np.mean(z[fin])),
            "coverage_2sigma": float(np.mean(np.abs(z[fin]) <= COVERAGE_K)),
        }
    allz = np.concatenate(zs) if zs else np.zeros(0)
    out["rms_z"] = _rms(allz)
    out["coverage_2sigma"] = float(np.mean(np.abs(allz) <= COVERAGE_K)) if allz.size else None
    det = [d for d in c["detected"][ok] if d is not None]
    out["detection_rate"] = float(np.mean(det)) if det else None
    out["named_first"] = dict(Counter(x for x in c["named_first"][ok] if x is not None))
    t = c["campaign_s"][rows]
    out["median_campaign_s"] = float(np.median(t)) if t.size else None
    return out


def _study_columns(study: Study, table: pa.Table) -> dict[str, np.ndarray]:
    return columns(
        table,
        ["cell", "error", "detected", "named_first", "campaign_s"]
        + [f"{p}_{f}" for p in study.param_names for f in ("z", "error", "truth")],
    )


def cell_summaries(study: Study, table: pa.Table) -> list[dict]:
    """One dict per cell: its axis values, expected effect and :func:`_stats`."""
    c = _study_columns(study, table)
    return [
        {
            "cell": cell.index,
            "values": cell.values,
            "plan": cell.plan,
            "expected": cell.expected,
            **_stats(c, c["cell"] == cell.index, study.param_names),
        }
        for cell in study.cells
    ]


def pooled_by_axis(study: Study, table: pa.Table) -> dict[str, list[dict]]:
    """Per axis, per value: the statistics pooled over the other axes (for the plots)."""
    c = _study_columns(study, table)
    out = {}
    for a in study.axes:
        rows = []
        for v in a.column:
            cells = [cell.index for cell in study.cells if cell.values[a.name] == v]
            rows.append({"value": v, **_stats(c, np.isin(c["cell"], cells), study.param_names)})
        out[a.name] = rows
    return out


def _fmt(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def format_cells(study: Study, cells: list[dict]) -> str:
    """The per-cell table the command line prints."""
    heads = [a.name for a in study.axes]
    widths = [max(len(h), *(len(str(c["values"][h])) for c in cells)) for h in heads]
    disc = any(c["named_first"] for c in cells)
    line = "  ".join(f"{h:<{w}}" for h, w in zip(heads, widths))
    line += f"  {'n':>4} {'fail':>4} {'RMS z':>6} {'±2σ':>6}" + (
        f" {'detect':>7}  expected -> named first" if disc else ""
    )
    out = [f"study {study.name}: {len(cells)} cells x {study.seeds} seeds", line]
    for c in cells:
        s = "  ".join(f"{str(c['values'][h]):<{w}}" for h, w in zip(heads, widths))
        s += (
            f"  {c['campaigns']:>4} {c['failed']:>4} {_fmt(c['rms_z'], '6.2f')} "
            f"{_fmt(None if c['coverage_2sigma'] is None else 100 * c['coverage_2sigma'], '5.1f')}%"
        )
        if disc:
            named = ", ".join(f"{k} {v}" for k, v in sorted(c["named_first"].items(), key=lambda kv: -kv[1]))
            s += f" {_fmt(c['detection_rate'], '7.2f')}  {c['expected']} -> {named}"
        out.append(s)
    out.append(
        "RMS z: RMS of (estimate - truth) / reported std over the identified parameters (1 when the "
        "std is honest); ±2σ: share of |z| <= 2 (95.4 % expected)"
        + ("; detect: share of campaigns naming the expected effect first" if disc else "")
    )
    return "\n".join(out)


__all__ = ["cell_summaries", "pooled_by_axis", "format_cells", "columns"]
