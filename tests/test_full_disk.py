"""A disk that fills (or a file-size limit) under any output: one line naming the path and the
cause, exit status 2, no temporary file left, the earlier file of that name intact; a campaign
log cut by a full disk keeps its finished poses readable (bench/core/outputs.py, the log writer).

The full disk is a small tmpfs mounted for the test (root only: skipped with the reason where
mounting is not allowed); the file-size limit (RLIMIT_FSIZE, EFBIG) works everywhere."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from conftest import PAPER, wait_for_lock

from calbench.bench.core import WriteError, atomic_path
from calbench.bench.log import read_log
from calbench.identify.cli import main


def digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def error_line(err: str) -> str:
    """The one error line of a verb's stderr (progress lines may precede it; no traceback)."""
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and err.rstrip().endswith(errors[0]), err
    return errors[0]


def _mount(where: Path, size: int) -> None:
    where.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs (a disk that can fill) needs root")
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True, text=True
    )
    if r.returncode != 0:
        pytest.skip(f"this machine refuses to mount a tmpfs: {r.stderr.strip()[:120]}")


def _umount(where: Path) -> None:
    subprocess.run(["umount", "-l", str(where)], capture_output=True)


def _fill(disk: Path) -> None:
    """Write zeros until the file system says ENOSPC."""
    with open(disk / "filler", "wb", buffering=0) as f:
        block = bytes(4096)
        while True:
            try:
                f.write(block)
            except OSError as e:
                assert e.errno == errno.ENOSPC
                return


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fulldisk")
    (d / "s.toml").write_text(
        PAPER.read_text().replace('robot = "../mjcf/', f'robot = "{PAPER.parent.parent}/mjcf/')
    )
    assert main(["simulate", str(d / "s.toml"), "--out", str(d / "l.mcap")]) == 0
    (d / "study.toml").write_text(
        f'scenario = "{(d / "s.toml").as_posix()}"\nseeds = 2\n[[axis]]\nkey = "tracker.sigma"\nvalues = [2e-5]\n'
    )
    return d


@pytest.fixture()
def full_disk(tmp_path):
    disk = tmp_path / "disk"
    _mount(disk, 1 << 20)
    try:
        yield disk
    finally:
        _umount(disk)


def verbs(w: Path, disk: Path) -> dict[str, tuple[list[str], Path]]:
    s, log = str(w / "s.toml"), str(w / "l.mcap")
    return {
        "identify --json": (["identify", log, "--json", str(disk / "id.json")], disk / "id.json"),
        "design --out": (
            ["design", s, "--out", str(disk / "plan.toml"), "--candidates", "50"],
            disk / "plan.toml",
        ),
        "montecarlo --json": (
            ["montecarlo", s, "--runs", "2", "--json", str(disk / "mc.json")],
            disk / "mc.json",
        ),
        "export --csv": (["export", log, "--csv", str(disk / "r.csv")], disk / "r.csv"),
        "report --out": (["report", log, "--out", str(disk / "r.html")], disk / "r.html"),
        "recover --out": (["recover", log, "--out", str(disk / "rec.mcap")], disk / "rec.mcap"),
        "view --rrd": (["view", log, "--rrd", str(disk / "v.rrd")], disk / "v.rrd"),
        "discover --json": (["discover", log, "--json", str(disk / "d.json")], disk / "d.json"),
        "study --out": (
            ["study", str(w / "study.toml"), "--out", str(disk / "s.parquet")],
            disk / "s.parquet",
        ),
    }


VERBS = [
    "identify --json",
    "design --out",
    "montecarlo --json",
    "export --csv",
    "report --out",
    "recover --out",
    "view --rrd",
    "discover --json",
    "study --out",
]


@pytest.mark.parametrize("verb", VERBS)
def test_a_full_disk_under_an_output_is_one_line_and_the_earlier_file_survives(work, full_disk, verb, capsys):
    argv, out = verbs(work, full_disk)[verb]
    earlier = verb != "study --out"  # a study resumes from its --out: an earlier file must be its own
    if earlier:
        out.write_bytes(b"the earlier file\n")
        before = digest(out)
    _fill(full_disk)
    capsys.readouterr()
    assert main(argv) == 2
    err = error_line(capsys.readouterr().err)
    # the file it could not write (discover writes its plot beside the JSON first)
    assert re.search(rf"cannot write {re.escape(str(full_disk))}/\S+: the disk is full", err), err
    if earlier:
        assert digest(out) == before
    else:
        assert not out.exists()
    left = {p.name for p in full_disk.iterdir()} - {"filler", out.name}
    if verb == "study --out":  # a study's journal of finished campaigns is kept for the rerun
        left = {n for n in left if not (n == "s.parquet.parts" and (full_disk / n).is_dir())}
        assert not [p for p in full_disk.rglob("*") if p.is_file() and p.name not in ("filler", out.name)]
    assert not left, left  # no temporary file


def test_a_campaign_log_cut_by_a_full_disk_keeps_its_finished_poses(work, tmp_path, capsys):
    """The disk holds about half of the log: the campaign stops with one line naming
    how many poses are kept, and the log reads with exactly those poses, as after a SIGKILL."""
    whole = (work / "l.mcap").stat().st_size
    disk = tmp_path / "disk"
    _mount(disk, (whole // 2) // 4096 * 4096)
    try:
        out = disk / "cut.mcap"
        capsys.readouterr()
        assert main(["simulate", str(work / "s.toml"), "--out", str(out)]) == 2
        err = error_line(capsys.readouterr().err)
        assert str(out) in err and "disk is full" in err, err
        kept = int(re.search(r"keeps its (\d+) finished poses", err).group(1))
        assert 0 < kept < 16
        log = read_log(out)
        assert log.complete_poses == list(range(kept)) and log.truncated
        full = read_log(work / "l.mcap")
        for p in range(kept):  # the kept poses are the campaign's own, unchanged
            assert (log.poses[p].unloaded == full.poses[p].unloaded).all()
            assert (log.poses[p].loaded == full.poses[p].loaded).all()
    finally:
        _umount(disk)


def _limit_file_size(limit: int):
    def set_limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return set_limit


def test_a_file_size_limit_is_named_not_a_traceback(work, tmp_path):
    """RLIMIT_FSIZE (Python ignores SIGXFSZ, so the write fails with EFBIG): identify's JSON."""
    out = tmp_path / "id.json"
    out.write_text("earlier\n")
    r = subprocess.run(
        [sys.executable, "-m", "calbench.identify.cli", "identify", str(work / "l.mcap"), "--json", str(out)],
        capture_output=True,
        text=True,
        preexec_fn=_limit_file_size(4096),
    )
    assert r.returncode == 2, r.stderr
    err = error_line(r.stderr)
    assert str(out) in err and "EFBIG" in err, err
    assert out.read_text() == "earlier\n"
    assert [p.name for p in tmp_path.iterdir()] == ["id.json"]


def test_a_refused_write_inside_atomic_path_is_a_write_error(tmp_path):
    out = tmp_path / "x.json"
    out.write_text("old")
    with pytest.raises(WriteError, match=r"x\.json: the disk is full \(ENOSPC\); the earlier file"):
        with atomic_path(out) as tmp:
            tmp.write_text("new, half")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert out.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["x.json"]
    with pytest.raises(ValueError):  # anything else passes through unchanged
        with atomic_path(tmp_path / f"{uuid.uuid4().hex}.json"):
            raise ValueError("a bug")
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]


def test_a_read_only_folder_is_refused_before_any_work(work, tmp_path, capsys):
    disk = tmp_path / "ro"
    _mount(disk, 1 << 16)
    try:
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        capsys.readouterr()
        assert main(["identify", str(work / "l.mcap"), "--json", str(disk / "id.json")]) == 2
        err = error_line(capsys.readouterr().err)
        assert "Read-only file system" in err and "--json" in err, err
    finally:
        _umount(disk)
    shutil.rmtree(disk, ignore_errors=True)


def test_a_second_run_on_the_same_output_is_refused_while_the_first_writes(work, tmp_path):
    """Two `calbench montecarlo --json` on one file: the one that starts second is refused with
    one line naming the first, and the file is the first run's, whole."""
    out = tmp_path / "mc.json"
    argv = [
        sys.executable,
        "-m",
        "calbench.identify.cli",
        "montecarlo",
        str(work / "s.toml"),
        "--json",
        str(out),
    ]
    # long enough to outlast the second's start-up (imports, ~1-2 s): 60 runs took 0.8 s on an
    # idle machine, and the first had finished before the second looked at the lock
    first = subprocess.Popen([*argv, "--runs", "600"], stderr=subprocess.PIPE, text=True)
    wait_for_lock(out, first)
    second = subprocess.run([*argv, "--runs", "2"], capture_output=True, text=True)
    assert first.wait(timeout=300) == 0, first.stderr.read()
    assert second.returncode == 2
    err = error_line(second.stderr)
    assert f"calbench pid {first.pid} is writing it" in err and str(out) in err, err
    report = json.loads(out.read_text())
    assert report["runs"] == 600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mc.json"]  # the lock is gone
