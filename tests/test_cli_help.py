"""Small things a newcomer meets (issue 10): every flag's help says its default (or that it is
required), every benchmark takes --quick for `make bench QUICK=1`, and the Makefile says what
it is doing."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest
from conftest import ROOT

from calbench.identify.cli import build_parser, main


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_every_flag_says_its_default():
    missing = []
    for name, sp in [("calbench", build_parser()), *subcommands().items()]:
        for a in sp._actions:
            if not a.option_strings or isinstance(
                a, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)
            ):
                continue
            text = (a.help or "") % {"default": a.default} if a.help else ""
            if not ("default" in text or (a.required and "required" in text)):
                missing.append(f"{name} {a.option_strings[-1]}: {a.help!r}")
    assert missing == []


@pytest.mark.parametrize("verb", sorted(subcommands()))
def test_every_subcommand_help_prints(verb, capsys):
    with pytest.raises(SystemExit) as e:
        main([verb, "--help"])
    assert e.value.code == 0
    assert "usage: calbench " + verb in capsys.readouterr().out


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("calbench ")


@pytest.mark.parametrize("bench", sorted(p.name for p in (ROOT / "benchmarks").glob("*_bench.py")))
def test_every_benchmark_takes_quick(bench):
    r = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / bench), "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    assert "--quick" in r.stdout


def test_make_bench_passes_quick_and_says_what_it_does():
    r = subprocess.run(
        ["make", "-n", "bench", "QUICK=1"], capture_output=True, text=True, cwd=ROOT, timeout=60
    )
    if r.returncode != 0 and "No rule" not in r.stderr:
        pytest.skip(f"make unavailable: {r.stderr.strip()}")
    assert "--quick" in r.stdout and "progress on stderr" in r.stdout
    text = (ROOT / "Makefile").read_text()
    assert "about 90 s" in text and "name as your package" in text and "harmless" in text
