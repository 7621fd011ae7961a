"""Where the public robot packages and cases of ``../shared/data`` are, for the tests that need them.

The data are never copied into the project (``../shared/data/README.md``): a test asks
:func:`shared_data` for a path and is skipped, with the reason named, where it is absent (a
user's clone). Looked for in ``$CALBENCH_SHARED_DATA``, else in ``shared/data`` beside the
checkout or beside any folder above it (a git worktree sits one level deeper than the clone).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def shared_root() -> Path | None:
    """The shared data folder, or None."""
    env = os.environ.get("CALBENCH_SHARED_DATA")
    if env:
        return Path(env) if Path(env).is_dir() else None
    for up in ROOT.parents:
        if (up / "shared" / "data").is_dir():
            return up / "shared" / "data"
    return None


def shared_data(*parts: str) -> Path:
    """The path ``../shared/data/<parts>``; skips the calling test where it is absent."""
    root = shared_root()
    path = None if root is None else root.joinpath(*parts)
    if path is None or not path.exists():
        pytest.skip(f"needs ../shared/data/{'/'.join(parts)} (public robot data, not shipped with calbench)")
    return path
