"""XML from strangers: parsed with no entities, reading no file outside its own folder.

A URDF, an MJCF, or the MJCF attached to a log someone sent is read with ``defusedxml``: a
document type that declares entities (the "billion laughs" expansion bomb, external entities
that read local files or URLs) is refused. MJCF can also read files itself: ``<include
file=...>``, and assets (meshes, textures, height fields, skins) under ``<compiler meshdir=
texturedir= assetdir=>``. Two rules (issue 24):

* a model file's references must stay inside the model's own folder (:func:`check_model_file`);
* MJCF *text*, such as a log's attachment, must read no file at all (:func:`check_mjcf_text`):
  a log carries its robot whole, and a reference would be resolved against whatever folder the
  reader happens to be in. A user who wants a file-based model gives it with ``--model``.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from defusedxml import DefusedXmlException
from defusedxml import ElementTree as SafeET

from .errors import InputError

_COMMENT = re.compile(r"<!--.*?-->", re.DOTALL)

# MJCF attributes that name a file, and the compiler folder each is relative to
_DIR_OF = {"mesh": "meshdir", "skin": "meshdir", "hfield": "assetdir", "texture": "texturedir"}


def parse_xml(source: str | os.PathLike, where: object, text: str | None = None) -> ET.Element:
    """The root of the XML at ``source`` (or of ``text``, with ``source`` naming it): InputError
    naming ``where`` for malformed XML or entity declarations."""
    try:
        if text is None:
            with open(source, "rb") as f:
                text = f.read().decode("utf-8", "replace")
        # comments read nothing, and MuJoCo accepts "--" inside one (which XML does not, and
        # which older calbench from-urdf headers hold): left out before parsing
        return SafeET.fromstring(_COMMENT.sub("", text))
    except DefusedXmlException as exc:
        raise InputError(
            where,
            "<!DOCTYPE>",
            "XML without entity declarations",
            f"entity declarations ({type(exc).__name__})",
        ) from None
    except ET.ParseError as exc:
        raise InputError(where, "XML", "well-formed XML", str(exc)) from None
    except OSError as exc:
        raise InputError(where, "file", "a readable XML file", exc.strerror or str(exc)) from None


def file_references(root: ET.Element) -> list[tuple[str, str]]:
    """(element tag, file path as written, joined to its compiler folder) for every file an MJCF
    reads: includes and assets."""
    dirs = {"meshdir": "", "texturedir": "", "assetdir": ""}
    for c in root.iter("compiler"):
        for k in dirs:
            if c.get(k) is not None:
                dirs[k] = c.get(k) or ""
    refs = []
    for el in root.iter():
        f = el.get("file")
        if f is None:
            continue
        if el.tag == "include":
            refs.append(("include", f))
            continue
        folder = dirs.get(_DIR_OF.get(el.tag, "assetdir"), "") or dirs["assetdir"]
        refs.append((el.tag, os.path.join(folder, f)))
    for k, v in dirs.items():
        if v:
            refs.append((f"compiler {k}", v))
    return refs


def check_mjcf_text(text: str, where: object = "MJCF text") -> ET.Element:
    """MJCF given as text must be safe XML and read no file. Returns its root."""
    root = parse_xml(where, where, text=text)
    refs = file_references(root)
    if refs:
        tag, path = refs[0]
        raise InputError(
            where,
            f"<{tag} file>",
            "a self-contained MJCF (a log's robot reads no file; give --model to use your own)",
            path,
        )
    return root


def check_model_file(path: str | os.PathLike, where: object | None = None) -> None:
    """An MJCF file (and what it includes) must be safe XML whose files lie inside its folder."""
    path = Path(path)
    home = path.resolve().parent
    seen: set[Path] = set()
    todo = [path]
    while todo:
        f = todo.pop()
        if f.resolve() in seen:
            continue
        seen.add(f.resolve())
        root = parse_xml(f, where or f)
        for tag, ref in file_references(root):
            target = (home / ref).resolve()  # MuJoCo resolves every file against the main model's folder
            if target != home and home not in target.parents:
                raise InputError(where or f, f"<{tag} file>", f"a file inside the model's folder {home}", ref)
            if tag == "include":
                todo.append(target)


__all__ = ["check_mjcf_text", "check_model_file", "file_references", "parse_xml"]
