"""Writing what users asked for without ever destroying what they had.

Every command checks all its output paths BEFORE any work starts (:func:`check_outputs`):
* no output may be one of the command's inputs (same resolved path, or the same file through a
  link), nor another of its outputs;
* an output may not be an existing directory;
* its folder must be writable: missing parent folders are created (the one behaviour for every
  verb), and a probe file is created and removed there, which catches read-only mounts, /proc and
  a regular file standing where a folder should be.
Any failure is an InputError naming the flag and the path (exit status 2), before anything exists.

Files are then written atomically (:func:`atomic_path`, :func:`write_text`): into a temporary
file in the same folder, renamed over the target only when complete, so an interrupted command
leaves either the old file or the new one, never half of one. (The campaign's MCAP log is the
exception by design: it is written in place, pose by pose, so that a crash leaves a log readable
up to its last finished pose; see bench/log/writer.py.)

A write that the machine refuses (a full disk, a quota, a file-size limit, a read-only remount,
an I/O error) becomes a :class:`WriteError` naming the output and the cause: the temporary file
is removed and the earlier file of that name is left as it was.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path

from .errors import CalbenchError, InputError

# What the machine says when it will not take more bytes (or any): reported, not a traceback.
REFUSED_WRITES = {
    errno.ENOSPC: "the disk is full (ENOSPC)",
    errno.EDQUOT: "the disk quota is exceeded (EDQUOT)",
    errno.EFBIG: "the file is larger than this system allows (EFBIG)",
    errno.EROFS: "the file system is read-only (EROFS)",
    errno.EIO: "an input/output error (EIO)",
    errno.EACCES: "permission denied (EACCES)",
    errno.EPERM: "operation not permitted (EPERM)",
}


class WriteError(CalbenchError):
    """An output could not be written because the machine refused it (see REFUSED_WRITES).
    ``kept`` says what is left for the user (the earlier file, the finished poses)."""

    def __init__(self, path: str | os.PathLike, cause: str, kept: str = ""):
        self.path = str(path)
        self.cause = cause
        super().__init__(f"cannot write {self.path}: {cause}" + (f"; {kept}" if kept else ""))


def refused_write(exc: BaseException) -> str | None:
    """The cause, in words, when ``exc`` is a write the machine refused; None otherwise. Some
    writers raise OSError without an errno (pyarrow) or a RuntimeError quoting the system's
    error (Rerun's Rust core: "... (os error 28)"): their text is matched too."""
    if isinstance(exc, OSError) and exc.errno in REFUSED_WRITES:
        return REFUSED_WRITES[exc.errno]
    if not isinstance(exc, (OSError, RuntimeError)):
        return None
    text = str(exc).lower()
    code = re.search(r"\(os error (\d+)\)", text)
    if code and int(code.group(1)) in REFUSED_WRITES:
        return REFUSED_WRITES[int(code.group(1))]
    if not isinstance(exc, OSError):
        return None
    for words, code in (("no space left", errno.ENOSPC), ("quota", errno.EDQUOT), ("read-only", errno.EROFS)):
        if words in text:
            return REFUSED_WRITES[code]
    return None


def _same(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(
    outputs: Mapping[str, str | os.PathLike | None], inputs: Mapping[str, str | os.PathLike | None] = ()
) -> dict[str, Path]:
    """Validate output paths (flag -> path; None entries are skipped) against the inputs
    (name -> path) and each other; create missing parent folders. Returns flag -> Path."""
    outs = {k: Path(v) for k, v in outputs.items() if v is not None}
    ins = {k: Path(v) for k, v in dict(inputs).items() if v is not None}
    for flag, out in outs.items():
        for name, inp in ins.items():
            if _same(out, inp):
                raise InputError(out, flag, f"an output path other than the input {name} ({inp})", str(out))
        for flag2, out2 in outs.items():
            if flag2 < flag and _same(out, out2):
                raise InputError(out, flag, f"an output path other than {flag2}", str(out))
        if out.is_dir():
            raise InputError(out, flag, "a file path, not a directory", "an existing directory")
        _check_folder(flag, out)
    return outs


def _check_folder(flag: str, out: Path) -> None:
    parent = out.parent if str(out.parent) else Path(".")
    for anc in (parent, *parent.parents):  # nearest existing ancestor must be a folder
        if anc.exists():
            if not anc.is_dir():
                raise InputError(out, flag, "a path whose folders are folders", f"{anc} is a file")
            break
    try:
        parent.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".calbench-probe-", dir=parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise InputError(
            out, flag, "a writable folder for this output", f"{parent}: {e.strerror or e}"
        ) from None


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on any
    exception (KeyboardInterrupt included) it is removed and ``path`` is left as it was.
    ``suffix`` (default: path's own) matters for writers that choose a format by extension.
    A refused write (:func:`refused_write`) is raised as :class:`WriteError` naming ``path``."""
    path = Path(path)
    kept = "the earlier file of that name is unchanged" if path.exists() else "nothing was written"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=path.suffix if suffix is None else suffix, dir=path.parent
        )
    except OSError as exc:
        cause = refused_write(exc)
        if cause is None:
            raise
        raise WriteError(path, cause, kept) from None
    os.close(fd)
    tmp = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; a report is meant to be shared
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        cause = refused_write(exc)
        if cause is None:
            raise
        raise WriteError(path, cause, kept) from None


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


__all__ = [
    "REFUSED_WRITES",
    "WriteError",
    "atomic_path",
    "check_outputs",
    "refused_write",
    "write_bytes",
    "write_text",
]
