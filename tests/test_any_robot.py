"""Nothing in bench/ or identify/ knows the FANUC by name: the robot is its MJCF's description.

Two proofs. (1) A renamed copy of the FANUC MJCF (every body, joint, geom, site, tendon and
equality renamed; the description texts follow) gives the same numbers, bit for bit, through
simulate, identify (both methods), design's candidates and discover: the compensator tendon,
renamed, is read from ``[truth.compensators.<name>]`` and named ``<name>_stiffness`` /
``<name>_preload``. (2) No string constant in the code (docstrings aside) is the name of a
FANUC element, and the contract's words that are also FANUC names ("payload", "flange",
"compensator") never name an element in a lookup.
"""

from __future__ import annotations

import ast
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import MJCF, PAPER, ROOT

from calbench.bench.campaign import run_campaign
from calbench.bench.log import read_log
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.identify.report import run_identify

NAMED = ("body", "joint", "geom", "site", "spatial", "connect")
REFERENCES = ("site", "site1", "site2")


def renamed_copy(dst: Path) -> dict[str, str]:
    """Write the FANUC MJCF with every element renamed to an opaque ``partNN``; returns the map."""
    tree = ET.parse(MJCF)
    mapping: dict[str, str] = {}
    for el in tree.iter():
        if el.tag in NAMED and "name" in el.attrib:
            mapping[el.attrib["name"]] = f"part{len(mapping):02d}"
    for el in tree.iter():
        if el.tag in NAMED and "name" in el.attrib:
            el.attrib["name"] = mapping[el.attrib["name"]]
        for ref in REFERENCES:  # a tendon path's <site site=...>, a connect's site1/2
            if ref in el.attrib:
                el.attrib[ref] = mapping[el.attrib[ref]]
        if el.tag == "text" and el.attrib.get("name", "").startswith("calbench:"):
            el.attrib["data"] = " ".join(mapping[w] for w in el.attrib["data"].split())
    tree.write(dst)
    return mapping


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    """The paper campaign on the FANUC and on its renamed copy, simulated and identified."""
    tmp = tmp_path_factory.mktemp("twins")
    mapping = renamed_copy(tmp / "renamed.xml")
    comp = mapping["compensator"]
    text = PAPER.read_text(encoding="utf-8")
    text = re.sub(r'^robot = "[^"]*"', f'robot = "{(tmp / "renamed.xml").as_posix()}"', text, flags=re.M)
    assert "[truth.compensator]" in text
    text = text.replace("[truth.compensator]", f"[truth.compensators.{comp}]")
    (tmp / "renamed.toml").write_text(text, encoding="utf-8")
    out = {}
    for key, scn_path in (("fanuc", PAPER), ("renamed", tmp / "renamed.toml")):
        log = tmp / f"{key}.mcap"
        run_campaign(load_scenario(scn_path), log)
        out[key] = {
            "scenario": scn_path,
            "log": log,
            "one": run_identify(log),
            "two": run_identify(log, method="two-step"),
        }
    out["mapping"] = mapping
    return out


def test_the_renamed_copy_shares_no_name_with_the_fanuc(twins):
    fanuc, renamed = Robot.from_file(MJCF), Robot.from_file(twins["renamed"]["scenario"].with_suffix(".xml"))

    def names(m):
        return {
            mujoco.mj_id2name(m, k, i)
            for k, n in (
                (mujoco.mjtObj.mjOBJ_BODY, m.nbody),
                (mujoco.mjtObj.mjOBJ_JOINT, m.njnt),
                (mujoco.mjtObj.mjOBJ_SITE, m.nsite),
                (mujoco.mjtObj.mjOBJ_TENDON, m.ntendon),
                (mujoco.mjtObj.mjOBJ_EQUALITY, m.neq),
                (mujoco.mjtObj.mjOBJ_GEOM, m.ngeom),
            )
            for i in range(n)
        } - {None, "world"}

    assert names(fanuc.model) & names(renamed.model) == set()
    assert renamed.layout.names[6:] == (
        f"{twins['mapping']['compensator']}_stiffness",
        f"{twins['mapping']['compensator']}_preload",
    )


def test_the_renamed_copy_simulates_the_same_campaign(twins):
    a, b = (read_log(twins[k]["log"], include_truth=True) for k in ("fanuc", "renamed"))
    assert a.complete_poses == b.complete_poses and len(a.measurements) == len(b.measurements)
    for ma, mb in zip(a.measurements, b.measurements):
        assert [twins["mapping"][r] for r in ma.reflectors] == list(mb.reflectors)
        np.testing.assert_array_equal(ma.position, mb.position)  # bit for bit, NaN = NaN
        np.testing.assert_array_equal(ma.covariance, mb.covariance)
    for p in a.complete_poses:
        for s in ("unloaded", "loaded"):
            np.testing.assert_array_equal(a.truth.joints[p].get(s).qpos, b.truth.joints[p].get(s).qpos)
    np.testing.assert_array_equal(a.truth.parameters.compliance, b.truth.parameters.compliance)
    assert list(a.truth.parameters.springs.values()) == list(b.truth.parameters.springs.values())


@pytest.mark.parametrize("method", ["one", "two"])
def test_the_renamed_copy_identifies_the_same_numbers(twins, method):
    ra, rb = twins["fanuc"][method], twins["renamed"][method]
    comp = twins["mapping"]["compensator"]
    rename = {"compensator_stiffness": f"{comp}_stiffness", "compensator_preload": f"{comp}_preload"}
    assert [rename.get(p.name, p.name) for p in ra.parameters] == [p.name for p in rb.parameters]
    for pa, pb in zip(ra.parameters, rb.parameters):
        assert (pa.estimate, pa.std, pa.truth, pa.z) == (pb.estimate, pb.std, pb.truth, pb.z), pa.name
        assert pa.truth is not None and pa.estimate is not None
    assert ra.chi2 == rb.chi2


def test_the_renamed_copy_designs_the_same_candidates(twins):
    from calbench.identify.design import excluded_pairs, generate_candidates, load_design_scenario

    cands = {}
    for key in ("fanuc", "renamed"):
        scn, settings = load_design_scenario(twins[key]["scenario"])
        cands[key] = generate_candidates(scn, settings, n=40, processes=1)
    np.testing.assert_array_equal(cands["fanuc"].q, cands["renamed"].q)
    np.testing.assert_array_equal(cands["fanuc"].blocks, cands["renamed"].blocks)
    assert cands["fanuc"].stats["rejected_first_rule"] == cands["renamed"].stats["rejected_first_rule"]
    # the self-collision exclusions, derived from the model, are the FANUC's old table and the
    # turret against the world's weld group (the base and the floor), which MuJoCo never filters
    loop = ("upper_arm", "crank", "m1", "rod", "forearm", "m2")
    table = {tuple(sorted((a, b))) for a in loop for b in loop if a != b} | {
        ("rod", "turret"),
        ("forearm", "link5"),
        ("base", "turret"),
        ("turret", "world"),
    }
    assert set(excluded_pairs(Robot.from_file(MJCF), MJCF)) == table
    xml = twins["renamed"]["scenario"].with_suffix(".xml")
    m = {**twins["mapping"], "world": "world"}
    assert set(excluded_pairs(Robot.from_file(xml), xml)) == {tuple(sorted((m[a], m[b]))) for a, b in table}


def test_the_renamed_copy_discovers_the_same(twins, tmp_path):
    from calbench.identify.discover import discover

    reps = {
        k: discover(twins[k]["log"], plot=tmp_path / f"{k}.png", view_rrd=tmp_path / f"{k}.rrd")
        for k in ("fanuc", "renamed")
    }
    a, b = reps["fanuc"], reps["renamed"]
    assert a["named_effects"] == b["named_effects"]
    assert (a["rms_before"], a["rms_after"]) == (b["rms_before"], b["rms_after"])
    m = twins["mapping"]
    # the link candidates are the renamed robot's calbench:links; a joint's is its index (j1..j6)
    detail = lambda c: m[c["detail"]] if c["effect"] == "link_compliance" else c["detail"]  # noqa: E731
    assert [(c["effect"], detail(c), c["score"]) for c in a["candidates"]] == [
        (c["effect"], c["detail"], c["score"]) for c in b["candidates"]
    ]
    assert {c["effect"] for c in a["candidates"]} == {
        "compensator",
        "joint_nonlinearity",
        "link_compliance",
        "base_compliance",
        "tracker_drift",
    }


# --------------------------------------------------------------------------- the code itself


def fanuc_names() -> set[str]:
    m = mujoco.MjModel.from_xml_path(str(MJCF))
    kinds = (
        (mujoco.mjtObj.mjOBJ_BODY, m.nbody),
        (mujoco.mjtObj.mjOBJ_JOINT, m.njnt),
        (mujoco.mjtObj.mjOBJ_SITE, m.nsite),
        (mujoco.mjtObj.mjOBJ_GEOM, m.ngeom),
        (mujoco.mjtObj.mjOBJ_TENDON, m.ntendon),
        (mujoco.mjtObj.mjOBJ_EQUALITY, m.neq),
    )
    return {mujoco.mj_id2name(m, k, i) for k, n in kinds for i in range(n)} - {None, "world"}


# contract vocabulary that happens to be a FANUC name too: description keys (calbench:payload,
# calbench:flange), the [truth.compensator] key and the `compensator` effect, and the loop
# `parallelogram` that from-urdf makes of a parallelogram drawn as mimic joints (docs/contract.md)
CONTRACT_WORDS = {"payload", "flange", "compensator", "parallelogram"}
LOOKUPS = {"mj_name2id", "site", "body", "joint", "tendon", "geom", "equality", "delete"}


def string_constants(path: Path):
    """(line, value, inside a lookup call) of every str constant that is not a docstring."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and n.body
        and isinstance(n.body[0], ast.Expr)
        and isinstance(n.body[0].value, ast.Constant)
    }
    lookup_args = set()
    for n in ast.walk(tree):
        if isinstance(n, ast.Call):
            f = n.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in LOOKUPS:
                lookup_args |= {id(a) for a in n.args}
    for n in ast.walk(tree):
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs:
            yield n.lineno, n.value, id(n) in lookup_args


def test_no_fanuc_name_in_the_code():
    names = fanuc_names()
    assert {"j1", "elbow", "rod", "parallelogram", "refl_a", "link5", "m1", "upper_arm", "comp_base"} <= names
    bad = []
    for path in sorted((ROOT / "bench").rglob("*.py")) + sorted((ROOT / "identify").rglob("*.py")):
        for line, value, lookup in string_constants(path):
            if value in names - CONTRACT_WORDS or value.startswith("refl_") or (lookup and value in names):
                bad.append(f"{path.relative_to(ROOT)}:{line}: {value!r}")
    assert bad == []


def test_the_name_check_can_fail(tmp_path):
    """The checker itself finds a FANUC name, and a contract word used as an element name."""
    probe = tmp_path / "probe.py"
    probe.write_text('"""docstring: elbow"""\nA = "elbow"\nB = spec.site("payload")\nC = {"payload": 1}\n')
    found = [(v, lk) for _, v, lk in string_constants(probe)]
    assert ("elbow", False) in found and ("payload", True) in found and ("payload", False) in found
    assert all(v != "docstring: elbow" for v, _ in found)
