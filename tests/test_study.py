"""`calbench study`: the grid, its validation before any task, the Parquet results and resuming.

In-process and small (the cluster is tests/test_cluster.py's): 2-3 cells of 2-3 identify-only
campaigns of the paper plan.
"""

from __future__ import annotations

import math

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import PAPER

from calbench.bench.core import InputError
from calbench.identify.cli import main
from calbench.identify.study import TIMING_COLUMNS, design_key, load_study, prepare, run_study, scaled

BASE = f'scenario = "{PAPER.as_posix()}"\n'


def write(tmp_path, body: str, name: str = "study.toml"):
    p = tmp_path / name
    p.write_text(body)
    return p


@pytest.mark.parametrize(
    "body, key, expected",
    [
        (
            BASE + 'seeds = 2\n[[axis]]\nkey = "tracker.sigmaa"\nvalues = [1e-5]\n',
            "tracker.sigmaa",
            "no such key",
        ),
        (BASE + 'seeds = 2\n[[axis]]\nkey = "tracker.sigma"\nvalues = []\n', "axis[0].values", "non-empty"),
        (
            BASE + 'seeds = 2\n[[axis]]\nkey = "tracker.sigma"\nvalues = [2e-5, -1e-5]\n',
            "tracker.sigma",
            "> 0",
        ),
        (BASE + 'seeds = 2\n[[axis]]\nkey = "load.mass"\nvalues = ["heavy"]\n', "load.mass", "finite number"),
        (
            BASE + 'seeds = 2\n[[axis]]\nkey = "truth.compliance[7]"\nvalues = [1e-7]\n',
            "truth.compliance[7]",
            "index",
        ),
        (
            BASE + 'seeds = 2\n[[axis]]\nkey = "plan"\nvalues = ["design:Q:12"]\n',
            "plan",
            "design:<criterion>:<M>",
        ),
        (
            BASE + 'seeds = 2\n[[axis]]\nkey = "plan"\nvalues = ["missing.toml"]\n',
            "plan",
            "readable scenario file",
        ),
        (
            BASE + 'seeds = 2\n[[axis]]\nname = "s"\nkey = "seed"\nvalues = [1, 2]\n',
            "seed",
            "other than robot and seed",
        ),
        (BASE + "seeds = 0\n", "seeds", ">= 1"),
        (BASE + "seeds = 2\nmagic = 1\n", "magic", "no such key"),
        (BASE + 'seeds = 2\n[campaign]\nmethod = "three-step"\n', "campaign.method", "one-step"),
        (
            BASE + 'seeds = 2\n[[axis]]\nname = "m"\nvalues = [1.0]\nscales = "nothing"\n',
            "axis[0].scales",
            "another axis",
        ),
        (
            BASE
            + 'seeds = 2\n[[axis]]\nname = "e"\ncases = [{label = "j3", set = {"truth.effects.joint_nonlinearity" = '
            '{joint = 3, cubic = 6000000000000}}}]\n[[axis]]\nname = "m"\nvalues = [0.5]\nscales = "e"\n',
            "axis[0] e",
            "floats only",
        ),
        (
            BASE + 'seeds = 2\n[[axis]]\nname = "cell"\nkey = "load.mass"\nvalues = [1.0]\n',
            "axis[0].name",
            "result column",
        ),
    ],
)
def test_bad_studies_are_refused_naming_the_file_and_key_before_any_task(
    tmp_path, capsys, body, key, expected
):
    path = write(tmp_path, body)
    with pytest.raises(InputError) as e:
        load_study(path)
    assert e.value.file == str(path) and key in e.value.key and expected in str(e.value), str(e.value)
    out = tmp_path / "r.parquet"
    assert main(["study", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and key in err
    assert (
        not out.exists()
        and not (tmp_path / "r.parquet.parts").exists()
        and not (tmp_path / "r_plots").exists()
    )


def test_the_grid_applies_every_axis_and_cells_with_equal_inputs_share_them(tmp_path):
    study = load_study(
        write(
            tmp_path,
            BASE
            + """seeds = 3
[set]
"load.mass" = 500.0
[[axis]]
name = "effect"
cases = [{label = "none"},
         {label = "base", set = {"truth.effects.base_compliance" = {compliance = [4.0e-9, 2.0e-9]}}}]
[[axis]]
name = "magnitude"
values = [0.5, 1.0]
scales = "effect"
[[axis]]
key = "tracker.sigma"
values = [1e-5, 3e-5]
""",
        )
    )
    assert len(study.cells) == 8
    c = {(cl.values["effect"], cl.values["magnitude"], cl.values["tracker.sigma"]): cl for cl in study.cells}
    half = c[("base", 0.5, 3e-5)]
    assert half.doc["truth"]["effects"]["base_compliance"]["compliance"] == [2.0e-9, 1.0e-9]
    assert half.doc["tracker"]["sigma"] == 3e-5 and half.doc["load"]["mass"] == 500.0
    assert half.expected == "base_compliance" and c[("none", 1.0, 1e-5)].expected == "nothing"
    # scaling nothing changes nothing: the two "none" cells of one sigma are computed once
    assert c[("none", 0.5, 1e-5)].inputs == c[("none", 1.0, 1e-5)].inputs
    assert c[("none", 0.5, 1e-5)].cell_id != c[("none", 1.0, 1e-5)].cell_id
    assert len({cl.inputs for cl in study.cells}) == 6
    seeds = [study.campaign_seed(r) for r in range(3)]
    assert len(set(seeds)) == 3 and seeds == [study.campaign_seed(r) for r in range(3)]
    assert scaled({"joint": 3, "cubic": 6e12, "s": "x"}, 0.5) == {"joint": 3, "cubic": 3e12, "s": "x"}


def test_cells_that_differ_by_a_hidden_effect_share_their_designed_plan(tmp_path):
    """The design model never has the truth's hidden effects (nominal_robot), so one plan per
    design:<c>:<M> and visible scenario serves every effect; a visible change designs anew."""
    study = load_study(
        write(
            tmp_path,
            BASE
            + """seeds = 1
[[axis]]
name = "effect"
cases = [{label = "none"},
         {label = "base", set = {"truth.effects.base_compliance" = {compliance = [4.0e-9, 2.0e-9]}}},
         {label = "soft", set = {"truth.compliance[2]" = 1.4e-7}}]
[[axis]]
key = "plan"
values = ["design:A:8"]
""",
        )
    )
    keys = {cl.values["effect"]: design_key(cl) for cl in study.cells}
    assert keys["none"] == keys["base"]
    assert keys["soft"] != keys["none"]


def test_plot_ticks_name_a_plan_file_by_its_name():
    from calbench.identify.study import axis_ticks

    x, labels = axis_ticks(["../scenarios/paper_table5.toml", "design:A:8", "/abs/plans/kr270_paper.toml"])
    assert list(x) == [0.0, 1.0, 2.0]
    assert labels == ["paper_table5.toml", "design:A:8", "kr270_paper.toml"]
    assert axis_ticks([1e-5, 2e-5])[1] is None  # numeric axes keep their values


def test_the_shipped_studies_are_valid():
    from importlib.resources import files

    power = load_study(files("calbench.studies") / "discovery_power.toml")
    assert len(power.cells) == 48 and len({c.inputs for c in power.cells}) == 43  # "none" x 6 is one
    expected = {c.values["effect"]: c.expected for c in power.cells}
    assert expected == {
        "none": "nothing",
        "forearm": "link_compliance[forearm]",
        "upper_arm": "link_compliance[upper_arm]",
        "base": "base_compliance",
        "j3": "joint_nonlinearity[j3]",
        "compensator": "compensator",
        "drift": "tracker_drift",
        "tool": "unexplained",
    }
    plans = load_study(files("calbench.studies") / "tracker_poses_plan.toml")
    assert len(plans.cells) == 12 and {c.plan.split(":")[0] for c in plans.cells} == {
        str(PAPER.resolve()),
        "design",
    }


SMALL = (
    BASE
    + """seeds = {seeds}
[[axis]]
key = "tracker.sigma"
values = [1e-5, 4e-5]
"""
)


def test_an_identify_only_task_does_not_import_discovery(tmp_path):
    """Discovery's import (scipy.stats, ~0.9 s) was paid in every worker's first task of an
    identify-only study, most of its per-task overhead (benchmarks/scaling_bench.py): a fresh
    process runs such a study and must not have imported it."""
    import subprocess
    import sys

    study = write(tmp_path, SMALL.format(seeds=1))
    code = (
        "import sys\n"
        "from calbench.identify.study import load_study, prepare, run_study\n"
        f"out = run_study(prepare(load_study({str(study)!r}), {str(tmp_path / 'r.parquet')!r}))\n"
        "assert out.ran == 2 and out.failed == 0, out\n"
        "print('calbench.identify.discover.workflow' in sys.modules)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


def _table(path):
    t = pq.read_table(path)
    return {n: t.column(n).to_pylist() for n in t.column_names if n not in TIMING_COLUMNS}


def _same(a: dict, b: dict) -> bool:
    nan = lambda v: "nan" if isinstance(v, float) and math.isnan(v) else v  # noqa: E731
    return a.keys() == b.keys() and all([nan(x) for x in a[k]] == [nan(x) for x in b[k]] for k in a)


def test_results_are_one_row_per_campaign_with_the_axes_as_columns(tmp_path):
    path = write(tmp_path, SMALL.format(seeds=2))
    out = tmp_path / "r.parquet"
    outcome = run_study(prepare(load_study(path), out))
    assert (outcome.total, outcome.ran, outcome.failed, outcome.rows) == (4, 4, 0, 4)
    t = pq.read_table(out)
    assert t.column("cell").to_pylist() == [0, 0, 1, 1] and t.column("replicate").to_pylist() == [0, 1, 0, 1]
    assert t.column("tracker.sigma").to_pylist() == [1e-5, 1e-5, 4e-5, 4e-5]
    meta = t.schema.metadata
    assert meta[b"calbench.study"].decode() == path.read_text()
    # the recorded numbers are identify's: error = estimate - truth, z = error / std
    est, tru, sd, z = (np.array(t.column(f"k2_{f}").to_pylist()) for f in ("estimate", "truth", "std", "z"))
    assert np.allclose(z, (est - tru) / sd, rtol=1e-12) and np.all(t.column("error").to_pylist() == [""] * 4)
    # common random numbers: the same noise draws, scaled by sigma, in both cells
    assert t.column("seed").to_pylist()[:2] == t.column("seed").to_pylist()[2:]
    assert not (tmp_path / "r.parquet.parts").exists()


def test_rerunning_resumes_and_more_seeds_reuse_the_finished_campaigns(tmp_path):
    p2 = write(tmp_path, SMALL.format(seeds=2), "s2.toml")
    p3 = write(tmp_path, SMALL.format(seeds=3), "s3.toml")
    out, fresh = tmp_path / "r.parquet", tmp_path / "fresh.parquet"
    run_study(prepare(load_study(p2), out))
    again = prepare(load_study(p2), out)
    assert again.campaigns == 0 and again.before == 4
    more = prepare(load_study(p3), out)
    assert more.campaigns == 2 and sorted(more.missing.values()) == [[2], [2]]
    assert run_study(more).ran == 2
    run_study(prepare(load_study(p3), fresh))
    a, b = _table(out), _table(fresh)
    assert _same(a, b)


def test_results_of_another_study_are_refused(tmp_path):
    out = tmp_path / "r.parquet"
    run_study(prepare(load_study(write(tmp_path, SMALL.format(seeds=2))), out))
    other = write(tmp_path, SMALL.format(seeds=2).replace("4e-5", "5e-5"), "other.toml")
    with pytest.raises(InputError, match="cells this study does not have"):
        prepare(load_study(other), out)
    fewer = write(tmp_path, SMALL.format(seeds=1), "fewer.toml")
    with pytest.raises(InputError, match="2 campaigns beyond them"):
        prepare(load_study(fewer), out)


def test_study_cli_prints_the_cell_summary_and_draws_plots(tmp_path, capsys):
    path = write(tmp_path, SMALL.format(seeds=2))
    out, js = tmp_path / "r.parquet", tmp_path / "summary.json"
    assert main(["study", str(path), "--out", str(out), "--json", str(js), "--scheduler", "in-process"]) == 0
    captured = capsys.readouterr()
    assert "RMS z" in captured.out and "in this process" in captured.err
    assert (tmp_path / "r_plots" / "accuracy_tracker.sigma.png").stat().st_size > 0
    import json

    cells = json.loads(js.read_text())["cells"]
    assert [c["campaigns"] for c in cells] == [2, 2] and all(c["failed"] == 0 for c in cells)
