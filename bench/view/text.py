"""The words of the Rerun view: one markdown page per pose (the numbers the 3D arrows carry
no labels for) and the legend that says what each colour means.

Pure functions of arrays and strings; bench/view/recording.py logs their results as ``rr.TextDocument``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calbench.bench.log import WrenchRecord


@dataclass(frozen=True)
class Legend:
    """What the 3D view shows, for the legend's lines."""

    magnify: float
    residual_magnify: float
    truth_ghost: bool = False
    model_ghost: bool = False
    ghost_note: str = ""  # why there is no model ghost, or what it assumes
    truth: bool = False
    predicted: bool = False  # model arrows and residuals (identify)
    discovery: bool = False  # residuals before/after (discover)
    robot_colour: str = "yellow"  # the colour most of the robot's geoms are drawn in (colour_name)


PALETTE = {
    "yellow": (0.95, 0.8, 0.1),
    "orange": (1.0, 0.5, 0.0),
    "red": (0.8, 0.1, 0.1),
    "green": (0.2, 0.7, 0.2),
    "blue": (0.2, 0.3, 0.8),
    "white": (0.95, 0.95, 0.95),
    "grey": (0.6, 0.6, 0.6),
    "dark grey": (0.3, 0.3, 0.3),
    "black": (0.05, 0.05, 0.05),
}


def colour_name(rgba: np.ndarray) -> str:
    """The palette name nearest (RGB distance) to most of the colours ``rgba`` (n, 4); "grey"
    when there are none (MuJoCo's default geom colour)."""
    rgb = np.asarray(rgba, float).reshape(-1, 4)[:, :3]
    if not len(rgb):
        return "grey"
    names = list(PALETTE)
    ref = np.array([PALETTE[n] for n in names])
    nearest = np.argmin(np.linalg.norm(rgb[:, None, :] - ref[None], axis=2), axis=1)
    return names[int(np.bincount(nearest, minlength=len(names)).argmax())]


def legend(g: Legend) -> str:
    """Markdown bullet list: each colour of the 3D view and what it is."""
    f, fr = f"×{g.magnify:g}", f"×{g.residual_magnify:g}"
    lines = [
        f"**{g.robot_colour} robot**: at the commanded angles (all a real campaign knows of its pose); "
        "grey dots on the posts: the reflectors as measured unloaded"
    ]
    if g.truth_ghost:
        lines.append(
            f"**green ghost**: the true loaded robot, joint deflections {f} (simulation "
            "only" + ("; hidden: show `truth` in the blueprint panel)" if g.model_ghost else ")")
        )
    if g.model_ghost:
        lines.append(f"**blue ghost**: the identified model's loaded robot, joint deflections {f}")
    if g.ghost_note:
        lines.append(f"model ghost: {g.ghost_note}")
    if not (g.truth_ghost or g.model_ghost or g.discovery):
        lines.append(
            "no ghost: a real campaign measures reflectors, not joints (`--identified` "
            "draws the identified model's)"
        )
    lines.append(f"**orange arrows**: measured deflection {f}, loaded − unloaded (tip ellipsoid: its 3σ)")
    if g.truth:
        lines.append(f"**green arrows**: true deflection {f}")
    if g.predicted:
        lines.append(f"**blue arrows**: the model's deflection {f}")
        lines.append(
            f"**magenta arrows**: residual, measured − model, {fr}, ending at the "
            f"measured tip; **grey wire ball**: 3σ of the noise {fr}: an arrow that "
            "starts inside it is noise"
        )
    if g.discovery:
        lines.append(
            f"**magenta arrows**: residual of the user's model {fr}, **violet**: with "
            f"the named effects; both end at the measured tip; **grey wire ball**: 3σ "
            f"of the noise {fr}: an arrow that starts inside it is noise"
        )
    lines.append("**grey lines**: the tracker's lines of sight")
    return "\n".join(f"- {line}" for line in lines)


def load_text(w: WrenchRecord | None, gravity: float) -> str:
    """The load in words; a payload's weight under ``gravity`` (m/s², the robot model's
    ``|opt.gravity|``, not a constant: the MJCF may set another)."""
    if w is None:
        return "no load recorded"
    if w.mass is not None:
        return f"{w.mass:g} kg payload at the tool ({w.mass * gravity / 1e3:.2f} kN)"
    f = ", ".join(f"{x / 1e3:.2f}" for x in w.force)
    m = np.linalg.norm(w.moment)
    return f"force ({f}) kN at `{w.site}`" + (f" and a moment of {m / 1e3:.2f} kN·m" if m else "")


def _mm(v: np.ndarray) -> str:
    return f"{np.linalg.norm(v) * 1e3:.3f} mm"


def sigmas(r: np.ndarray, cov: np.ndarray) -> float:
    """Mahalanobis length sqrt(r' C^-1 r) of a residual against its noise covariance (noise
    alone gives about 1.6 for a 3-vector)."""
    return float(np.sqrt(r @ np.linalg.solve(cov, r)))


def pose_table(
    names: list[str], measured: np.ndarray, cov: np.ndarray, columns: dict[str, np.ndarray]
) -> list[str]:
    """Markdown rows: per reflector the measured deflection and, per extra column, its value:
    a deflection (``name`` ends in "deflection": shown in mm) or a residual (µm and sigmas).
    Rows are NaN where the reflector was not seen in both states."""
    head = ["reflector", "measured"] + list(columns)
    lines = ["| " + " | ".join(head) + " |", "|---" + "|---:" * (len(head) - 1) + "|"]
    for i, nm in enumerate(names):
        if not np.all(np.isfinite(measured[i])):
            lines.append(f"| {nm} | not seen in both states" + " |" * len(columns) + " |")
            continue
        cells = [nm, _mm(measured[i])]
        for title, vals in columns.items():
            v = vals[i]
            if not np.all(np.isfinite(v)):
                cells.append("-")
            elif title.endswith("deflection"):
                cells.append(_mm(v))
            else:
                cells.append(f"{np.linalg.norm(v) * 1e6:.0f} µm ({sigmas(v, cov[i]):.1f}σ)")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def pose_page(
    index: int,
    n_poses: int,
    command: np.ndarray,
    wrench: WrenchRecord | None,
    sag: np.ndarray,
    table: list[str],
    gravity: float,
    header: str = "",
    footer: str = "",
) -> str:
    """The markdown page of one pose (``gravity``: see :func:`load_text`)."""
    q = ", ".join(f"{np.degrees(x):.0f}" for x in command)
    s = sag[np.isfinite(sag)]
    lines = ([header, ""] if header else []) + [
        f"### Pose {index} ({n_poses} poses) · q = ({q})°",
        f"Load: {load_text(wrench, gravity)}.",
    ]
    if s.size:
        lo, hi = f"{1e3 * s.min():.0f}", f"{1e3 * s.max():.0f}"
        lines.append(
            f"Unloaded, the reflectors sit {lo if lo == hi else f'{lo}–{hi}'} mm from "
            "their posts: the arm sags under its own weight from the command."
        )
    lines += [""] + table
    if footer:
        lines += ["", footer]
    return "\n".join(lines)


__all__ = ["Legend", "legend", "load_text", "sigmas", "pose_table", "pose_page"]
