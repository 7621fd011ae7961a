"""6-DoF probe series in a `;`-separated, `,`-decimal CSV: real readings in, SI out.

The form is that of the public UR10 laser-tracker dataset (christianlandgraf/ipa-robot-accuracy,
Landgraf et al., CASE 2021; docs/geometry.md), one row per pose:

    Timestamp;Goal x;...;Goal yaw;<joint 1>;...;<joint n>;measurement_temperature;
    measurement_x[;measurement_std_x];measurement_y[...];measurement_z[...];
    measurement_rx[;measurement_std_rx];measurement_ry[...];measurement_rz[...]

* joint columns: the robot's joint names, in its order, in rad;
* ``measurement_x, y, z``: the probe (a Leica T-Mac) in the tracker's frame, in mm;
  ``measurement_rx, ry, rz``: its orientation there, in degrees (read as R = Rz Ry Rx, the fixed-axis
  x-y-z convention; the geometric fit uses positions only, so the convention only matters to
  whoever uses :attr:`ProbeSeries.rotation`);
* ``measurement_std_*``: the tracker's per-axis 1-sigma of that row (mm, deg), optional
  (series A of the dataset has none);
* ``measurement_temperature``: ambient, degrees Celsius. Goal and Timestamp are kept as given.

Every bad value is an InputError naming the file, the line and the column (exit 2): a non-number,
a header that lacks a column or whose joint names are not the robot's, a joint angle beyond one
turn (the unit is degrees, not rad), orientations that all lie within +-pi (radians, not degrees),
positions that are all within 10 (metres, not mm), a std that is negative. The 4x4 transforms
(``Trafo_TM_F_init.txt``: probe to flange, mm) are read by :func:`read_transform`, which refuses a
rotation block that is not a rotation (not orthonormal to 1e-5, or a reflection).

Units: SI inside (m, rad, and degrees Celsius for temperature).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError

POSITION = ("measurement_x", "measurement_y", "measurement_z")
ORIENTATION = ("measurement_rx", "measurement_ry", "measurement_rz")
TEMPERATURE = "measurement_temperature"
GOAL = ("Goal x", "Goal y", "Goal z", "Goal roll", "Goal pitch", "Goal yaw")
MM = 1e-3
# A joint of a six-axis arm turns at most +-2 pi (UR joints: +-360 deg); a value beyond that by more
# than rounding is an angle in degrees.
MAX_JOINT = 2 * math.pi + 1e-3  # rad
# A tracker measures from ~0.3 m; positions all within 10 of zero are metres, not mm.
MIN_SPREAD_MM = 10.0
ORTHO_TOL = 1e-5  # |R^T R - I| of a rotation written with 8 digits


@dataclass(frozen=True)
class ProbeSeries:
    """A validated series: one row per pose, SI, tracker frame for the measurements."""

    path: Path
    joint_names: tuple[str, ...]
    line: np.ndarray  # (n,) 1-based line of each row in the file
    q: np.ndarray  # (n, dof) rad, the controller's joint angles
    position: np.ndarray  # (n, 3) m, probe origin in the tracker frame
    rotation: np.ndarray  # (n, 3, 3) tracker from probe
    position_std: np.ndarray | None  # (n, 3) m, or None when the file gives none
    angle_std: np.ndarray | None  # (n, 3) rad
    temperature: np.ndarray  # (n,) degrees Celsius
    goal: np.ndarray  # (n, 6) the commanded pose as written (m, rad), NaN where absent

    def __len__(self) -> int:
        return len(self.q)


def _number(path: Path, line: int, column: str, text: str) -> float:
    try:
        value = float(text.strip().replace(",", "."))
    except ValueError:
        raise InputError(path, f"line {line}, column {column}", "a number", text) from None
    if not math.isfinite(value):
        raise InputError(path, f"line {line}, column {column}", "a finite number", text)
    return value


def euler_xyz(angles: np.ndarray) -> np.ndarray:
    """R = Rz(c) Ry(b) Rx(a) for rows of (a, b, c) in rad: (n, 3) -> (n, 3, 3)."""
    a, b, c = np.asarray(angles, float).T
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    r = np.empty((len(a), 3, 3))
    r[:, 0] = np.stack([cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa], axis=1)
    r[:, 1] = np.stack([sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa], axis=1)
    r[:, 2] = np.stack([-sb, cb * sa, cb * ca], axis=1)
    return r


def _columns(path: Path, header: list[str], joint_names: Sequence[str]) -> dict[str, int]:
    """Column index of every name the series needs; InputError naming the first missing one."""
    index = {name.strip(): i for i, name in enumerate(header)}
    found = [h.strip() for h in header if h.strip().endswith("_joint") or h.strip() in joint_names]
    if list(found) != list(joint_names):
        raise InputError(path, "line 1, joint columns", f"the robot's joints {list(joint_names)}", found)
    for name in (*POSITION, *ORIENTATION, TEMPERATURE):
        if name not in index:
            raise InputError(path, f"line 1, column {name}", "a column of that name", None)
    return index


def read_probe_series(path: str | Path, joint_names: Sequence[str]) -> ProbeSeries:
    """Read and check one series file against the robot's joint names (in the robot's order)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except OSError as e:
        raise InputError(path, "file", "a readable CSV file", e.strerror) from None
    except UnicodeDecodeError as e:
        line = path.read_bytes()[: e.start].count(b"\n") + 1
        raise InputError(path, f"line {line}", "UTF-8 text", str(e)) from None
    if len(lines) < 2:
        raise InputError(path, "line 2", "a header and at least one row", f"{len(lines)} line(s)")
    header = lines[0].split(";")
    col = _columns(path, header, joint_names)
    wanted = {
        "q": list(joint_names),
        "p": list(POSITION),
        "r": list(ORIENTATION),
        "ps": [n.replace("measurement_", "measurement_std_") for n in POSITION],
        "rs": [n.replace("measurement_", "measurement_std_") for n in ORIENTATION],
        "t": [TEMPERATURE],
        "g": list(GOAL),
    }
    has_std = all(n in col for n in wanted["ps"] + wanted["rs"])
    values: dict[str, list[list[float]]] = {k: [] for k in wanted}
    numbers = []
    for k, text in enumerate(lines[1:], start=2):
        if not text.strip():
            continue
        cells = text.split(";")
        if len(cells) != len(header):
            raise InputError(path, f"line {k}", f"{len(header)} ';'-separated cells", len(cells))
        numbers.append(k)
        for key, names in wanted.items():
            if key in ("ps", "rs") and not has_std:
                continue
            row = [
                _number(path, k, n, cells[col[n]]) if n in col else math.nan
                for n in names
                if key == "g" or n in col
            ]
            values[key].append(row)
        for n, v in zip(joint_names, values["q"][-1], strict=True):
            if abs(v) > MAX_JOINT:
                raise InputError(path, f"line {k}, column {n}", "a joint angle in rad (|q| <= 2 pi)", v)
        if has_std:
            for n, v in zip(wanted["ps"] + wanted["rs"], values["ps"][-1] + values["rs"][-1], strict=True):
                if v < 0:
                    raise InputError(path, f"line {k}, column {n}", "a std >= 0", v)
        for n, v in zip(ORIENTATION, values["r"][-1], strict=True):
            if abs(v) > 360.0:
                raise InputError(path, f"line {k}, column {n}", "an angle in degrees within +-360", v)
    rot = np.asarray(values["r"])
    if len(rot) >= 3 and np.all(np.abs(rot) <= math.pi):
        raise InputError(
            path, f"lines 2-{numbers[-1]}, columns {', '.join(ORIENTATION)}",
            "orientations in degrees (every value lies within +-pi: radians?)", None,
        )  # fmt: skip
    pos = np.asarray(values["p"])
    if len(pos) >= 3 and np.all(np.abs(pos) <= MIN_SPREAD_MM):
        raise InputError(
            path, f"lines 2-{numbers[-1]}, columns {', '.join(POSITION)}",
            "positions in mm (every value lies within +-10: metres?)", None,
        )  # fmt: skip
    return ProbeSeries(
        path=path,
        joint_names=tuple(joint_names),
        line=np.asarray(numbers),
        q=np.asarray(values["q"]),
        position=pos * MM,
        rotation=euler_xyz(np.radians(rot)),
        position_std=np.asarray(values["ps"]) * MM if has_std else None,
        angle_std=np.radians(np.asarray(values["rs"])) if has_std else None,
        temperature=np.asarray(values["t"])[:, 0],
        goal=np.asarray(values["g"]),
    )


def read_transform(path: str | Path) -> np.ndarray:
    """A 4x4 homogeneous transform written as 16 numbers (rows; translation in mm) -> SI (m).

    The dataset writes it without line breaks between rows; any whitespace separates numbers."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(path, "file", "a readable transform file", e.strerror) from None
    except UnicodeDecodeError as e:
        raise InputError(path, "file", "a UTF-8 text file", str(e)) from None
    # the rows run together as "... 1.-0.00079 ..." or "1.0. 0.": split a number after its "."
    cells = text.replace("\n", " ").split()
    numbers: list[float] = []
    for cell in cells:
        numbers.extend(_split_run(path, cell))
    if len(numbers) != 16:
        raise InputError(path, "matrix", "16 numbers (a 4x4 transform)", len(numbers))
    t = np.asarray(numbers).reshape(4, 4)
    if not np.all(np.isfinite(t)):
        i, j = np.argwhere(~np.isfinite(t))[0]
        raise InputError(path, f"row {i + 1}, column {j + 1}", "a finite number", float(t[i, j]))
    r = t[:3, :3]
    err = np.abs(r.T @ r - np.eye(3))
    if not err.max() <= ORTHO_TOL or np.linalg.det(r) < 0:
        i, j = np.unravel_index(int(np.argmax(err)), err.shape)
        raise InputError(
            path, f"rows 1-3, columns 1-3 (worst entry row {i + 1}, column {j + 1})",
            f"a rotation (orthonormal to {ORTHO_TOL:g}, det +1)",
            f"|R^T R - I| = {err.max():.3g}, det {np.linalg.det(r):.6g}",
        )  # fmt: skip
    out = t.copy()
    out[:3, 3] *= MM
    return out


def _split_run(path: Path, cell: str) -> list[float]:
    """'1.-0.5' -> [1.0, -0.5]; '1.0.' -> [1.0, 0.0]: numbers written as 'int.' run together."""
    out: list[float] = []
    rest = cell
    while rest:
        head, dot, tail = rest.partition(".")
        if not dot:
            out.append(_matrix_number(path, head))
            break
        digits = len(tail) - len(tail.lstrip("0123456789"))
        frac, rest = tail[:digits], tail[digits:]
        if rest and rest[0] in "eE":
            exp_end = 1 + (rest[1:2] in "+-")
            exp_end += len(rest[exp_end:]) - len(rest[exp_end:].lstrip("0123456789"))
            frac, rest = frac + rest[:exp_end], rest[exp_end:]
        out.append(_matrix_number(path, f"{head}.{frac}"))
    return out


def _matrix_number(path: Path, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(path, "matrix", "16 numbers (a 4x4 transform)", text) from None


def series_files(folder: str | Path) -> tuple[Path, Path]:
    """A series folder of the public dataset (``Series_X``): its one ``measurements_*.csv`` (for
    :func:`read_probe_series`) and the probe's ``Trafo_TM_F_init.txt`` (for :func:`read_transform`);
    InputError naming the folder when either is missing or the CSV is not alone."""
    folder = Path(folder)
    found = sorted(folder.glob("measurements_*.csv"))
    if len(found) != 1:
        raise InputError(folder, "measurements_*.csv", "one probe series CSV in the folder", len(found))
    transform = folder / "Trafo_TM_F_init.txt"
    if not transform.is_file():
        raise InputError(folder, transform.name, "the probe-to-flange transform", "no such file")
    return found[0], transform


def campaign_files(
    series: ProbeSeries, rows: np.ndarray, robot: str, point: str = "probe", sigma: float = 20e-6
) -> tuple[str, str]:
    """A plan (TOML) and readings (CSV, mm) of the given rows for ``calbench import``.

    The plan's poses are the rows' joint angles (degrees, 9 digits: 1e-9 deg, far below any
    encoder); each row is one ``unloaded`` reading of ``point`` (the probe's site in ``robot``,
    the MJCF path as the plan should name it, relative to the plan). A plan needs a ``[load]``;
    with no loaded reading its mass is never used. The readings' ``sigma`` column is each row's
    largest per-axis std, where the series has them; ``sigma`` is the plan's tracker noise."""
    plan = [
        f'robot = "{robot}"',
        f'name = "{series.path.stem}"',
        "[tracker]",
        f"sigma = {sigma:.6g}",
        "[load]",
        "mass = 1.0  # required by a plan; no loaded readings, never used",
    ]
    for q in series.q[rows]:
        plan += ["[[pose]]", "q = [" + ", ".join(f"{v:.9f}" for v in np.degrees(q)) + "]"]
    has_std = series.position_std is not None
    out = ["pose,state,point,x,y,z" + (",sigma" if has_std else "")]
    for k, i in enumerate(rows):
        x, y, z = series.position[i] / MM
        line = f"{k},unloaded,{point},{x:.6f},{y:.6f},{z:.6f}"
        if has_std:
            line += f",{max(series.position_std[i].max(), 1e-7) / MM:.7f}"
        out.append(line)
    return "\n".join(plan) + "\n", "\n".join(out) + "\n"
