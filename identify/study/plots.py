"""Plots of a study (matplotlib, PNG): accuracy against each axis, power curves of discovery.

* ``accuracy_<axis>.png``: per value of the axis (pooled over the other axes), the RMS relative
  error of every identified parameter (log scale), and the honesty of the reported std: RMS z
  (1 when honest) and the coverage of +-2 sigma (95.4 % when honest).
* ``power_<axis>.png`` (studies that run discover, numeric axes): the share of campaigns naming
  the expected effect first against the axis, one curve per combination of the other axes'
  values, with binomial error bars (2 standard errors).
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import numpy as np

from .spec import Study


def _numeric(values) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def axis_ticks(values):
    """Positions and tick labels: the values themselves when numeric, else 0, 1, 2, ... labelled
    by the value, a plan file by its name (a path across the axis hid its neighbours' labels)."""
    if _numeric(values):
        return np.array(values, float), None
    return np.arange(len(values), dtype=float), [_label(v) for v in values]


def _label(v) -> str:
    s = str(v)
    return Path(s).name if s.endswith(".toml") else s


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


def accuracy_plots(study: Study, pooled: dict, folder: Path) -> list[Path]:
    plt = _pyplot()
    out = []
    for a in study.axes:
        rows = pooled[a.name]
        x, labels = axis_ticks([r["value"] for r in rows])
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
        for p in study.param_names:
            y = [r["parameters"][p].get("rms_relative_error") for r in rows]
            if all(v is None for v in y):
                continue
            ax1.plot(x, [np.nan if v is None else 100 * v for v in y], "o-", label=p)
        ax1.set_yscale("log")
        ax1.set_ylabel("RMS relative error (%)")
        if ax1.lines:
            ax1.legend(fontsize=7, ncol=2)
        ax2.plot(x, [np.nan if r["rms_z"] is None else r["rms_z"] for r in rows], "o-", label="RMS z")
        ax2.plot(
            x,
            [np.nan if r["coverage_2sigma"] is None else r["coverage_2sigma"] for r in rows],
            "s-",
            label="coverage of ±2σ",
        )
        ax2.axhline(1.0, color="grey", lw=0.8)
        ax2.axhline(0.954, color="grey", lw=0.8, ls="--")
        ax2.set_ylim(0.0, max(1.5, *[r["rms_z"] or 0 for r in rows]) * 1.05)
        ax2.set_ylabel("honesty of the reported std")
        ax2.legend(fontsize=8)
        for ax in (ax1, ax2):
            ax.set_xlabel(a.name)
            if labels is not None:
                ax.set_xticks(x, labels, rotation=20, fontsize=8)
            elif x.min() > 0 and x.max() / x.min() >= 10:
                ax.set_xscale("log")
            ax.grid(alpha=0.3)
        fig.suptitle(f"{study.name}: accuracy against {a.name} (pooled over the other axes)")
        out.append(_save(fig, folder / f"accuracy_{_slug(a.name)}.png"))
    return out


def power_plots(study: Study, cells: list[dict], folder: Path, max_curves: int = 12) -> list[Path]:
    plt = _pyplot()
    out = []
    if not any(c["detection_rate"] is not None for c in cells):
        return out
    for a in study.axes:
        if not _numeric(a.column):
            continue
        others = [b for b in study.axes if b is not a]
        combos = list(itertools.product(*[b.column for b in others])) or [()]
        if len(combos) > max_curves:
            continue
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for combo in combos:
            want = dict(zip([b.name for b in others], combo))
            pts = [
                (c["values"][a.name], c["detection_rate"], c["campaigns"] - c["failed"])
                for c in cells
                if all(c["values"][k] == v for k, v in want.items()) and c["detection_rate"] is not None
            ]
            if not pts:
                continue
            pts.sort()
            xv = np.array([p[0] for p in pts], float)
            pv = np.array([p[1] for p in pts], float)
            nv = np.maximum([p[2] for p in pts], 1)
            err = 2 * np.sqrt(pv * (1 - pv) / nv)
            ax.errorbar(
                xv,
                pv,
                yerr=err,
                marker="o",
                capsize=3,
                label=", ".join(f"{k}={v}" for k, v in want.items()) or "all",
            )
        ax.axhline(0.9, color="grey", lw=0.8, ls="--")
        ax.set_ylim(-0.05, 1.05)
        ax.set_xlabel(a.name)
        ax.set_ylabel("share naming the expected effect first")
        ax.set_title(f"{study.name}: detection power against {a.name}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        out.append(_save(fig, folder / f"power_{_slug(a.name)}.png"))
    return out


__all__ = ["accuracy_plots", "power_plots"]
