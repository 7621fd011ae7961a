"""The documents a newcomer reads match the repository: every link in README.md and docs/*.md
resolves to a file inside the repository (issue 10: a clone has no ../shared/), and the README's
architecture page (docs/architecture.md) names exactly the rooms and the modules each holds,
both ways (issue 20)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import ROOT

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


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
