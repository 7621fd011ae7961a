"""The URDF text from-urdf converts: a ``.xacro`` expanded, the overlay's inertials written in,
geom names made unique (issue 21).

* ``.xacro``: expanded by the ``xacro`` package (pure Python, no ROS). ``$(find PKG)`` is the
  overlay's ``[packages] PKG`` folder, else a folder named PKG beside the file's package or any
  folder above it (ROS-Industrial's packages sit side by side: ``fanuc_m900ib_support`` finds
  ``fanuc_resources``). The overlay's ``[xacro]`` table gives the file's arguments (what
  ``xacro FILE NAME:=value`` gives on a command line; ``$(find PKG)`` in a value resolved the
  same way). xacro's own errors become InputError naming the file, on one line: an argument
  without a value names the ``[xacro]`` key to add, a file the xacro reads and cannot find is
  named as the package's missing file.
* ``[inertials.LINK]``: an ``<inertial>`` element written into the link (replacing the URDF's,
  if any), inertia mass * ASSUMED_GYRATION^2 on the diagonal when not given.
* Geom names: ROS-Industrial's URDFs name every ``<collision>`` and ``<visual>`` "collision" and
  "visual"; MuJoCo warns once per duplicate and drops the name. Each name used twice becomes
  ``LINK_NAME``.
"""

from __future__ import annotations

import contextlib
import io
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers.expat import ExpatError

from calbench.bench.core import InputError, parse_xml

from .overlay import ASSUMED_GYRATION, Overlay
from .urdfnumbers import check_numbers


def is_xacro(path: Path) -> bool:
    return path.name.endswith(".xacro")


def _find_package(name: str, path: Path, packages: dict[str, Path]) -> str:
    if name in packages:
        return str(packages[name])
    for folder in path.resolve().parents:
        if (folder / name).is_dir():
            return str(folder / name)
    raise InputError(
        path,
        f"$(find {name})",
        f'a [packages] {name} = "FOLDER" in the overlay, or a folder {name!r} beside the package',
        "not found",
    )


@contextlib.contextmanager
def _finder(path: Path, packages: dict[str, Path]):
    """xacro's ``$(find PKG)`` answered from the overlay's [packages] while expanding (xacro asks
    ROS 2's ament index, which a plain Python has not), restored afterwards."""
    from xacro import substitution_args as sa

    old, old_eval = sa._eval_find, sa._eval_dict["find"]
    failed: list[InputError] = []

    def find(pkg: str) -> str:
        try:
            return _find_package(pkg, path, packages)
        except InputError as exc:  # xacro wraps it into its own: keep ours
            failed.append(exc)
            raise

    sa._eval_find = sa._eval_dict["find"] = find
    try:
        yield failed
    finally:
        sa._eval_find, sa._eval_dict["find"] = old, old_eval


_FIND = re.compile(r"\$\(find ([^)\s]+)\)")


def _xacro_error(path: Path, exc: Exception) -> InputError:
    """xacro's error as one line naming what to change (module docstring)."""
    text = str(exc) or type(exc).__name__
    first = text.strip().splitlines()[0] if text.strip() else text
    if m := re.match(r"Undefined substitution argument (\S+)", first):
        return InputError(
            path,
            f"(xacro) $(arg {m[1]})",
            f'a value for it: [xacro] {m[1]} = "VALUE" in the overlay',
            "none given",
        )
    if isinstance(exc, FileNotFoundError) or "No such file or directory" in first:
        missing = getattr(exc, "filename", None) or (re.findall(r"'([^']+)'", first) or [first])[-1]
        return InputError(
            path,
            "(xacro)",
            "every file the xacro reads (a package with all its files; or [xacro] arguments that point "
            "to files that exist)",
            f"{missing} is missing",
        )
    return InputError(path, "(xacro)", "a xacro file that expands to a URDF", first)


def expand_xacro(path: Path, packages: dict[str, Path], args: dict[str, str] | None = None) -> str:
    """The URDF a ``.xacro`` file expands to, with arguments ``args`` (InputError naming the file
    on any xacro error)."""
    try:
        import xacro
    except ImportError:  # a dependency of calbench, but a user may run without it
        raise InputError(path, "(file)", "the xacro package (pip install xacro)", "not installed") from None
    try:
        mappings = {
            k: _FIND.sub(lambda m: _find_package(m[1], path, packages), v) for k, v in (args or {}).items()
        }
        with _finder(path, packages) as failed, contextlib.redirect_stderr(io.StringIO()):
            try:
                doc = xacro.process_file(str(path), mappings=mappings)
            except Exception:
                if failed:
                    raise failed[0] from None
                raise
    except InputError:
        raise
    except (xacro.XacroException, OSError, ExpatError, KeyError, NameError, ValueError) as exc:
        raise _xacro_error(path, exc) from None
    return doc.toxml()


def _inertial_element(spec) -> ET.Element:
    el = ET.Element("inertial")
    ET.SubElement(el, "origin", xyz=" ".join(repr(x) for x in spec.com), rpy="0 0 0")
    ET.SubElement(el, "mass", value=repr(spec.mass))
    i = spec.inertia or (spec.mass * ASSUMED_GYRATION**2,) * 3 + (0.0, 0.0, 0.0)
    names = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
    ET.SubElement(el, "inertia", {k: repr(float(v)) for k, v in zip(names, i)})
    return el


def urdf_text(path: Path, ov: Overlay | None = None) -> tuple[str, bool]:
    """The URDF text to convert and whether it came from xacro (module docstring). The file is
    read as it is when there is nothing to change."""
    packages = ov.packages if ov is not None else {}
    if is_xacro(path):
        parse_xml(path, path)  # no entity declarations in the xacro itself, before xacro reads it
        text, expanded = expand_xacro(path, packages, ov.xacro_args if ov is not None else None), True
    else:
        if ov is not None and ov.xacro_args:
            raise InputError(ov.path, "xacro", "arguments only for a .xacro robot file", path.name)
        try:
            text, expanded = path.read_text(encoding="utf-8"), False
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(path, "(file)", "a readable URDF (XML)", str(exc)) from None
    try:
        root = parse_xml(path, path, text=text)  # defusedxml (bench/core/xmlsafe.py)
    except InputError:
        return text, expanded  # read_urdf reports it
    check_numbers(path, root)  # before anything reads them (bench/robots/urdfnumbers.py)
    links = {el.get("name", ""): el for el in root.findall("link")}
    for spec in ov.inertials if ov is not None else ():
        if spec.link not in links:
            raise InputError(
                ov.path, f"{spec.key}", f"a link of {path.name} (" + ", ".join(links) + ")", spec.link
            )
        if spec.density is not None:  # estimated from its geometry (bench/robots/density.py)
            continue
        link = links[spec.link]
        for old in link.findall("inertial"):
            link.remove(old)
        link.append(_inertial_element(spec))
    names: dict[str, int] = {}
    for link in links.values():
        for el in (*link.findall("collision"), *link.findall("visual")):
            if el.get("name"):
                names[el.get("name")] = names.get(el.get("name"), 0) + 1
    for lname, link in links.items():
        for el in (*link.findall("collision"), *link.findall("visual")):
            if names.get(el.get("name", ""), 0) > 1:
                el.set("name", f"{lname}_{el.get('name')}")
    return ET.tostring(root, encoding="unicode"), expanded


__all__ = ["expand_xacro", "is_xacro", "urdf_text"]
