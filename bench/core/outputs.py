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

Two runs writing one file: inside :func:`holding_outputs` (every verb of the command line runs
in one), :func:`check_outputs` also takes an exclusive lock on each output, a ``.NAME.lock``
file beside it holding the owner's PID; a second run asking for the same output is refused
with one line naming the running one, so the file is never a mix of two runs.

A write that the machine refuses (a full disk, a quota, a file-size limit, a read-only remount,
an I/O error) becomes a :class:`WriteError` naming the output and the cause: the temporary file
is removed and the earlier file of that name is left as it was.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import fcntl
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


# The locks of the command running in this context: resolved output path -> open lock file.
_LOCKS: contextvars.ContextVar[dict[Path, int] | None] = contextvars.ContextVar(
    "calbench_locks", default=None
)


@contextlib.contextmanager
def holding_outputs() -> Iterator[None]:
    """Run a command whose :func:`check_outputs` lock their outputs until it ends."""
    held: dict[Path, int] = {}
    token = _LOCKS.set(held)
    try:
        yield
    finally:
        _LOCKS.reset(token)
        for path, fd in held.items():
            with contextlib.suppress(OSError):
                _lock_path(path).unlink()  # unlinked while still held: see _lock
            os.close(fd)


def _lock_path(out: Path) -> Path:
    return out.with_name(f".{out.name}.lock")


def _lock(flag: str, out: Path, held: dict[Path, int]) -> None:
    """Take ``out``'s lock for this command, or raise InputError naming the run that holds it.
    The lock file is unlinked by its holder before release, so a run that opened it just
    before checks that the file it locked is still the one at the path, and retries if not."""
    key = out.resolve()
    if key in held or (key.exists() and not key.is_file()):  # /dev/null, a FIFO: nothing to mix
        return
    lock = _lock_path(key)
    for _ in range(100):
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            cause = refused_write(exc)
            if cause is None:
                raise
            raise WriteError(lock, cause, "nothing was written") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            owner = os.read(fd, 64).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise InputError(
                out,
                flag,
                "an output no other calbench run is writing",
                f"calbench pid {owner} is writing it ({lock})",
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            with contextlib.suppress(OSError):  # the PID is for the message; a full disk has no room
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()}\n".encode())
            held[key] = fd
            return
        os.close(fd)  # its holder finished and removed it between our open and our lock
    raise InputError(out, flag, "an output whose lock can be taken", str(lock))


def check_outputs(
    outputs: Mapping[str, str | os.PathLike | None], inputs: Mapping[str, str | os.PathLike | None] = ()
) -> dict[str, Path]:
    """Validate output paths (flag -> path; None entries are skipped) against the inputs
    (name -> path) and each other; create missing parent folders. Returns flag -> Path.
    Inside :func:`holding_outputs`, each output is also locked until the command ends."""
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
    held = _LOCKS.get()
    if held is not None:
        for flag, out in outs.items():
            _lock(flag, out, held)
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
    "holding_outputs",
    "refused_write",
    "write_bytes",
    "write_text",
]
