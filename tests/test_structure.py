"""The layout holds (issue 20): rooms of at most a dozen modules, each with a face that names
what others may import; no module imports another folder's private name; the packages import
one way (identify builds on bench, never the reverse) with no circle between modules or rooms.

Imports are read from the source (every ``import`` and ``from ... import``, at any depth:
inside functions and under ``TYPE_CHECKING`` too, since a circle hidden in a function is still
a circle). A name imported from a room's face counts as an import of the module that defines
it, as the face's stub says.
"""

from __future__ import annotations

import ast
import importlib
from collections import defaultdict
from pathlib import Path

import pytest
from conftest import ROOT

from calbench.bench.core import face_exports

PACKAGES = ("bench", "identify")
MAX_MODULES = 12


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES: dict[str, Path] = {
    _module_name(p): p for top in PACKAGES for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts
}
ROOMS = sorted(m for m, p in MODULES.items() if p.name == "__init__.py")


def _room(module: str) -> str:
    return module if module in ROOMS else module.rsplit(".", 1)[0]


def _faces() -> dict[str, dict[str, str]]:
    """room -> public name -> the module (absolute, without 'calbench.') that defines it."""
    out = {}
    for room in ROOMS:
        stub = MODULES[room].with_suffix(".pyi")
        if stub.exists():
            out[room] = {n: f"{room}{mod}" for n, (mod, _a) in face_exports(stub).items()}
    return out


FACES = _faces()


def _imports(module: str) -> list[tuple[str, str | None, int]]:
    """(target module, imported name or None, line) for every import of calbench code."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name[9:], None, node.lineno) for a in node.names if a.name.startswith("calbench.")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            elif (node.module or "").startswith("calbench."):
                target = node.module[9:]
            else:
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.append((sub, None, node.lineno) if sub in MODULES else (target, a.name, node.lineno))
    return out


def _defining_module(target: str, name: str | None) -> str:
    if name is not None and target in FACES and name in FACES[target]:
        return FACES[target][name]
    return target


def _graph() -> dict[str, set[str]]:
    g: dict[str, set[str]] = defaultdict(set)
    for m in MODULES:
        for target, name, _ in _imports(m):
            d = _defining_module(target, name)
            if d in MODULES and d != m and not (MODULES[m].name == "__init__.py" and d.startswith(m + ".")):
                g[m].add(d)
    return g


def _cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one member (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in list(g):
        if v not in index:
            visit(v)
    return out


def test_no_module_import_circle():
    assert _cycles(_graph()) == []


def test_no_room_import_circle():
    rooms: dict[str, set[str]] = defaultdict(set)
    for m, targets in _graph().items():
        for t in targets:
            if _room(t) != _room(m) and not t.startswith(_room(m) + "."):
                rooms[_room(m)].add(_room(t))
    assert _cycles(rooms) == []


def test_bench_never_imports_identify():
    bad = [
        (m, t) for m, ts in _graph().items() if m.startswith("bench") for t in ts if t.startswith("identify")
    ]
    assert bad == []


def _all_sources() -> list[Path]:
    return [p for top in (*PACKAGES, "tests", "benchmarks") for p in (ROOT / top).rglob("*.py")]


def _imported_folder(path: Path, node: ast.ImportFrom) -> Path | None:
    """The folder a ``from X import ...`` in ``path`` takes its names from (a module's folder, or
    the package folder itself), or None for an import from outside calbench."""
    if node.level:  # relative: the same folder or a parent's
        target = path.parent.joinpath(*[".."] * (node.level - 1), *(node.module or "").split(".")).resolve()
    elif (node.module or "").startswith("calbench."):
        target = ROOT.joinpath(*node.module.split(".")[1:])
    else:
        return None
    return target if target.is_dir() else target.parent


def private_imports(path: Path, source: str) -> list[str]:
    """Every ``_private`` name ``source`` (the text of ``path``) imports from another folder's
    module or package: a module may share its own folder's private names, never another's."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ImportFrom):
            continue
        target = _imported_folder(path, node)
        if target is None:
            continue
        for a in node.names:
            if a.name.startswith("_") and not a.name.startswith("__") and target != path.parent.resolve():
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno} {a.name}")
    return bad


def test_no_private_name_is_imported_from_another_folder():
    bad = [b for path in _all_sources() for b in private_imports(path, path.read_text(encoding="utf-8"))]
    assert bad == []


@pytest.mark.parametrize(
    "line, refused",
    [
        ("from .certificate import _scale", False),  # a module beside it: the same folder
        ("from . import _helper", False),
        ("from calbench.identify.design.plan import _lateral_sign", False),  # absolute, same folder
        ("from ..core.forward import _x", True),  # a sibling room's module
        ("from ..core import _x", True),  # a sibling room's package
        ("from calbench.identify.core.forward import _x", True),
        ("from calbench.bench.model import _x", True),
        ("from .sub.mod import _x", True),  # a folder below is another folder too
        ("from calbench.identify.design.plan import __all__", False),  # dunder: not private
    ],
)
def test_the_private_import_check_is_exact(line, refused):
    """Same folder allowed, any other folder refused: the check above, on a module written into
    identify/design (not on disk: only its path matters)."""
    path = ROOT / "identify" / "design" / "example.py"
    assert bool(private_imports(path, line + "\n")) == refused


@pytest.mark.parametrize("room", ROOMS)
def test_a_room_holds_at_most_a_dozen_modules(room):
    folder = MODULES[room].parent
    assert len([p for p in folder.glob("*.py") if p.name != "__init__.py"]) <= MAX_MODULES


@pytest.mark.parametrize("room", ROOMS)
def test_every_room_has_a_face_whose_names_resolve(room):
    """Every room, and the two packages themselves (calbench.bench, calbench.identify: what a
    notebook calls), has a stub whose names resolve and equal no module's or room's name beside
    it (a name equal to a room's would be replaced by the room once it is imported)."""
    stub = MODULES[room].with_suffix(".pyi")
    assert stub.exists(), f"{room}: no __init__.pyi"
    tree = ast.parse(stub.read_text(encoding="utf-8"))
    declared = next(
        ast.literal_eval(n.value)
        for n in tree.body
        if isinstance(n, ast.Assign) and n.targets[0].id == "__all__"
    )
    exports = face_exports(stub)
    assert sorted(declared) == sorted(exports), f"{room}: __all__ and the imports of its stub differ"
    package = importlib.import_module(f"calbench.{room}")
    folder = MODULES[room].parent
    clashes = [n for n in exports if (folder / f"{n}.py").exists() or (folder / n / "__init__.py").exists()]
    assert clashes == [], f"{room}: a public name is also a module's or a room's name"
    for name in exports:
        assert getattr(package, name) is not None


def test_code_outside_a_room_imports_from_its_face():
    """`from calbench.bench.model.robot import Robot` outside bench/model/ should read
    `from calbench.bench.model import Robot`; importing a module itself (to monkeypatch it) is fine."""
    bad = []
    for path in _all_sources():
        here = (
            _module_name(path)
            if path.is_relative_to(ROOT / "bench") or path.is_relative_to(ROOT / "identify")
            else ""
        )
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.ImportFrom)
                and not node.level
                and (node.module or "").startswith("calbench.")
            ):
                target = node.module[9:]
                if target not in MODULES or target in ROOMS:
                    continue
                room = _room(target)
                names = [a.name for a in node.names if f"{target}.{a.name}" not in MODULES]
                if room in PACKAGES:  # bench/cli.py, identify/cli.py, identify/demo.py: by their paths
                    continue
                if names and room in FACES and not (here == room or here.startswith(room + ".")):
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno} from calbench.{target}")
    assert bad == []


@pytest.mark.parametrize("package", PACKAGES)
def test_a_package_face_re_exports_from_its_rooms_faces(package):
    """calbench.bench's and calbench.identify's faces are made of their rooms' faces: each name
    comes from a room's face (or a module that sits at the package's top, as identify/demo.py),
    never from a module inside a room, so the rooms stay free to move their modules."""
    bad = []
    for name, (mod, attr) in face_exports(ROOT / package / "__init__.pyi").items():
        target = f"{package}{mod}"
        inside_a_room = target not in ROOMS and MODULES.get(target, ROOT).parent != ROOT / package
        if inside_a_room or target not in MODULES:
            bad.append(f"{name} from {mod}")
        elif target in FACES and attr not in FACES[target]:
            bad.append(f"{name}: {attr} is not on the face of {mod}")
    assert bad == []


def test_code_inside_the_packages_does_not_import_the_package_faces():
    """The package faces are for users (notebooks, tests, benchmarks, docs); calbench's own modules
    import from the rooms' faces, which say what they depend on."""
    bad = []
    for m, path in MODULES.items():
        if path.name == "__init__.py":
            continue
        for target, name, line in _imports(m):
            if target in PACKAGES and name is not None:
                bad.append(f"{path.relative_to(ROOT)}:{line} from calbench.{target} import {name}")
    assert bad == []


def _unit(module: str) -> str | None:
    """What docs/architecture.md's Layers picture names a module by: its room's folder
    ("bench/model/"), or its own path when it sits at a package's top ("bench/cli.py"); None for
    the packages' own faces."""
    if module in PACKAGES:
        return None
    room = _room(module)
    return MODULES[module].relative_to(ROOT).as_posix() if room in PACKAGES else room.replace(".", "/") + "/"


def _layers() -> dict[str, int]:
    """Unit -> its height in the Layers picture (the first text block under "## Layers"; the top
    line is the highest)."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text[text.index("\n## Layers\n") :]
    block = section[section.index("```text\n") + 8 : section.index("```", section.index("```text\n") + 8)]
    lines = [line.split() for line in block.splitlines() if line.strip()]
    return {unit: len(lines) - i for i, units in enumerate(lines) for unit in units}


def test_rooms_import_only_the_layers_below_them():
    """docs/architecture.md's Layers picture, held to the imports: it names every room and
    top-level module and nothing else, and each imports only from lines below its own."""
    layers = _layers()
    units = {u for u in map(_unit, MODULES) if u is not None}
    assert units - set(layers) == set(), "add these to docs/architecture.md's Layers picture"
    assert set(layers) - units == set(), "docs/architecture.md's Layers picture names what does not exist"
    bad = sorted(
        f"{a} imports {b}"
        for m, targets in _graph().items()
        for t in targets
        if (a := _unit(m)) is not None and (b := _unit(t)) is not None and a != b and layers[b] >= layers[a]
    )
    assert bad == []
