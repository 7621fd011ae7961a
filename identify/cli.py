"""`calbench`: the one console script. Subcommands from both packages (bench: simulate;
identify: the estimation verbs). Exit status: 0 success, 1 a check failed, 2 bad input."""
from __future__ import annotations

import argparse
import sys

from calbench.bench.cli import add_simulate
from calbench.bench.errors import InputError
from calbench.bench.view import add_view

from . import demo
from .design.plan import add_design
from .discover.workflow import add_discover
from .montecarlo import add_montecarlo
from .report import add_identify


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="calbench", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    add_simulate(sub)
    demo.add_demo(sub)
    add_identify(sub)
    add_montecarlo(sub)
    add_design(sub)
    add_view(sub)
    add_discover(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"calbench {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("calbench: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
