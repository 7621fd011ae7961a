"""The case table of issue 10: every bad input of the issue, run through the real command line.

    .venv/bin/python tests/case_table.py [--calbench PATH] [--out TABLE.md]

Prints a markdown table (case, exit status, first line of the message). Run against main
before the changes and against the branch after; the tests assert the same cases one by one
(tests/test_outputs.py, test_logread.py, test_interrupt.py, test_checks.py, test_timeline.py,
test_cli_help.py, test_fuzz.py). Not collected by pytest (no test_ prefix).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import badcases as bc  # noqa: E402
from conftest import PAPER  # noqa: E402


def first_line(r: subprocess.CompletedProcess) -> str:
    text = (r.stderr or "").strip() or (r.stdout or "").strip()
    lines = [x for x in text.splitlines() if x.strip()]
    if not lines:
        return ""
    if "Traceback" in lines[0]:
        return "Traceback ... " + lines[-1][:150]
    return lines[0][:160]


def mention(r: subprocess.CompletedProcess, words=("lost", "truncated")) -> str:
    text = (r.stdout or "") + (r.stderr or "")
    hits = [x.strip() for x in text.splitlines() if any(w in x for w in words)]
    return hits[0][:160] if hits else "(no mention of lost poses or truncation)"


class Runner:
    def __init__(self, exe: str, tmp: Path):
        self.exe = exe
        self.tmp = tmp
        self.rows: list[tuple[str, str, str]] = []

    def run(self, *args, timeout=600, **kw) -> subprocess.CompletedProcess:
        return subprocess.run(
            [self.exe, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=self.tmp, **kw
        )

    def row(self, case: str, status, msg: str) -> None:
        self.rows.append((case, str(status), msg.replace("|", "\\|")))
        print(f"{case}: {status}: {msg}", file=sys.stderr, flush=True)

    def cmd(self, case: str, *args, show=first_line, **kw) -> subprocess.CompletedProcess:
        try:
            r = self.run(*args, **kw)
        except subprocess.TimeoutExpired as e:
            self.row(case, "timeout", f"still running after {e.timeout:.0f} s")
            return None
        self.row(case, r.returncode, show(r))
        return r


def flags_without_default(help_text: str) -> list[str]:
    """Options of an argparse help text that take a value but state no default (and are not
    required)."""
    import re

    opts = help_text.split("options:", 1)[-1]
    blocks = re.split(r"\n(?=  -)", opts)
    out = []
    for b in blocks:
        m = re.match(r"\s*(?:-\w(?: [A-Z_]+)?, )?(--[\w-]+) [A-Z_{]", b)
        if m and "default" not in b and "required" not in b:
            out.append(m.group(1))
    return out


def make_reader_opens(path: Path) -> str:
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            r = make_reader(f)
            s = r.get_summary()
            n = sum(1 for _ in r.iter_messages())
        return f"make_reader opens it ({n} messages, summary {'present' if s else 'absent'})"
    except Exception as e:  # noqa: BLE001
        return f"make_reader fails: {type(e).__name__}: {str(e)[:80]}"


def rerun_info(path: Path, tmp: Path) -> str:
    from rerun_cli import rerun_env

    exe = Path(sys.executable).with_name("rerun")
    r = subprocess.run(
        [str(exe), "mcap", "info", str(path)], env=rerun_env(tmp), capture_output=True, text=True, timeout=120
    )
    return f"rerun mcap info: exit {r.returncode}"


def sigint_mid_campaign(exe: str, scenario: Path, out: Path, min_bytes: int) -> subprocess.CompletedProcess:
    p = subprocess.Popen(
        [exe, "simulate", str(scenario), "--out", str(out)],
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    t0 = time.time()
    while time.time() - t0 < 60 and (not out.exists() or out.stat().st_size < min_bytes):
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    so, se = p.communicate(timeout=120)
    return subprocess.CompletedProcess(p.args, p.returncode, so, se)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calbench", default=str(Path(sys.executable).with_name("calbench")))
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="calbench-cases-"))
    R = Runner(args.calbench, tmp)
    log = tmp / "paper.mcap"
    R.run("simulate", PAPER, "--out", log)
    before = {p: p.read_bytes() for p in [log]}

    def mutated(name, edit=None, **kw):
        return bc.rewrite_json(log, tmp / name, edit, **kw)

    def first(topic, fn, pose=3):
        return bc.edit_pose(topic, pose, fn)

    q5 = mutated("q5.mcap", first("/campaign/pose", lambda m: m.update(q=m["q"][:5])))
    novis = mutated("novis.mcap", first("/tracker/measurement", lambda m: m.pop("visible")))
    strpos = mutated(
        "strpos.mcap", first("/tracker/measurement", lambda m: m["position"].__setitem__(0, "1.0, 2.0, 3.0"))
    )
    inf = mutated(
        "inf.mcap", first("/tracker/measurement", lambda m: m["position"][0].__setitem__(2, float("inf")))
    )
    nancov = mutated(
        "nancov.mcap",
        first("/tracker/measurement", lambda m: m["covariance"][0][1].__setitem__(1, float("nan"))),
    )
    p999 = mutated("p999.mcap", lambda t, m: {**m, "pose": 999} if m.get("pose") == 15 else m)
    nowrench = bc.drop_topic(log, tmp / "nowrench.mcap", "/campaign/wrench")
    flip = bc.flip_bit_in_chunk(log, tmp / "flip.mcap", seed=1)
    cut = bc.truncate(log, tmp / "cut.mcap", int(log.stat().st_size * 0.6))

    R.cmd("identify: a 5-element q", "identify", q5)
    R.cmd("identify: missing `visible`", "identify", novis)
    R.cmd("identify: a string where a position belongs", "identify", strpos)
    R.cmd("identify --json: an Infinity position", "identify", inf, "--json", tmp / "inf.json")
    R.cmd("identify: a NaN covariance", "identify", nancov)
    R.cmd("identify: pose 999 in a 16-pose campaign", "identify", p999)
    R.cmd("discover: pose 999 in a 16-pose campaign", "discover", p999, "--json", tmp / "d999.json")
    R.cmd("identify: no /campaign/wrench channel", "identify", nowrench)
    R.cmd("identify: a bit-flipped chunk that still decompresses", "identify", flip)
    R.cmd("discover: the same bit-flipped chunk", "discover", flip, "--json", tmp / "dflip.json")
    R.cmd("view: the same bit-flipped chunk", "view", flip, "--rrd", tmp / "flip.rrd")
    R.cmd(
        "discover: a truncated log (says lost/truncated?)",
        "discover",
        cut,
        "--json",
        tmp / "dcut.json",
        show=mention,
    )
    R.cmd("view: a truncated log (says lost/truncated?)", "view", cut, "--rrd", tmp / "cut.rrd", show=mention)

    # interrupted campaigns
    big = tmp / "big.toml"
    big.write_text(bc.scenario_text(n_poses=16, repeats=400))
    ctrlc = tmp / "ctrlc.mcap"
    r = sigint_mid_campaign(args.calbench, big, ctrlc, min_bytes=300_000)
    R.row(
        "simulate, Ctrl-C mid-campaign",
        r.returncode,
        f"{first_line(r)}; {make_reader_opens(ctrlc)}; {rerun_info(ctrlc, tmp)}",
    )
    killed = bc.truncate(ctrlc, tmp / "killed.mcap", int(ctrlc.stat().st_size * 0.7))
    R.row("SIGKILL-like cut log opened by make_reader", "-", make_reader_opens(killed))
    r = R.cmd("recover KILLED.mcap --out FIXED.mcap", "recover", killed, "--out", tmp / "fixed.mcap")
    if r is not None and r.returncode == 0:
        R.row(
            "  ... FIXED.mcap",
            "-",
            f"{make_reader_opens(tmp / 'fixed.mcap')}; {rerun_info(tmp / 'fixed.mcap', tmp)}",
        )
    R.cmd(
        "recover FLIPPED.mcap --out FIXED2.mcap (the bit-flipped log)",
        "recover",
        flip,
        "--out",
        tmp / "fixed2.mcap",
    )
    (tmp / "notmcap.mcap").write_text("hello\n")
    R.cmd("recover on a non-MCAP file", "recover", tmp / "notmcap.mcap", "--out", tmp / "x.mcap")
    huge = tmp / "huge.toml"
    huge.write_text(bc.scenario_text(n_poses=2, repeats=1000000000))
    R.cmd("simulate: repeats = 1000000000", "simulate", huge, "--out", tmp / "huge.mcap", timeout=20)
    # checks that can be trusted
    for seed in (1, 7):
        two = tmp / f"two{seed}.toml"
        two.write_text(
            bc.scenario_text(poses=[[0, 0, -30, 0, 0, 0], [0, 120, 30, 0, 0, 0]]).replace(
                "seed = 3", f"seed = {seed}"
            )
        )
        R.run("simulate", two, "--out", tmp / f"two{seed}.mcap")
        r = R.run("identify", tmp / f"two{seed}.mcap", "--check")
        stiff = [
            " ".join(x.split())
            for x in r.stdout.splitlines()
            if x.strip().startswith("compensator_stiffness")
        ]
        warn = " (did not converge)" if "did not converge" in r.stdout else ""
        R.row(
            f"identify --check, 2 poses q2 in {{0, 120}}, seed {seed}",
            r.returncode,
            (stiff[0] if stiff else "") + warn + " / " + r.stdout.strip().splitlines()[-1][:90],
        )
    R.cmd(
        "design --configs 30 --candidates 20",
        "design",
        PAPER,
        "--configs",
        30,
        "--candidates",
        20,
        "--json",
        tmp / "d.json",
    )
    R.cmd("design --candidates 0", "design", PAPER, "--candidates", 0, "--json", tmp / "d0.json")
    # timestamps
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    topics, seq = {}, []
    with open(log, "rb") as f:
        for rec in StreamReader(f).records:
            if isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                seq.append((rec.log_time, topics[rec.channel_id], json.loads(rec.data)))
    t0 = seq[0][0]
    ordered = all(a[0] < b[0] for a, b in zip(seq, seq[1:]))
    p0 = [(t, tp, m.get("state")) for t, tp, m in seq if m.get("pose") == 0 and not tp.startswith("/truth")]
    kinds = [f"{tp.split('/')[-1]}{'/' + s if s else ''}" for _, tp, s in p0]
    order = []
    for k in kinds:
        if not order or order[-1] != k:
            order.append(k)
    R.row(
        "log times: start and pose 0's message order",
        "-",
        f"first log time {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(t0 / 1e9))}; "
        f"file order increasing: {ordered}; pose 0: {' > '.join(order)}",
    )
    bad_start = tmp / "badstart.toml"
    bad_start.write_text(bc.scenario_text(n_poses=2, extra='start_time = "yesterday"'))
    R.cmd('simulate: start_time = "yesterday"', "simulate", bad_start, "--out", tmp / "bs.mcap")
    # help text
    missing = []
    for verb in ("simulate", "identify", "montecarlo", "design", "view", "discover", "demo", "recover"):
        r = R.run(verb, "--help")
        if r.returncode != 0:
            missing.append(f"{verb} (no such command)")
            continue
        missing += [f"{verb} {flag}" for flag in flags_without_default(r.stdout)]
    R.row("--help: value flags without a default shown", "-", ", ".join(missing) or "none")
    # inputs unchanged
    R.row("inputs unchanged after all cases", "-", str(all(p.read_bytes() == b for p, b in before.items())))

    lines = ["| case | exit | first line of the message |", "| --- | --- | --- |"]
    lines += [f"| {c} | {s} | {m} |" for c, s, m in R.rows]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
