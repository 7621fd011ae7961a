"""Fuzz of the inputs calbench gained after the first fuzz (issue 24), like tests/test_fuzz.py:
seeded mutations of a small valid file of each kind, run through the command that reads it.

* overlays (``from-urdf --overlay``), URDF and xacro (``from-urdf``), study files (``study``),
  compensation jobs (``compensate``), candidate sets (``design --from-candidates``): every case
  ends in exit 0, or exit 2 with one line naming the file (``compensate`` also exits 1 when a
  point cannot be reached, as documented: one line naming the point); never a traceback (an
  exception out of ``main`` fails the test); no input altered (SHA-256 before and after);
* probe series CSVs (bench/shopfloor/probe.py, read by the geometry workflow's tools): read or
  refused with an InputError naming the file, the line and the column, nothing else.

The mutations are those a hand, an editor or a disk makes: a key deleted or unknown, a value of
the wrong type, NaN or infinity, zero, negative or absurdly large, a list one too long or short
or empty; in XML an attribute set to junk, an element deleted or doubled, the text cut; in CSV a
cell set to junk, a column dropped, a line cut, bytes that are not UTF-8; in NPZ an array
missing, of the wrong shape, dtype (objects: must not be unpickled) or content, the file cut.
"""

from __future__ import annotations

import copy
import hashlib
import io
import math
import random
import re
import tomllib
import zipfile
from pathlib import Path

import badcases as bc
import numpy as np
import pytest
from test_fuzz import DELETE, set_path, toml
from test_probe_series import HEAD, row
from urdf_robots import arm_overlay, arm_urdf

from calbench.bench.core import InputError
from calbench.bench.shopfloor import read_probe_series, read_transform
from calbench.identify.cli import main
from calbench.identify.geometry import UR10_JOINTS

SEED = 24_2026
ROOT = Path(__file__).resolve().parent.parent


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run(argv: list[str], inputs: list[Path], blamed: Path, capsys, exit1: str | None = None) -> int:
    """One case through the command line: exit 0, or 2 with one line naming ``blamed`` (1 with
    one line matching ``exit1`` where the command documents it); the inputs unchanged."""
    before = {p: digest(p) for p in inputs}
    rc = main(argv)  # a traceback would be an exception here
    err = capsys.readouterr().err.strip()
    lines = [x for x in err.splitlines() if "warning" not in x and "note:" not in x]
    if rc == 2:
        assert len(lines) == 1 and str(blamed) in lines[0], (argv, err)
    elif rc == 1 and exit1 is not None:
        assert re.search(exit1, err), (argv, err)
    else:
        assert rc == 0, (argv, rc, err)
    for p, d in before.items():
        assert digest(p) == d, f"{p} was altered"
    return rc


# --------------------------------------------------------------------------- TOML inputs


def paths_of(doc, at=()):
    """Every (path, value) of a TOML document."""
    out = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.append((at + (k,), v))
            out += paths_of(v, at + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out.append((at + (i,), v))
            out += paths_of(v, at + (i,))
    return out


def toml_mutation(rng: random.Random, doc: dict) -> tuple[dict, str]:
    """A copy of ``doc`` with one thing changed (module docstring), and what."""
    m = copy.deepcopy(doc)
    path, value = rng.choice(paths_of(m))
    kind = rng.choice(["delete", "type", "nonfinite", "sign", "huge", "length", "unknown", "empty"])
    if kind == "delete" and isinstance(path[-1], str):
        set_path(m, path, DELETE)
    elif kind == "type":
        set_path(
            m, path, rng.choice(["x", [1], {"a": 1}, True, 3] if not isinstance(value, str) else [3, [1], {}])
        )
    elif kind == "nonfinite":
        set_path(m, path, rng.choice([math.nan, math.inf, -math.inf]))
    elif kind == "sign":
        set_path(m, path, rng.choice([0, -1, -0.5, 0.0]))
    elif kind == "huge":
        set_path(m, path, rng.choice([1e300, 10**18, -1e300, 2**63 - 1]))
    elif kind == "length" and isinstance(value, list) and value:
        set_path(m, path, value + value[-1:] if rng.random() < 0.5 else value[:-1])
    elif kind == "unknown":
        table = m
        for k in path[:-1]:
            table = table[k]
        if isinstance(table, dict):
            table["colour"] = 3
        else:
            set_path(m, path, "")
    else:
        set_path(m, path, [] if isinstance(value, list) else "")
    return m, f"{kind} {path}"


def fuzz_toml(base: Path, argv, capsys, n: int, seed: int, inputs=(), exit1=None) -> dict[int, int]:
    """``n`` mutations of the TOML file ``base`` through ``argv(path)``; returns the exit counts."""
    doc = tomllib.loads(base.read_text())
    rng = random.Random(seed)
    counts: dict[int, int] = {}
    for i in range(n):
        m, what = toml_mutation(rng, doc)
        bad = base.with_name(f"{base.stem}_m{i}.toml")
        bad.write_text(toml(m))
        try:
            rc = run(argv(bad), [bad, *inputs], bad, capsys, exit1)
        except AssertionError as e:
            raise AssertionError(f"case {i}: {what}: {e}\n{bad.read_text()}") from None
        counts[rc] = counts.get(rc, 0) + 1
        bad.unlink()
    return counts


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("arm")
    (d / "arm.urdf").write_text(arm_urdf())
    (d / "overlay.toml").write_text(arm_overlay())
    return d


def test_overlays(arm, capsys):
    urdf = arm / "arm.urdf"
    argv = lambda ov: ["from-urdf", str(urdf), "--overlay", str(ov), "--out", str(arm / "out.xml")]  # noqa: E731
    assert main(argv(arm / "overlay.toml")) == 0
    counts = fuzz_toml(arm / "overlay.toml", argv, capsys, 60, SEED, [urdf])
    assert counts.get(2, 0) >= 20, counts  # most mutations are refused


def xml_mutation(rng: random.Random, text: str) -> tuple[str, str]:
    """The URDF ``text`` with one thing changed (module docstring), and what."""
    attrs = list(re.finditer(r'(\w+)="([^"]*)"', text))
    elems = list(
        re.finditer(
            r"<(inertial|origin|axis|limit|mass|inertia|geometry|joint|link|parent|child)\b[^>]*/>", text
        )
    )
    kind = rng.choice(["attribute", "attribute", "attribute", "delete", "double", "cut", "junk"])
    if kind == "attribute":
        a = rng.choice(attrs)
        junk = rng.choice(["nan", "inf", "-1e308", "", "abc", "1 2", "-1", "0", "1e400", "0 0 0 0", "&amp;"])
        return text[: a.start(2)] + junk + text[a.end(2) :], f'{a.group(1)}="{junk}" at {a.start()}'
    if kind in ("delete", "double") and elems:
        e = rng.choice(elems)
        new = "" if kind == "delete" else e.group(0) * 2
        return text[: e.start()] + new + text[e.end() :], f"{kind} {e.group(0)[:60]}"
    if kind == "cut":
        n = rng.randrange(len(text))
        return text[:n], f"cut at {n}"
    n = rng.randrange(len(text))
    junk = rng.choice(["<", ">", "&", '"', "</robot>", "<link/>", "\x00", "<!-- "])
    return text[:n] + junk + text[n:], f"{junk!r} at {n}"


def test_urdf_and_xacro(arm, capsys):
    text = arm_urdf()
    assert (
        main(
            [
                "from-urdf",
                str(arm / "arm.urdf"),
                "--overlay",
                str(arm / "overlay.toml"),
                "--out",
                str(arm / "o.xml"),
            ]
        )
        == 0
    )
    rng = random.Random(SEED + 1)
    counts: dict[int, int] = {}
    for i in range(60):
        new, what = xml_mutation(rng, text)
        xacro = i % 4 == 3
        if xacro:  # the same robot through xacro: a property the mutation may break
            new = new.replace("<robot ", '<robot xmlns:xacro="http://www.ros.org/wiki/xacro" ', 1).replace(
                '<robot name="arm6">', '<robot name="arm6" xmlns:xacro="http://www.ros.org/wiki/xacro">'
            )
            new = re.sub(r"(<robot[^>]*>)", r'\1<xacro:property name="m1" value="600.0"/>', new, count=1)
            new = new.replace(
                'value="600.0"', rng.choice(['value="600.0"', 'value="${1/0}"', 'value="${m2}"']), 1
            )
        bad = arm / (f"u{i}.urdf.xacro" if xacro else f"u{i}.urdf")
        bad.write_text(new)
        argv = ["from-urdf", str(bad), "--overlay", str(arm / "overlay.toml"), "--out", str(arm / "out.xml")]
        try:
            rc = run(argv, [bad, arm / "overlay.toml"], bad, capsys)
        except AssertionError as e:
            raise AssertionError(f"case {i}: {what}: {e}") from None
        counts[rc] = counts.get(rc, 0) + 1
        bad.unlink()
    assert counts.get(2, 0) >= 20, counts


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """A 4-pose scenario, and the paper campaign's identification (every parameter determined:
    the job's --identified)."""
    d = tmp_path_factory.mktemp("campaign")
    (d / "small.toml").write_text(bc.scenario_text(n_poses=4))
    assert main(["simulate", str(ROOT / "scenarios/paper_table5.toml"), "--out", str(d / "paper.mcap")]) == 0
    assert main(["identify", str(d / "paper.mcap"), "--json", str(d / "id.json")]) == 0
    return d


def test_study_files(campaign, capsys):
    """A one-campaign study of the small scenario, mutated: refused up front, or run (small)."""
    d = campaign
    study = d / "study.toml"
    study.write_text(
        f'name = "tiny"\nscenario = "{d / "small.toml"}"\nseeds = 1\n\n'
        '[[axis]]\nkey = "tracker.sigma"\nvalues = [20e-6]\n'
    )
    argv = lambda s: ["study", str(s), "--out", str(d / f"{s.stem}.parquet")]  # noqa: E731
    assert main(argv(study)) == 0
    counts = fuzz_toml(study, argv, capsys, 20, SEED + 2, [d / "small.toml"])
    assert counts.get(2, 0) >= 8, counts


def test_compensation_jobs(campaign, capsys):
    d = campaign
    text = (ROOT / "scenarios/jobs/fanuc_milling.toml").read_text()
    head, *points = text.split("[[point]]")
    job = d / "job.toml"
    job.write_text(
        head.replace('robot = "../../mjcf/', f'robot = "{ROOT}/mjcf/')
        + "[[point]]"
        + "[[point]]".join(points[:3])
    )
    argv = lambda j: ["compensate", str(j), "--identified", str(d / "id.json"), "--out", str(d / "c.csv")]  # noqa: E731
    assert main(argv(job)) == 0
    counts = fuzz_toml(job, argv, capsys, 50, SEED + 3, [d / "id.json"], exit1=r"reach")
    assert counts.get(2, 0) >= 15, counts


# --------------------------------------------------------------------------- probe series


def csv_mutation(rng: random.Random, lines: list[str]) -> tuple[bytes, str]:
    """The probe series ``lines`` with one thing changed, as bytes."""
    lines = list(lines)
    kind = rng.choice(["cell", "cell", "cell", "column", "cut", "bytes", "header", "empty"])
    i = rng.randrange(len(lines))
    cells = lines[i].split(";")
    j = rng.randrange(len(cells))
    if kind == "cell":
        cells[j] = rng.choice(["", "x", "nan", "inf", "-inf", "1e400", "1,2,3", "-1", "99999", "0", " "])
        lines[i] = ";".join(cells)
    elif kind == "column":
        lines = [";".join(c for k, c in enumerate(line.split(";")) if k != j) for line in lines]
    elif kind == "cut":
        lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)]
        lines = lines[: i + 1]
    elif kind == "header":
        cells[j] = rng.choice(["joint_x", "measurement_x", "", "Timestamp"])
        lines[0] = ";".join(cells)
    elif kind == "empty":
        lines = lines[:1] if rng.random() < 0.5 else []
    data = ("\n".join(lines) + "\n").encode()
    if kind == "bytes":
        n = rng.randrange(len(data))
        data = data[:n] + b"\xff\xfe" + data[n:]
    return data, f"{kind} line {i + 1} column {j + 1}"


def test_probe_series(tmp_path):
    good = [HEAD, row(), row(q=(-3.0, -1.4, 0.1, -1.5, 0.1, 0.2)), row(p=(300.1, -3100.5, 250.0))]
    path = tmp_path / "series.csv"
    path.write_text("\n".join(good) + "\n")
    assert len(read_probe_series(path, UR10_JOINTS).q) == 3
    rng = random.Random(SEED + 4)
    refused = 0
    for i in range(150):
        data, what = csv_mutation(rng, good)
        bad = tmp_path / f"p{i}.csv"
        bad.write_bytes(data)
        try:
            read_probe_series(bad, UR10_JOINTS)
        except InputError as e:
            refused += 1
            text = str(e)
            assert text.startswith(str(bad)) and "\n" not in text, (what, text)
            assert re.search(r": (line \d+|file|header)", text), (what, text)
        except Exception as e:  # noqa: BLE001
            raise AssertionError(f"case {i}: {what}: {type(e).__name__}: {e}") from None
        assert bad.read_bytes() == data
    assert refused >= 60


def test_probe_transforms(tmp_path):
    good = "1 0 0 10\n0 1 0 20\n0 0 1 30\n0 0 0 1\n"
    rng = random.Random(SEED + 5)
    for i in range(60):
        nums = good.split()
        k = rng.randrange(len(nums))
        nums[k] = rng.choice(["x", "nan", "inf", "", "1e400", "2", "-1", "0.5"])
        if rng.random() < 0.2:
            nums = nums[: rng.randrange(len(nums))]
        bad = tmp_path / f"t{i}.txt"
        bad.write_text(" ".join(nums))
        try:
            t = read_transform(bad)
        except InputError as e:
            assert str(e).startswith(str(bad)) and "\n" not in str(e)
        else:
            assert t.shape == (4, 4) and np.all(np.isfinite(t))


# --------------------------------------------------------------------------- candidate sets


def npz_mutation(rng: random.Random, arrays: dict[str, np.ndarray]) -> tuple[bytes, str]:
    a = {k: v.copy() for k, v in arrays.items()}
    key = rng.choice(sorted(a))
    kind = rng.choice(["drop", "shape", "nan", "object", "empty", "cut", "dtype", "extra", "inf"])
    if kind == "drop":
        del a[key]
    elif kind == "shape":
        a[key] = a[key].reshape(-1)[: max(a[key].size - 1, 0)]
    elif kind in ("nan", "inf") and a[key].dtype.kind == "f" and a[key].size:
        a[key] = a[key].copy()
        a[key].flat[rng.randrange(a[key].size)] = math.nan if kind == "nan" else math.inf
    elif kind == "object":
        a[key] = np.array([{"x": 1}, "y"], dtype=object)
    elif kind == "empty":
        a[key] = a[key][:0]
    elif kind == "dtype":
        a[key] = a[key].astype(str)
    elif kind == "extra":
        a["colour"] = np.arange(3)
    buf = io.BytesIO()
    np.savez(buf, **a)
    data = buf.getvalue()
    if kind == "cut":
        data = data[: rng.randrange(len(data))]
    return data, f"{kind} {key}"


def test_candidate_sets(campaign, capsys):
    d = campaign
    good = d / "cands.npz"
    common = ["--configs", "4", "--processes", "1"]
    assert (
        main(
            ["design", str(d / "small.toml"), "--candidates", "40", "--export-candidates", str(good), *common]
        )
        == 0
    )
    with np.load(good, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    assert main(["design", "--from-candidates", str(good), *common]) == 0
    capsys.readouterr()
    rng = random.Random(SEED + 6)
    counts: dict[int, int] = {}
    for i in range(40):
        data, what = npz_mutation(rng, arrays)
        bad = d / f"c{i}.npz"
        bad.write_bytes(data)
        try:
            rc = run(["design", "--from-candidates", str(bad), *common], [bad], bad, capsys)
        except AssertionError as e:
            raise AssertionError(f"case {i}: {what}: {e}") from None
        counts[rc] = counts.get(rc, 0) + 1
        bad.unlink()
    assert counts.get(2, 0) >= 20, counts
    assert zipfile.is_zipfile(good)
