"""Do the report's inputs belong together? The log, and the identify, discover and design JSON made from it.

A report that puts an identification of one campaign next to the log of another, or a plan
designed for another robot, says something false without a word (issue 22). Each JSON names
what it was made from: identify's and discover's ``log`` and ``model``, design's ``scenario``.
Where that file can be found (as named, or beside the JSON) it is compared by content with the
report's own inputs:

* an identify or discover report of ANOTHER LOG (its log's bytes differ from the report's log):
  refused, InputError naming the JSON and its ``log`` key (exit 2, nothing written);
* a design whose scenario's robot is ANOTHER MJCF than the one the log carries: refused the same
  way, naming ``scenario``;
* what cannot be compared (the named file is not here) or differs legitimately (an
  identification with the user's own --model, not the MJCF the log carries) is NAMED in the report.
"""

from __future__ import annotations

import hashlib
import tomllib
from pathlib import Path

from calbench.bench.core import InputError

FROM_LOG = ("(from the log)", "MJCF from the log")


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def locate(name: str | None, beside: Path) -> Path | None:
    """The file a JSON names: as named (from the working folder), else beside the JSON."""
    if not name:
        return None
    for p in (Path(name), beside.parent / name):
        if p.is_file():
            return p
    return None


def check_log(kind: str, json_path: Path, named: str | None, log_path: Path, notes: list[str]) -> None:
    found = locate(named, json_path)
    if found is None:
        notes.append(
            f"The {kind} report {json_path} names its log {named!r}, which is not here: "
            f"it was not checked to be {log_path}."
        )
        return
    mine, theirs = sha256(log_path.read_bytes()), sha256(found.read_bytes())
    if mine != theirs:
        raise InputError(
            json_path,
            "log",
            f"the {kind} report of the report's log {log_path} (sha256 {mine[:12]}…)",
            f"{named} (sha256 {theirs[:12]}…): the {kind} report of another campaign",
        )


def check_model(kind: str, json_path: Path, named: str | None, mjcf_text: str, notes: list[str]) -> None:
    if not named or any(named.endswith(s) for s in FROM_LOG):
        return
    found = locate(named, json_path)
    if found is None:
        notes.append(f"The {kind} report {json_path} used the model {named!r}, which is not here to compare.")
    elif found.read_text(encoding="utf-8", errors="replace") != mjcf_text:
        notes.append(
            f"The {kind} report {json_path} used the model {named} ({kind}'s --model), not the MJCF the "
            "log carries: a user's model of the robot, named here."
        )


def check_design(json_path: Path, doc: dict, mjcf_text: str, robot: str, notes: list[str]) -> None:
    named = doc.get("scenario")
    found = locate(named, json_path)
    if found is None:
        notes.append(
            f"The design {json_path} names its scenario {named!r}, which is not here: "
            "it was not checked to be of this log's robot."
        )
        return
    try:
        rel = tomllib.loads(found.read_text(encoding="utf-8"))["robot"]
        text = (found.parent / rel).read_text(encoding="utf-8")
    except (OSError, KeyError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        notes.append(f"The design's scenario {found} could not be read to check its robot ({exc}).")
        return
    if sha256(text.encode()) != sha256(mjcf_text.encode()):
        raise InputError(
            json_path,
            "scenario",
            f"a design for the log's robot ({robot}, the MJCF the log carries)",
            f"{named}, whose robot {rel} is another MJCF",
        )


def provenance(log_path: Path, log, inputs: dict) -> list[str]:
    """Check the report's inputs against each other (module docstring); raises InputError on
    a mismatch and returns the notes the report prints. ``inputs``: kind -> (path, its report:
    an IdentificationReport for identify, the JSON dict for discover and design)."""
    notes: list[str] = []
    mjcf = log.mjcf_text or ""
    for kind in ("identify", "discover"):
        if kind not in inputs:
            continue
        path, doc = inputs[kind]
        named_log = doc.log if kind == "identify" else doc.get("log")
        named_model = doc.model if kind == "identify" else doc.get("model")
        check_log(kind, Path(path), named_log, log_path, notes)
        check_model(kind, Path(path), named_model, mjcf, notes)
    if "design" in inputs:
        path, doc = inputs["design"]
        check_design(Path(path), doc, mjcf, str(log.header.get("robot", "robot")), notes)
    return notes


__all__ = ["provenance", "locate", "check_log", "check_model", "check_design"]
