"""Fuzz (issue 10): a seeded generator of mutated logs and malformed scenarios, a few hundred
cases. None may give a traceback, exit 0 on bad data, or alter an input.

Mutated logs (from one small campaign, 4 poses): random bit flips anywhere after the magic, cuts
at random lengths, and schema-violating messages (a required field deleted, a value of the wrong
type, NaN or Infinity in a number, a fixed-length array one too long or short, a pose index
outside the plan, a bad state, a duplicated message, a missing channel, bytes that are not
JSON). The invariants:

* the one reader either refuses the log (InputError: exit status 2) or returns data identical
  to what was written, for the complete poses it returns (a cut log: a prefix of the poses);
  a schema-violating message is always refused;
* `calbench recover` either refuses (InputError) or writes a log that reads back, again with
  data identical to what was written;
* the command line (a sample of the cases) exits 2 exactly when the reader refuses;
* the input file is unchanged.

Malformed scenarios (from a small valid one): a required key deleted, a value of the wrong type,
NaN or infinity, zero or negative where a positive is needed, an array of the wrong length, an
unknown key, a bad start_time, absurd repeats, a joint beyond its limit: `calbench simulate`
exits 2 with one line and writes nothing.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import random
import tomllib
from pathlib import Path

import badcases as bc
import pytest

from calbench.bench.core import InputError
from calbench.bench.log import SCHEMAS, read_log, recover_log
from calbench.identify.cli import main

SEED = 20251201
N_FLIPS, N_CUTS, N_JSON, N_SCENARIOS = 120, 40, 110, 80


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    scn = d / "base.toml"
    scn.write_text(bc.scenario_text(n_poses=4))
    log = d / "base.mcap"
    assert main(["simulate", str(scn), "--out", str(log)]) == 0
    return d, scn, log, read_log(log, include_truth=True)


# --------------------------------------------------------------------------- comparing logs


def pose_data(log, p: int) -> tuple:
    """Everything a log says about pose p, as bytes."""
    ms = [
        (
            m.state,
            m.repeat,
            tuple(m.reflectors),
            m.position.tobytes(),
            m.covariance.tobytes(),
            m.visible.tobytes(),
        )
        for m in log.measurements
        if m.pose == p
    ]
    w = log.wrenches[p]
    out = (
        ms,
        log.poses[p].unloaded.tobytes(),
        log.poses[p].loaded.tobytes(),
        w.force.tobytes(),
        w.moment.tobytes(),
        w.site,
        w.mass,
    )
    if log.truth is not None and p in log.truth.joints:
        j = log.truth.joints[p]
        out += (
            j.unloaded.qpos.tobytes(),
            j.loaded.deflection.tobytes(),
            log.truth.reflectors[p].loaded.position_world.tobytes(),
        )
    return out


def same_as_written(got, ref) -> None:
    """``got`` holds only what ``ref`` (the log as written) holds, for its complete poses."""
    assert set(got.complete_poses) <= set(ref.complete_poses)
    assert got.header == ref.header
    assert got.n_poses_planned == ref.n_poses_planned
    for p in got.complete_poses:
        assert pose_data(got, p) == pose_data(ref, p), p
    if got.truth is not None and got.truth.parameters is not None:
        assert got.truth.parameters.compliance.tobytes() == ref.truth.parameters.compliance.tobytes()


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_log_case(mut: Path, ref, tmp: Path, run_cli: bool, capsys, must_refuse: bool) -> str:
    """The invariants of the module docstring for one mutated log; returns "refused",
    "accepted" or "cut" (accepted with fewer poses)."""
    before = digest(mut)
    try:
        got = read_log(mut, include_truth=True)
    except InputError:
        outcome = "refused"
    else:
        assert not must_refuse, "a schema-violating log was read"
        same_as_written(got, ref)
        outcome = "accepted" if got.complete_poses == ref.complete_poses else "cut"
    fixed = tmp / "fixed.mcap"
    try:
        recover_log(mut, fixed)
    except InputError:
        pass
    else:
        same_as_written(read_log(fixed, include_truth=True), ref)
    if run_cli:
        rc = main(["identify", str(mut), "--json", str(tmp / "id.json")])
        err = capsys.readouterr().err
        # a cut log may keep no pose to identify: then exit 2 as well, for that reason
        assert rc == {"refused": 2, "accepted": 0}.get(outcome, rc), err
        assert rc == 0 or outcome != "cut" or "complete pose" in err, err
        assert (tmp / "id.json").exists() == (rc == 0)
        if rc == 2:
            assert len(err.strip().splitlines()) == 1 and str(mut) in err
        (tmp / "id.json").unlink(missing_ok=True)
    assert digest(mut) == before
    return outcome


# --------------------------------------------------------------------------- bytes


def test_bit_flips_and_cuts(base, tmp_path, capsys):
    d, _, log, ref = base
    rng = random.Random(SEED)
    data = log.read_bytes()
    outcomes: dict[str, int] = {}
    for i in range(N_FLIPS + N_CUTS):
        mut = tmp_path / f"m{i}.mcap"
        if i < N_FLIPS:
            bc.flip_any_bit(log, mut, rng.randrange(1 << 30))
        else:
            bc.truncate(log, mut, rng.randrange(len(bc.MAGIC), len(data)))
        o = check_log_case(mut, ref, tmp_path, run_cli=i % 5 == 0, capsys=capsys, must_refuse=False)
        outcomes[o] = outcomes.get(o, 0) + 1
        mut.unlink()
    # most flips land in CRC-checked bytes; most cuts keep some poses
    assert outcomes.get("refused", 0) >= N_FLIPS // 2, outcomes
    assert outcomes.get("cut", 0) >= N_CUTS // 4, outcomes


def test_a_bit_flip_that_decompresses_is_always_caught(base, tmp_path):
    _, _, log, ref = base
    for seed in range(8):
        mut = bc.flip_bit_in_chunk(log, tmp_path / f"f{seed}.mcap", seed=seed)
        with pytest.raises(InputError, match="CRC mismatch"):
            read_log(mut)


# --------------------------------------------------------------------------- JSON


def leaves(msg, schema, path=()):
    """(path, schema) of every field a mutation can make invalid."""
    out = []
    if schema.get("type") == "object" and "properties" in schema:
        for k, sub in schema["properties"].items():
            if k in msg:
                out.append((path + (k,), sub, k in schema.get("required", ())))
                out += leaves(msg[k], sub, path + (k,))
    elif isinstance(msg, list) and "items" in schema:
        for i, v in enumerate(msg):
            if v is not None:
                out.append((path + (i,), schema["items"], False))
                out += leaves(v, schema["items"], path + (i,))
    return out


def wrong_value(rng, schema, value):
    """A value that breaks ``schema``, chosen among the ways the schema says."""
    types = schema.get("type")
    types = [types] if isinstance(types, str) else list(types or [])
    ways = []
    if "number" in types or "integer" in types:
        ways += [math.nan, math.inf, -math.inf, "1.0"]
    if "string" in types:
        ways += [3, True]
    if "array" in types:
        ways += ["[1, 2]", {"x": 1}]
        n = schema.get("maxItems")
        if n is not None and n == schema.get("minItems") and isinstance(value, list):
            ways += [value + value[:1], value[:-1]]
    if "boolean" in types:
        ways += ["yes", 1]
    if "object" in types:
        ways += [[1], "{}"]
    if "enum" in schema:
        ways += ["half-loaded"]
    if "minimum" in schema:
        ways += [-1]
    return rng.choice(ways)


def set_path(msg, path, value):
    for k in path[:-1]:
        msg = msg[k]
    if value is DELETE:
        del msg[path[-1]]
    else:
        msg[path[-1]] = value


DELETE = object()


def json_mutation(rng, topic, msg, n_poses):
    """A copy of ``msg`` that the reader must refuse, and what was done."""
    m = copy.deepcopy(msg)
    kind = rng.choice(["field", "field", "field", "required", "pose"])
    if kind == "pose" and "pose" in m:
        m["pose"] = rng.choice([n_poses, n_poses + 7, 999, -1])
        return m, f"pose {m['pose']}"
    fields = leaves(m, SCHEMAS[topic])
    req = [f for f in fields if f[2]]
    if kind == "required" and req:
        path, _, _ = rng.choice(req)
        set_path(m, path, DELETE)
        return m, f"delete {path}"
    path, schema, _ = rng.choice(fields)
    cur = m
    for k in path:
        cur = cur[k]
    v = wrong_value(rng, schema, cur)
    set_path(m, path, v)
    return m, f"{path} = {v!r}"


def test_schema_violating_messages_are_always_refused(base, tmp_path, capsys):
    d, _, log, ref = base
    rng = random.Random(SEED + 1)
    topics = [
        "/campaign/info",
        "/campaign/pose",
        "/campaign/wrench",
        "/tracker/measurement",
        "/campaign/pose_done",
        "/truth/parameters",
        "/truth/reflectors",
        "/truth/joints",
    ]
    n_poses = ref.n_poses_planned
    for i in range(N_JSON):
        mut = tmp_path / f"j{i}.mcap"
        special = i % 11
        if special == 0:  # a missing channel
            what = rng.choice(
                ["/campaign/info", "/campaign/pose", "/campaign/wrench", "/tracker/measurement"]
            )
            bc.drop_topic(log, mut, what)
        elif special == 1:  # not JSON
            target = (rng.choice(topics[1:5]), rng.randrange(n_poses))
            what = f"not JSON in {target}"
            bc.rewrite_json(log, mut, bc.edit_pose(*target, lambda m: json.dumps(m).encode()[:-3]))
        elif special == 2:  # a message given twice
            topic = rng.choice(topics[1:5])
            what = f"{topic} twice"
            dup = []

            def edit(t, m, topic=topic, dup=dup):
                if t == topic and not dup:
                    dup.append(m)
                    return m
                if t == topic and len(dup) == 1:
                    dup.append(m)
                    return dup[0]
                return m

            bc.rewrite_json(log, mut, edit)
        else:
            topic = rng.choice(topics)
            pose = rng.randrange(n_poses)
            hit = []

            def edit(t, m, topic=topic, pose=pose, hit=hit):
                if t == topic and not hit and m.get("pose", pose) == pose:
                    new, desc = json_mutation(rng, topic, m, n_poses)
                    hit.append(desc)
                    return new
                return m

            bc.rewrite_json(log, mut, edit)
            what = f"{topic}: {hit}"
        try:
            check_log_case(mut, ref, tmp_path, run_cli=i % 4 == 0, capsys=capsys, must_refuse=True)
        except AssertionError as e:
            raise AssertionError(f"case {i}: {what}: {e}") from None
        mut.unlink()


# --------------------------------------------------------------------------- scenarios


def toml(doc: dict, path=()) -> str:
    """A TOML writer that also writes what a careless user would: nan, inf, any type."""

    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if v != v else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
        if isinstance(v, (int,)):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + "}"
        raise TypeError(v)

    lines, tables, arrays = [], [], []
    for k, v in doc.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            arrays.append((k, v))
        else:
            lines.append(f"{k} = {val(v)}")
    for k, v in tables:
        lines.append(f"\n[{'.'.join(path + (k,))}]")
        lines.append(toml(v, path + (k,)))
    for k, v in arrays:
        for x in v:
            lines.append(f"\n[[{'.'.join(path + (k,))}]]")
            lines.append(toml(x, path + (k,)))
    return "\n".join(lines)


REQUIRED = [
    ("robot",),
    ("seed",),
    ("truth",),
    ("truth", "compliance"),
    ("truth", "compensator"),
    ("truth", "compensator", "stiffness"),
    ("truth", "compensator", "preload"),
    ("tracker",),
    ("tracker", "position"),
    ("load",),
    ("load", "mass"),
    ("pose",),
    ("pose", 0, "q"),
]
POSITIVE = [("truth", "compliance", 2), ("tracker", "sigma"), ("load", "mass"), ("pose", 1, "repeats")]
VECTORS = [("truth", "compliance"), ("tracker", "position"), ("pose", 0, "q"), ("pose", 1, "q")]
NUMBERS = [
    ("truth", "compliance", 0),
    ("truth", "compensator", "stiffness"),
    ("tracker", "sigma"),
    ("tracker", "position", 1),
    ("load", "mass"),
    ("pose", 0, "q", 3),
    ("tracker", "yaw"),
]


def scenario_mutation(rng, doc):
    m = copy.deepcopy(doc)
    kind = rng.choice(
        ["required", "type", "nonfinite", "positive", "length", "unknown", "start_time", "repeats", "limit"]
    )
    if kind == "required":
        path = rng.choice(REQUIRED)
        set_path(m, path, DELETE)
    elif kind == "type":
        path = rng.choice(NUMBERS + VECTORS + [("robot",), ("seed",)])
        cur = m
        for k in path:
            cur = cur.get(k) if isinstance(cur, dict) else cur[k]
        set_path(m, path, rng.choice(["x", [1], {"a": 1}] if not isinstance(cur, str) else [3, [1]]))
    elif kind == "nonfinite":
        path = rng.choice(NUMBERS)
        set_path(m, path, rng.choice([math.nan, math.inf, -math.inf]))
    elif kind == "positive":
        path = rng.choice(POSITIVE)
        set_path(m, path, rng.choice([0, -1, -1.5]) if path[-1] != "repeats" else rng.choice([0, -3]))
    elif kind == "length":
        path = rng.choice(VECTORS)
        cur = m
        for k in path:
            cur = cur[k]
        set_path(m, path, cur + [1.0] if rng.random() < 0.5 else cur[:-1])
    elif kind == "unknown":
        table = rng.choice([(), ("truth",), ("tracker",), ("load",), ("pose", 0)])
        cur = m
        for k in table:
            cur = cur[k]
        cur["colour"] = 3
        path = table + ("colour",)
    elif kind == "start_time":
        path = ("start_time",)
        m["start_time"] = rng.choice(
            ["tomorrow", "2024-13-01T00:00:00Z", "1969-12-31T23:00:00Z", "2024-03-01T09:30:00", 17]
        )
    elif kind == "repeats":
        path = ("pose", 0, "repeats")
        m["pose"][0]["repeats"] = rng.choice([10**9, 10**12, 2**62])
    else:
        path = ("pose", 1, "q", 0)
        m["pose"][1]["q"][rng.choice([0, 1, 2])] = rng.choice([400.0, -400.0, 1e6])
    return m, kind, path


def test_malformed_scenarios(base, tmp_path, capsys):
    d, scn, _, _ = base
    doc = tomllib.loads(scn.read_text())
    rng = random.Random(SEED + 2)
    kinds = set()
    for i in range(N_SCENARIOS):
        m, kind, path = scenario_mutation(rng, doc)
        kinds.add(kind)
        bad = tmp_path / f"s{i}.toml"
        bad.write_text(toml(m))
        before = digest(bad)
        out = tmp_path / f"s{i}.mcap"
        rc = main(["simulate", str(bad), "--out", str(out)])
        err = capsys.readouterr().err.strip()
        assert rc == 2, (kind, path, bad.read_text())
        assert len(err.splitlines()) == 1 and str(bad) in err, (kind, path, err)
        assert not out.exists() and digest(bad) == before
    assert len(kinds) == 9


def test_the_generator_is_seeded(base):
    """Same seed, same cases: a failure can be replayed."""
    _, scn, _, _ = base
    doc = tomllib.loads(scn.read_text())
    a = [scenario_mutation(random.Random(5), doc)[1:] for _ in range(3)]
    b = [scenario_mutation(random.Random(5), doc)[1:] for _ in range(3)]
    assert a == b
