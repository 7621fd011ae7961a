"""Running the `rerun` CLI from tests: a scratch HOME so it writes no settings of the user's,
and analytics off (CI=1 stops its first-run prompt and telemetry)."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest


def rerun_env(tmp_path: Path) -> dict:
    home = tmp_path / "home"
    home.mkdir(exist_ok=True)
    return {
        **os.environ,
        "HOME": str(home),
        "XDG_CONFIG_HOME": str(home / ".config"),
        "XDG_DATA_HOME": str(home / ".local/share"),
        "XDG_CACHE_HOME": str(home / ".cache"),
        "CI": "1",
        "RERUN_ANALYTICS": "0",
    }


def rerun_exe() -> str:
    exe = Path(sys.executable).with_name("rerun")
    found = str(exe) if exe.exists() else shutil.which("rerun")
    if not found:
        pytest.skip("rerun CLI not installed")
    return found
