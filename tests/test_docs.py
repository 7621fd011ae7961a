"""The documents a newcomer reads match the repository: every link in README.md and docs/*.md
resolves to a file inside the repository (issue 10: a clone has no ../shared/), and to a heading
of it when it names one; the README's architecture page (docs/architecture.md) names exactly the
rooms and the modules each holds, both ways (issue 20). The README is one page (at most 12 KB),
its tour runs and its Python example does what it says (issue 20), and every Python block of the
docs imports from a face."""

from __future__ import annotations

import ast
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import K_TRUE, PAPER, ROOT

from calbench.bench import load_scenario, read_log
from calbench.bench.core import face_exports

README = ROOT / "README.md"
DOCS = [README, *sorted((ROOT / "docs").glob("*.md"))]
MAX_README_BYTES = 12 * 1024  # one page: mink's README is 3.6 KB, PySINDy's 5.3 KB


def links(md: Path) -> list[str]:
    """Targets of markdown links and images, and of HTML src/href attributes."""
    text = md.read_text(encoding="utf-8")
    found = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r'(?:src|href)="([^"]+)"', text)
    return [x for x in found if not re.match(r"[a-z]+:|#", x)]


@pytest.mark.parametrize("md", DOCS, ids=lambda p: p.name)
def test_every_link_resolves_inside_the_repository(md):
    targets = links(md)
    if md.name == "README.md":
        assert "docs/contract.md" in targets  # the contract travels with the project
    for target in targets:
        path = (md.parent / target.split("#")[0]).resolve()
        assert path.is_relative_to(ROOT), f"{md.name}: {target} leaves the repository"
        assert path.exists(), f"{md.name}: {target} does not exist"


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(md: Path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", md.read_text(encoding="utf-8"), flags=re.M | re.S)  # not code
    return {slug(h) for h in re.findall(r"^#+ (.+)$", text, re.M)}


@pytest.mark.parametrize("md", DOCS, ids=lambda p: p.name)
def test_every_anchor_names_a_heading(md):
    text = md.read_text(encoding="utf-8")
    for target in re.findall(r"\]\(([^)\s]*#[^)\s]+)\)", text):
        path, anchor = target.split("#", 1)
        if re.match(r"[a-z]+:", path):
            continue
        page = (md.parent / path).resolve() if path else md
        if page.suffix == ".md":
            assert anchor in anchors(page), f"{md.name}: {target}: no such heading in {page.name}"


def test_the_readme_is_one_page():
    assert len(README.read_bytes()) <= MAX_README_BYTES


def readme_section(title: str) -> str:
    """The README's text under "## title", up to the next "## " heading."""
    text = README.read_text(encoding="utf-8")
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else None]


def fenced(text: str, lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.M | re.S)


TOUR = [
    line.strip()
    for block in fenced(readme_section("A tour"), "sh")
    for line in block.splitlines()
    if line.strip() and not line.lstrip().startswith("#")
]
OUTPUT_FLAGS = ("--out", "--json", "--rrd", "--csv")


@pytest.fixture(scope="module")
def tour(tmp_path_factory) -> dict[str, subprocess.CompletedProcess]:
    """Every command of the README's tour, in order (later ones read what earlier ones wrote), in a
    fresh folder holding what a checkout has (scenarios/, mjcf/, as links) with the project's
    environment first on PATH, as `. .venv/bin/activate` puts it.

    The whole tour runs, not a subset: it is written to take seconds on two cores, which is why it
    says `montecarlo --runs 200 --method one-step` (1000 runs of every estimator take minutes) and
    `design --candidates 2000` (the default 10^4 takes ~10 s more)."""
    here = tmp_path_factory.mktemp("tour")
    for folder in ("scenarios", "mjcf"):
        (here / folder).symlink_to(ROOT / folder, target_is_directory=True)
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "calbench").exists(), f"{bin_dir}: no calbench console script (make test installs it)"
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}", MPLBACKEND="Agg")
    env.update(RERUN_ANALYTICS="0", DASK_SCHEDULER_ADDRESS="")
    out = {}
    for cmd in TOUR:
        out[cmd] = subprocess.run(
            ["bash", "-c", cmd], cwd=here, env=env, capture_output=True, text=True, timeout=600
        )
    out["folder"] = here
    return out


def test_the_tour_is_six_verbs():
    assert [shlex.split(c, comments=True)[1] for c in TOUR] == [
        "simulate", "identify", "view", "discover", "montecarlo", "design"
    ]  # fmt: skip


@pytest.mark.parametrize("cmd", TOUR, ids=lambda c: shlex.split(c, comments=True)[1])
def test_every_tour_command_exits_0_and_writes_what_it_names(tour, cmd):
    res = tour[cmd]
    assert res.returncode == 0, f"{cmd}\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}"
    words = shlex.split(cmd, comments=True)
    for flag in OUTPUT_FLAGS:
        if flag in words:
            written = tour["folder"] / words[words.index(flag) + 1]
            assert written.is_file() and written.stat().st_size > 0, f"{cmd}: wrote no {written.name}"


def test_the_readme_python_example_does_what_it_says(tmp_path, monkeypatch, capsys):
    """The example simulates the shipped paper campaign into logs/paper.mcap, identifies it and
    prints the table and k2 against the truth; its last line asserts what `identify --check`
    tests. Checked here independently: the log holds the scenario's poses, the printed truth
    is the scenario's k2, and the estimate is within 4 of its std of it."""
    (code,) = fenced(readme_section("From Python"), "python")
    assert len(code.strip().splitlines()) <= 10
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})  # its own assert: converged, every |z| < 4
    printed = capsys.readouterr().out
    log = read_log(tmp_path / "logs" / "paper.mcap")
    assert len(log.complete_poses) == len(load_scenario(PAPER).poses) == 16
    table, k2_line = printed.rstrip().rsplit("\n", 1)
    for name in ("k1", "k2", "k3", "k4", "k5", "k6", "compensator_stiffness", "compensator_preload"):
        assert name in table
    estimate, std, truth = map(
        float, re.fullmatch(r"k2 = (\S+) ± (\S+) rad/\(N·m\), truth (\S+)", k2_line).groups()
    )
    assert truth == pytest.approx(K_TRUE[1], rel=5e-4)  # printed to 4 digits
    assert abs(estimate - K_TRUE[1]) < 4 * std and std < 0.05 * K_TRUE[1]


def test_the_pipeline_names_functions_on_the_package_faces():
    """Each box of the README's pipeline names a verb the console script has and a function that
    calbench.bench's or calbench.identify's face exports."""
    (diagram,) = fenced(readme_section("The pipeline"), "text")
    functions = re.findall(r"\b(bench|identify)\.(\w+)", diagram)
    verbs = set(re.findall(r"calbench (\w+)", diagram))
    assert len(functions) >= 10 and {"simulate", "identify", "view", "design", "discover"} <= verbs
    for package, name in functions:
        assert name in face_exports(ROOT / package / "__init__.pyi"), f"calbench.{package}.{name}"
    help_text = subprocess.run(
        [sys.executable, "-m", "calbench.identify.cli", "--help"], capture_output=True, text=True
    ).stdout
    assert verbs <= set(re.search(r"\{([a-z,-]+)\}", help_text).group(1).split(",")), verbs


def python_blocks() -> list[tuple[str, str]]:
    return [(md.name, code) for md in DOCS for code in fenced(md.read_text(encoding="utf-8"), "python")]


def test_the_docs_show_python():
    assert any(name == "README.md" for name, _ in python_blocks())


@pytest.mark.parametrize("name, code", python_blocks(), ids=lambda x: x if x.endswith(".md") else "")
def test_every_python_block_imports_from_a_face(name, code):
    """Docs show what users may rely on: a package's or a room's face, never a module path."""
    for node in ast.walk(ast.parse(code)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("calbench."):
            stub = ROOT.joinpath(*node.module.split(".")[1:], "__init__.pyi")
            assert stub.exists(), f"{name}: from {node.module}: not a face"
            missing = {a.name for a in node.names} - set(face_exports(stub))
            assert not missing, f"{name}: from {node.module} import {missing}: not on its face"


def architecture_sections() -> dict[str, str]:
    """docs/architecture.md's rooms: folder -> the text of its section (a heading "### `folder/`")."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    parts = re.split(r"^### `([\w/]+)/`[^\n]*$", text, flags=re.M)
    return {parts[i]: parts[i + 1] for i in range(1, len(parts), 2)}


def package_folders() -> list[str]:
    """Every folder of bench/ and identify/ that is a package (has an __init__.py)."""
    return sorted(
        p.parent.relative_to(ROOT).as_posix()
        for top in ("bench", "identify")
        for p in (ROOT / top).rglob("__init__.py")
    )


def test_the_architecture_page_has_a_section_for_every_package_and_no_other():
    assert set(architecture_sections()) == set(package_folders())


@pytest.mark.parametrize("folder", package_folders())
def test_the_architecture_page_names_every_module_of_a_package(folder):
    named = set(re.findall(r"^- `(\w+\.py)`", architecture_sections().get(folder, ""), re.M))
    present = {p.name for p in (ROOT / folder).glob("*.py") if p.name != "__init__.py"}
    assert present - named == set(), f"{folder}/: modules docs/architecture.md does not name"
    assert named - present == set(), f"{folder}/: docs/architecture.md names modules that do not exist"
