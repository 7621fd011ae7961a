"""Make the tests folder importable for its small shared helpers (tests/rerun_cli.py)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
