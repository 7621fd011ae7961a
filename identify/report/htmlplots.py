"""The calibration report's figures: matplotlib drawings returned as SVG data URIs.

SVG keeps the report sharp at any zoom and small (text stays text: ``svg.fonttype = none``);
a data URI keeps the HTML one self-contained file that opens offline. The drawings are
deterministic (fixed hash salt, no date in the metadata), so the same inputs give the same
report byte for byte. Every function takes plain arrays in display units (µm, %, µrad/(N·m))
and returns ``data:image/svg+xml;base64,...``.
"""

from __future__ import annotations

import base64
import io

import numpy as np
from matplotlib import rc_context
from matplotlib.colors import LinearSegmentedColormap
from matplotlib.figure import Figure

RC = {
    "svg.fonttype": "none",
    "svg.hashsalt": "calbench-report",
    "font.size": 9,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "font.family": "DejaVu Sans",
}
REFLECTOR_COLORS = ("#d95f02", "#1b9e77", "#7570b3", "#e7298a", "#66a61e", "#e6ab02")
NOISE_COLOR = "#444444"
# white at the noise level and below, to dark red at three times it
RATIO_CMAP = LinearSegmentedColormap.from_list(
    "ratio", ["#f7f7f7", "#f7f7f7", "#fdae61", "#d7301f", "#7f0000"]
)


def svg_uri(fig: Figure) -> str:
    buf = io.BytesIO()
    with rc_context(RC):
        fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(w: float, h: float) -> Figure:
    with rc_context(RC):
        return Figure(figsize=(w, h), dpi=96, layout="constrained")


def correlation_heatmap(names: list[str], corr: np.ndarray) -> str:
    """Correlation matrix, -1 (blue) to +1 (red), every cell annotated."""
    n = len(names)
    with rc_context(RC):
        fig = _figure(1.2 + 0.62 * n, 0.9 + 0.55 * n)
        ax = fig.add_subplot()
        im = ax.imshow(corr, cmap="RdBu_r", vmin=-1, vmax=1)
        ax.set_xticks(range(n), names, rotation=40, ha="right")
        ax.set_yticks(range(n), names)
        for i in range(n):
            for j in range(n):
                v = corr[i, j]
                ax.text(
                    j,
                    i,
                    f"{v:+.2f}",
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="white" if abs(v) > 0.6 else "black",
                )
        ax.spines[:].set_visible(False)
        fig.colorbar(im, ax=ax, shrink=0.8, label="correlation")
        return svg_uri(fig)


def residual_map(poses: list[int], reflectors: list[str], rms_um: np.ndarray, expected_um: float) -> str:
    """Per-axis residual RMS of each (reflector, pose), coloured by its ratio to the noise
    level, annotated in µm; blank where the reflector was not seen in both states."""
    ratio = rms_um / expected_um
    with rc_context(RC):
        fig = _figure(1.6 + 0.5 * len(poses), 0.9 + 0.42 * len(reflectors))
        ax = fig.add_subplot()
        im = ax.imshow(np.ma.masked_invalid(ratio), cmap=RATIO_CMAP, vmin=0, vmax=3, aspect="auto")
        for r in range(len(reflectors)):
            for c in range(len(poses)):
                if np.isfinite(rms_um[r, c]):
                    ax.text(
                        c,
                        r,
                        f"{rms_um[r, c]:.0f}",
                        ha="center",
                        va="center",
                        fontsize=7.5,
                        color="white" if ratio[r, c] > 2.2 else "black",
                    )
        ax.set_xticks(range(len(poses)), [str(p) for p in poses])
        ax.set_yticks(range(len(reflectors)), reflectors)
        ax.set_xlabel("pose")
        ax.spines[:].set_visible(False)
        fig.colorbar(im, ax=ax, label=f"RMS / noise ({expected_um:.1f} µm)", pad=0.01)
        return svg_uri(fig)


def residual_per_pose(poses: list[int], reflectors: list[str], rms_um: np.ndarray, expected_um: float) -> str:
    """Grouped bars: per-axis residual RMS per pose and reflector, the noise level and three
    times it as lines."""
    k = len(reflectors)
    width = 0.8 / max(k, 1)
    x = np.arange(len(poses))
    with rc_context(RC):
        fig = _figure(max(6.0, 0.45 * len(poses) + 2), 2.8)
        ax = fig.add_subplot()
        for i, name in enumerate(reflectors):
            ax.bar(
                x + (i - (k - 1) / 2) * width,
                np.nan_to_num(rms_um[i]),
                width,
                label=name,
                color=REFLECTOR_COLORS[i % len(REFLECTOR_COLORS)],
            )
        ax.axhline(expected_um, color=NOISE_COLOR, ls="--", lw=1, label=f"noise level {expected_um:.1f} µm")
        ax.axhline(3 * expected_um, color=NOISE_COLOR, ls=":", lw=1, label="3 × noise")
        ax.set_xticks(x, [str(p) for p in poses])
        ax.set_xlabel("pose")
        ax.set_ylabel("residual RMS per axis (µm)")
        ax.legend(ncols=k + 2, fontsize=8, loc="upper left", frameon=False, bbox_to_anchor=(0, 1.15))
        return svg_uri(fig)


def relative_std_bars(names: list[str], rel_pct: list[float | None]) -> str:
    """Relative standard deviation (%) of each parameter, log scale; none: not identifiable."""
    vals = np.array([np.nan if v is None else v for v in rel_pct], float)
    with rc_context(RC):
        fig = _figure(max(5.0, 0.7 * len(names) + 1.5), 2.6)
        ax = fig.add_subplot()
        y = np.arange(len(names))
        ax.barh(y, np.nan_to_num(vals, nan=0.0), color="#3b75af")
        for i, v in enumerate(vals):
            ax.text(
                v * 1.08 if np.isfinite(v) else 0,
                i,
                f"{v:.2g} %" if np.isfinite(v) else "not identifiable",
                va="center",
                fontsize=8,
            )
        ax.set_yticks(y, names)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ok = vals[np.isfinite(vals) & (vals > 0)]
        if ok.size:
            ax.set_xlim(ok.min() / 2, ok.max() * 6)
        ax.set_xlabel("relative standard deviation (%)")
        return svg_uri(fig)


def before_after(
    poses: list[int],
    before_um: list[float],
    after_um: list[float] | None,
    noise_before_um: float,
    noise_after_um: float,
) -> str:
    """Discovery: residual RMS per pose with the user's model and (``after_um`` not None) with
    the named effects."""
    x = np.arange(len(poses))
    w = 0.4 if after_um is not None else 0.7
    with rc_context(RC):
        fig = _figure(max(6.0, 0.45 * len(poses) + 2), 2.8)
        ax = fig.add_subplot()
        ax.bar(x - (0.2 if after_um is not None else 0), before_um, w, color="#c44e52", label="user's model")
        if after_um is not None:
            ax.bar(x + 0.2, after_um, w, color="#4c72b0", label="with the named effects")
        ax.axhline(
            noise_before_um, color=NOISE_COLOR, ls="--", lw=1, label=f"noise level {noise_before_um:.1f} µm"
        )
        if abs(noise_after_um - noise_before_um) > 0.05:
            ax.axhline(
                noise_after_um,
                color=NOISE_COLOR,
                ls=":",
                lw=1,
                label=f"noise level after {noise_after_um:.1f} µm",
            )
        ax.set_xticks(x, [str(p) for p in poses])
        ax.set_xlabel("pose")
        ax.set_ylabel("residual RMS per axis (µm)")
        ax.legend(ncols=4, fontsize=8, loc="upper left", frameon=False, bbox_to_anchor=(0, 1.15))
        return svg_uri(fig)


__all__ = [
    "correlation_heatmap",
    "residual_map",
    "residual_per_pose",
    "relative_std_bars",
    "before_after",
    "svg_uri",
]
