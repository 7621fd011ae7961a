"""The documents a newcomer reads match the repository: every link in README.md and docs/*.md
resolves to a file inside the repository (issue 10: a clone has no ../shared/), and the README's
layout table names exactly the modules each package folder holds (issue 9)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from conftest import ROOT

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PACKAGES = ["bench", "identify", "identify/design", "identify/discover", "identify/study"]


def links(md: Path) -> list[str]:
    """Targets of markdown links and images, and of HTML src/href attributes."""
    text = md.read_text(encoding="utf-8")
    found = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r'(?:src|href)="([^"]+)"', text)
    return [x for x in found if not re.match(r"[a-z]+:|#", x)]


@pytest.mark.parametrize("md", DOCS, ids=lambda p: p.name)
def test_every_link_resolves_inside_the_repository(md):
    targets = links(md)
    if md.name == "README.md":
        assert "docs/contract.md" in targets            # the contract travels with the project
    for target in targets:
        path = (md.parent / target.split("#")[0]).resolve()
        assert path.is_relative_to(ROOT), f"{md.name}: {target} leaves the repository"
        assert path.exists(), f"{md.name}: {target} does not exist"


def layout_rows() -> dict[str, str]:
    """The README's layout table: folder -> the text of its row."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme.split("### Layout", 1)[1].split("\n## ", 1)[0]
    return {m.group(1): m.group(2) for m in re.finditer(r"^\| `([\w/]+)/` \| (.*) \|$", section, re.M)}


@pytest.mark.parametrize("folder", PACKAGES)
def test_the_readme_layout_names_every_module_of_a_package(folder):
    rows = layout_rows()
    assert folder in rows, f"no layout row for {folder}/"
    named = set(re.findall(r"`(\w+\.py)`", rows[folder]))
    present = {p.name for p in (ROOT / folder).glob("*.py") if p.name != "__init__.py"}
    assert present - named == set(), f"{folder}/: modules the README does not name"
    assert named - present == set(), f"{folder}/: the README names modules that do not exist"
