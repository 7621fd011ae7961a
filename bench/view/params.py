"""The identified parameters as a person reads them: a chart with the parameter names, and a
table, both in display units (bench/core/units.py: µrad/(N·m), kN/m, mm).

Rerun's bar charts have no category labels, so the chart is drawn in a 2D view: one block per
quantity (parameters sharing a unit), one row per parameter with its name at the left, the
estimate as a dot with a bar of ±1 std, the truth (when the log carries it) as a tick across
the row, and the block's own axis under it. Zero is on every axis, so lengths compare.

The truth (which identify copies into its report from a simulated log) is drawn only under
``truth/``: its ticks under ``truth/parameters/chart``, its table as ``truth/parameters/table``;
hide ``truth`` and the chart is what a real campaign shows.

Pure functions: :func:`chart` returns the (entity path, archetype) pairs and the extent the 2D
view must show; :func:`parameter_table` and :func:`truth_table` return markdown. Rerun draws a
point's label centred just below it, so text is placed by its points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calbench.bench.core import unit_display
from calbench.bench.log import IdentificationReport, ParameterEstimate

# chart geometry, in the 2D view's units (the view fits them; about one unit per pixel)
WIDTH = 400.0  # the axis, from its lowest to its highest tick
ROW = 22.0  # one parameter
NAME_X = -40.0  # centre of the name labels
LABEL_LIFT = 8.0  # a label hangs below its point: lift the point to centre it on a row
TICK = 3.0
GAP = 16.0  # between blocks


@dataclass
class Chart:
    """The chart's entities and the ranges of the 2D view that show all of it."""

    items: list[tuple[str, object]] = field(default_factory=list)
    x_range: tuple[float, float] = (NAME_X - 40.0, WIDTH + 30.0)
    y_range: tuple[float, float] = (-ROW, 0.0)


def nice_ticks(lo: float, hi: float, target: int = 5) -> np.ndarray:
    """Round tick values (1, 2 or 5 times a power of ten) covering [lo, hi]."""
    if not hi > lo:
        hi = lo + (abs(lo) or 1.0)
    raw = (hi - lo) / target
    mag = 10.0 ** math.floor(math.log10(raw))
    step = min((s * mag for s in (1, 2, 5, 10) if s * mag >= raw), default=10 * mag)
    return np.arange(math.floor(lo / step), math.ceil(hi / step) + 1) * step


def blocks(ident: IdentificationReport) -> list[tuple[str, list[ParameterEstimate]]]:
    """Parameters grouped by unit, in the report's order: one chart block per quantity."""
    out: dict[str, list[ParameterEstimate]] = {}
    for p in ident.parameters:
        out.setdefault(p.unit, []).append(p)
    return list(out.items())


def _fmt(x: float | None, std: float | None = None) -> str:
    """A value to the precision its std allows (two significant digits of the std)."""
    if x is None:
        return "-"
    dec = max(0, 1 - math.floor(math.log10(std))) if std else 3
    if abs(x) >= 1e5 or (x != 0 and abs(x) < 1e-3 and not std):
        return f"{x:.3g}"
    return f"{x:.{min(dec, 6)}f}"


def chart(rr, ident: IdentificationReport, colors: dict) -> Chart:
    """The chart (module doc); ``colors`` gives ``estimate``, ``truth``, ``text``, ``grid``
    and ``axis``. A block of one parameter carries its name in its title."""
    items: list[tuple[str, object]] = []
    keys = ["estimate"] + (["truth"] if ident.has_truth() else [])
    for i, (key, text) in enumerate(zip(keys, ("estimate ± 1 std (dot and bar)", "truth (tick)"))):
        items.append(
            (
                ("truth/" if key == "truth" else "") + "parameters/chart/legend",
                rr.Points2D(
                    [[WIDTH * (0.3 + 0.4 * i), -1.6 * ROW - LABEL_LIFT]],
                    radii=[0.0],
                    colors=[colors[key]],
                    labels=[text],
                    show_labels=True,
                ),
            )
        )
    y = 0.0
    for b, (unit, params) in enumerate(blocks(ident)):
        label, f = unit_display(unit)
        # the axis from the estimates alone (± 2 std), so that it reads the same with or without
        # the truth; a truth beyond it is drawn at its end
        vals = [
            v * f
            for p in params
            if p.estimate is not None
            for v in (p.estimate - 2 * (p.std or 0), p.estimate + 2 * (p.std or 0))
        ]
        ticks = nice_ticks(min([0.0] + vals), max([0.0] + vals))
        x0, x1 = float(ticks[0]), float(ticks[-1])

        def x(v: float, x0: float = x0, x1: float = x1) -> float:
            return (v - x0) / (x1 - x0) * WIDTH

        base = f"parameters/chart/{b}_{_slug(label)}"
        title = f"{params[0].name} ({label})" if len(params) == 1 else label
        items.append(
            (
                f"{base}/title",
                rr.Points2D(
                    [[WIDTH / 2, y - LABEL_LIFT]],
                    radii=[0.0],
                    colors=[colors["text"]],
                    labels=[title],
                    show_labels=True,
                ),
            )
        )
        y += ROW
        rows = y + ROW * np.arange(len(params))
        if len(params) > 1:
            items.append(
                (
                    f"{base}/names",
                    rr.Points2D(
                        [[NAME_X, r - LABEL_LIFT] for r in rows],
                        radii=[0.0],
                        colors=[colors["text"]],
                        labels=[p.name for p in params],
                        show_labels=True,
                    ),
                )
            )
        bars, dots, dot_labels, truths, truth_labels, missing = [], [], [], [], [], []
        for p, r in zip(params, rows):
            if p.truth is not None:
                tx = min(max(x(p.truth * f), 0.0), WIDTH)
                truths.append([[tx, r - ROW * 0.4], [tx, r + ROW * 0.4]])
                truth_labels.append(f"{p.name} truth {_fmt(p.truth * f, p.std and p.std * f)} {label}")
            if p.estimate is None:
                missing.append(r)
                continue
            e = p.estimate * f
            if p.std:
                bars.append([[x(e - p.std * f), r], [x(e + p.std * f), r]])
            dots.append([x(e), r])
            dot_labels.append(
                f"{p.name} = {_fmt(e, p.std and p.std * f)}"
                + (f" ± {_fmt(p.std * f, p.std * f)}" if p.std else "")
                + f" {label}"
            )
        grid = [[[x(t), y - ROW * 0.5], [x(t), rows[-1] + ROW * 0.5]] for t in ticks]
        items.append((f"{base}/grid", rr.LineStrips2D(grid, radii=[-0.5], colors=[colors["grid"]])))
        if truths:
            items.append(
                (
                    f"truth/{base}/truth",
                    rr.LineStrips2D(
                        truths, radii=[-2.0], colors=[colors["truth"]], labels=truth_labels, show_labels=False
                    ),
                )
            )
        if bars:
            items.append((f"{base}/std", rr.LineStrips2D(bars, radii=[-3.0], colors=[colors["estimate"]])))
        if dots:
            items.append(
                (
                    f"{base}/estimate",
                    rr.Points2D(
                        dots, radii=[-5.0], colors=[colors["estimate"]], labels=dot_labels, show_labels=False
                    ),
                )
            )
        if missing:
            items.append(
                (
                    f"{base}/not_identifiable",
                    rr.Points2D(
                        [[WIDTH / 2, r - LABEL_LIFT] for r in missing],
                        radii=[0.0],
                        colors=[colors["text"]],
                        labels=["not identifiable"] * len(missing),
                        show_labels=True,
                    ),
                )
            )
        axis_y = rows[-1] + ROW * 0.6
        items.append(
            (
                f"{base}/axis",
                rr.LineStrips2D([[[0.0, axis_y], [WIDTH, axis_y]]], radii=[-1.0], colors=[colors["axis"]]),
            )
        )
        items.append(
            (
                f"{base}/ticks",
                rr.Points2D(
                    [[x(t), axis_y + TICK] for t in ticks],
                    radii=[0.0],
                    colors=[colors["text"]],
                    labels=[f"{t:g}" for t in ticks],
                    show_labels=True,
                ),
            )
        )
        y = axis_y + TICK + ROW + GAP
    return Chart(items, y_range=(-2.4 * ROW, y - GAP))


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label).strip("_") or "unitless"


def _estimate(p: ParameterEstimate, f: float) -> str:
    sd = p.std * f if p.std else None
    if p.estimate is None:
        return "not identifiable"
    return _fmt(p.estimate * f, sd) + (f" ± {_fmt(sd, sd)}" if sd else "")


def parameter_table(ident: IdentificationReport) -> str:
    """Markdown: every parameter with its estimate ± std in display units (no truth)."""
    source = Path(ident.source).name if ident.source else "report"
    lines = [
        f"**{ident.method or 'identified'}** (`{source}`)",
        "",
        "| parameter | estimate ± std | unit |",
        "|---|---:|---|",
    ]
    for p in ident.parameters:
        label, f = unit_display(p.unit)
        lines.append(f"| {p.name} | {_estimate(p, f)} | {label} |")
    if reasons := [p for p in ident.parameters if p.reason]:
        lines += [""] + [f"- {p.name}: {p.reason}" for p in reasons]
    if ident.residual_rms is not None:
        lines += [
            "",
            f"Residual RMS {ident.residual_rms * 1e6:.1f} µm per axis"
            + (
                f" (noise alone leaves {ident.expected_residual_rms * 1e6:.1f} µm)"
                if ident.expected_residual_rms
                else ""
            )
            + ".",
        ]
    return "\n".join(lines)


def truth_table(ident: IdentificationReport) -> str | None:
    """Markdown: estimate, truth and z = (estimate - truth)/std of every parameter whose truth
    the report carries; None when it carries none."""
    if not ident.has_truth():
        return None
    lines = [
        "**Against the truth** (simulated log)",
        "",
        "| parameter | estimate ± std | truth | z | unit |",
        "|---|---:|---:|---:|---|",
    ]
    for p in ident.parameters:
        label, f = unit_display(p.unit)
        z = (
            p.z
            if p.z is not None
            else ((p.estimate - p.truth) / p.std if None not in (p.estimate, p.truth) and p.std else None)
        )
        truth = "-" if p.truth is None else _fmt(p.truth * f, p.std and p.std * f)
        lines.append(
            f"| {p.name} | {_estimate(p, f)} | {truth} | {'-' if z is None else f'{z:+.2f}'} | {label} |"
        )
    return "\n".join(lines)


__all__ = ["Chart", "chart", "parameter_table", "truth_table", "nice_ticks", "blocks"]
