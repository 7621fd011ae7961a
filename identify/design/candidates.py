"""Feasible measurement configurations and their Fisher information blocks (issue 4, §2).

A candidate is a commanded configuration q (rad, controller convention) and a load: either the
scenario's ``[load]`` mass hanging at the payload site ("vertical") or a horizontal pull
("lateral", paper §5.1: vertical loads cannot turn J1, so k1 needs a non-vertical load)
of ``lateral_force`` newtons perpendicular to the arm's vertical plane, direction
(-sin q1, cos q1, 0) times a random sign. Like a ``[[pose]] wrench``, the pull REPLACES the
payload in the loaded state.

The rules a candidate must pass are in identify/design/feasibility.py, its information block in
identify/design/engine.py, the settings and the nominal model in identify/design/settings.py.

The candidate-set NPZ (`design --export-candidates`, `design --from-candidates`), issue 16.

Arrays written by calbench (only ``q`` and ``blocks`` are required on reading, so any other
tool's candidates can be optimised by calbench, and calbench's by any other tool):

* ``q`` (N, n): commanded joint angles, degrees, one per actuated joint (the FANUC's 6).
* ``blocks`` (N, m, p): candidate i's regressor R_i, so that sum_i R_i^T R_i over a plan is its
  Fisher information. Rows: the x, y, z deflection of each reflector (m = 9 for 3; rows of
  reflectors a candidate cannot see are zero). Columns: the p parameters theta_k / theta0_k
  of the robot's layout (bench/model/params.py; the FANUC's 8: k1..k6, K_C, s0). Each row is
  WHITENED by the tracker noise (R = L^-1 J with L L^T the covariance of a deflection, i.e.
  of two readings: sqrt(2) x 20 um per axis on the paper scenario), and each column is SCALED BY theta0 (J = d deflection / d(theta / theta0)). So an
  entry is "how many noise sigmas this reflector coordinate moves when parameter k changes by
  100 % of its prior value".
  Column scales (RMS over all rows of the 10^4 candidates of scenarios/paper_table5.toml):
  k1 71.3, k2 29.3, k3 48.1, k4 22.0, k5 35.3, k6 6.1, K_C 1.9, s0 6.1; the diagonal of the mean
  information R^T R spans 3.5 (K_C) to 5100 (k1), that of one candidate 0 to 5.1e4.
* ``wrench`` (N, 6), ``load_kind`` (N,) "vertical" | "lateral", ``theta0`` (p,), ``param_names``
  (p,), ``note``: what the arrays mean.

``--normalise`` divides each column by its RMS scale s (certificate.normalise_blocks; written
as ``column_scale``, so blocks * column_scale restores the raw ones). The mean information then
has a unit diagonal, which tools that divide by diagonal entries need (FIGAROH 1.0.2's SOCP
fails with ZeroDivisionError on the raw blocks). Every plan's log det moves by the same
-2 sum ln s_k, so the D-optimal plan does not change; A (trace) plans do.

Reading validates the file as user input: a missing array, a wrong shape or a non-finite entry
raises InputError naming the file and the array (exit status 2 on the command line).
"""

from __future__ import annotations

import functools
import os
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError, ProgressSink, sink
from calbench.bench.scenario import Scenario
from calbench.identify.runtime import IN_PROCESS, Executor, InProcess, PortableScenario

from .engine import InfoEngine
from .feasibility import LOAD_KINDS, RULES, lateral_wrench, sample_commands, tally_rules
from .optimal import normalise_blocks
from .settings import DesignSettings

# --------------------------------------------------------------------------- candidate set


@dataclass
class CandidateSet:
    q: np.ndarray  # (N, n_joints) rad
    wrench: np.ndarray  # (N, 6)
    kind: np.ndarray  # (N,) 0 vertical, 1 lateral
    blocks: np.ndarray  # (N, m, p)
    theta0: np.ndarray
    settings: DesignSettings
    stats: dict = field(default_factory=dict)
    param_names: tuple[str, ...] = ()  # the p parameters (the robot's layout)

    def __len__(self) -> int:
        return len(self.q)

    def save_npz(self, path: str | Path, normalise: bool = False) -> None:
        """The NPZ of the module docstring (``normalise``: unit column scales)."""
        write_candidates(
            path, self.q, self.blocks, self.wrench, self.kind, self.theta0, self.param_names, normalise
        )


MAX_DRAWS = 200  # raw commands per candidate asked for, at most


def hopeless(found: int, raw: int, n: int) -> bool:
    """Give up drawing (still short of n): past MAX_DRAWS n raw commands, or, after a full BATCH,
    when even an optimistic feasible share (found + 3 + 2 sqrt(found), about the 97.5 % Poisson
    upper bound; 3 for none found) is below 1 / MAX_DRAWS: 0 of 4096 gives up in a second, not
    after 2 million draws."""
    if raw > MAX_DRAWS * n:
        return True
    return raw >= BATCH and (found + 3 + 2 * np.sqrt(found)) * MAX_DRAWS < raw


CANDIDATE_BLOCK = 512  # raw commands per chunk (a few tenths of a second of batched work)
BATCH = 4096  # commands drawn at a time (the order of the random stream)
SECONDS_PER_CANDIDATE = 2e-4  # in-process, batched (10^4 in ~1.7 s of CPU), for the executor choice


@dataclass(frozen=True)
class CandidateJob:
    """What a chunk of raw commands needs on any machine (identify/runtime/executor.py): the scenario's
    texts, the settings, the load probabilities, and how to compute (batched, threads)."""

    scenario: PortableScenario
    settings: DesignSettings
    p_vertical: float
    p_lateral: float
    batched: bool = True
    threads: int = 1


@functools.lru_cache(maxsize=2)
def _engine(scenario: PortableScenario, settings: DesignSettings) -> InfoEngine:
    return InfoEngine(scenario.scenario(), settings)


@functools.lru_cache(maxsize=2)
def _batch(job: CandidateJob):
    from .batch_info import BatchInfo

    return BatchInfo(_engine(job.scenario, job.settings), nthread=job.threads)


def candidate_block(job: CandidateJob, q, signs, u_lat, u_vert) -> dict:
    """The task: one chunk of raw commands (see :func:`scalar_block`), on this process's engine
    for the job (built once per process; a chunk's result does not depend on the chunks before)."""
    if job.batched:
        return _batch(job).block(q, signs, u_lat, u_vert, job.p_vertical, job.p_lateral)
    return scalar_block(
        _engine(job.scenario, job.settings), q, signs, u_lat, u_vert, job.p_vertical, job.p_lateral
    )


def scalar_block(eng: InfoEngine, q, signs, u_lat, u_vert, p_vertical: float, p_lateral: float) -> dict:
    """One chunk of raw commands, one candidate at a time (InfoEngine.pose): the reference that
    identify/design/batch_info.BatchInfo.block reproduces. Returns the feasible candidates as
    (q, wrench, kind, block) in command order, the rejections by first rule, and how many
    commands passed the command rules with a load."""
    st = eng.settings
    vertical = np.concatenate([eng.robot.weight(eng.scn.load_mass), np.zeros(3)])
    rejected = {r: 0 for r in RULES}
    out, passed = [], 0
    for qi, s, ul, uv in zip(np.asarray(q, float), signs, u_lat, u_vert):
        bad = eng.feas.check_command(qi)
        if bad:
            rejected[bad[0]] += 1
            continue
        loads = []
        if uv < p_vertical:
            loads.append((vertical, 0))
        if ul < p_lateral and st.lateral_force > 0:
            loads.append((lateral_wrench(qi[0], s, st.lateral_force), 1))
        if not loads:
            continue
        passed += 1
        try:
            e0 = eng.solver.solve(qi)
        except (np.linalg.LinAlgError, RuntimeError):
            e0 = None
        for w, kind in loads:
            info = None
            if e0 is not None:
                try:
                    info = eng.pose(qi, w, LOAD_KINDS[kind], e0=e0, check=True)
                except (np.linalg.LinAlgError, RuntimeError):
                    pass
            if info is not None and not info.violations:
                out.append((qi, w, kind, info.block))
            else:
                rejected["visibility"] += 1  # equilibrium rules, mostly visibility
    return {"candidates": out, "rejected": rejected, "passed": passed}


def generate_candidates(
    scn: Scenario,
    settings: DesignSettings,
    n: int | None = None,
    processes: int | None = None,
    progress: ProgressSink | None = None,
    batched: bool = True,
    executor: Executor | None = None,
) -> CandidateSet:
    """At least ``n`` (default settings.candidates) feasible candidates, exactly n returned.

    Raw commands are drawn uniformly in the joint ranges (seeded by settings.seed or the
    scenario's) in batches of BATCH and handled in chunks of CANDIDATE_BLOCK: the command rules,
    the equilibria, the remaining rules and the exact information, by
    identify/design/batch_info.BatchInfo.block (``batched=False``: :func:`scalar_block`, one
    candidate at a time, the reference). The chunks are tasks of ``executor``
    (identify/runtime/executor.py; default: this process, on ``processes`` threads, default the CPUs it
    may use; a Dask worker uses ``processes`` threads, default one: one worker per core). Each
    surviving command yields a vertical candidate and, with probability lateral_fraction /
    (1 - lateral_fraction) capped at 1, a lateral one. The first n feasible candidates in the
    order of the draws are kept, so the result is deterministic for a given seed and n, whatever
    the executor, worker and thread count.
    """
    n = settings.candidates if n is None else n
    seed = scn.seed if settings.seed is None else settings.seed
    rng = np.random.default_rng([seed, 4])
    t0 = time.perf_counter()
    executor = executor or InProcess()
    here = executor.choice.kind == IN_PROCESS
    threads = processes or (len(os.sched_getaffinity(0)) if here else 1)
    frac = settings.lateral_fraction
    p_lat = 1.0 if frac >= 0.5 else frac / (1 - frac)
    p_vert = 1.0 if frac <= 0.5 else (1 - frac) / frac
    job = CandidateJob(PortableScenario.from_scenario(scn), settings, p_vert, p_lat, batched, threads)
    eng = _engine(job.scenario, job.settings)
    limits = eng.robot.limits()
    phase0 = dict(_batch(job).seconds) if here and batched else None
    bar = sink(progress)
    bar.start(n, "candidates")
    rejected: dict[str, int] = {r: 0 for r in RULES}
    qs, ws, kinds, blocks = [], [], [], []
    screened = raw = shown = 0

    def chunks():
        while True:
            batch = sample_commands(rng, limits, BATCH)
            signs = np.where(rng.random(len(batch)) < 0.5, -1.0, 1.0)
            u_lat = rng.random(len(batch))
            u_vert = rng.random(len(batch))
            for a in range(0, BATCH, CANDIDATE_BLOCK):
                sl = slice(a, a + CANDIDATE_BLOCK)
                yield job, batch[sl], signs[sl], u_lat[sl], u_vert[sl]

    results = executor.ordered(candidate_block, chunks())
    try:
        for got in results:
            raw += CANDIDATE_BLOCK
            screened += got["passed"]
            for r, k in got["rejected"].items():
                rejected[r] += k
            for q, w, kind, block in got["candidates"]:
                qs.append(q)
                ws.append(w)
                kinds.append(kind)
                blocks.append(block)
            now = min(len(qs), n)
            bar.update(f"candidates {now}/{n}", step=now - shown)
            shown = now
            if len(qs) >= n:
                break
            if hopeless(len(qs), raw, n):
                tally = tally_rules(
                    eng.feas,
                    eng.solver,
                    scn.load_mass,
                    sample_commands(np.random.default_rng([seed, 5]), limits, 256),
                )
                raise InputError(
                    scn.path,
                    "design",
                    "settings that leave feasible configurations",
                    f"only {len(qs)} of {raw} sampled commands feasible, too few for {n} candidates; "
                    f"each rule on {tally.sampled} more: {tally.summary()}",
                )
    finally:
        results.close()  # cancels the chunks drawn ahead
    m = max(b.shape[0] for b in blocks)
    out = np.zeros((n, m, eng.n_params))
    for i, b in enumerate(blocks[:n]):
        out[i, : b.shape[0]] = b
    stats = {
        "raw_commands": raw,
        "passed_command_rules": screened,
        "rejected_first_rule": rejected,
        "seconds": time.perf_counter() - t0,
        "threads": threads,
        "batched": batched,
        "executor": executor.choice.describe(),
    }
    if phase0 is not None:
        stats["phase_seconds"] = {k: round(v - phase0.get(k, 0.0), 4) for k, v in _batch(job).seconds.items()}
    return CandidateSet(
        np.array(qs[:n]),
        np.array(ws[:n]),
        np.array(kinds[:n], int),
        out,
        eng.theta0,
        eng.settings,
        stats,
        eng.robot.layout.names,
    )


# --------------------------------------------------------------------------- the candidate file (NPZ)

NOTE = (
    "blocks[i] = whitened regressor of candidate i (rows: reflector deflections divided by their "
    "noise, 2 tracker readings) w.r.t. theta/theta0 (columns); sum_i blocks[i].T @ blocks[i] over a "
    "plan = its Fisher information; q in degrees; wrench world-frame N, N*m at the payload site"
)
NORMALISED_NOTE = (
    "; NORMALISED: blocks = raw blocks / column_scale (each column's RMS over all rows), "
    "so the mean information has a unit diagonal; every plan's log det shifts by "
    "-2 sum(log(column_scale)): the D-optimal plan is unchanged (A plans are not)"
)


@dataclass(frozen=True)
class CandidateFile:
    """Candidates read from an NPZ: only q and blocks are required."""

    path: Path
    q: np.ndarray  # (N, n) rad
    blocks: np.ndarray  # (N, m, p)
    wrench: np.ndarray | None  # (N, 6) N, N*m
    kind: np.ndarray | None  # (N,) 0 vertical, 1 lateral
    theta0: np.ndarray | None  # (p,)
    column_scale: np.ndarray | None  # (p,) when the blocks were normalised

    def __len__(self) -> int:
        return len(self.q)


def write_candidates(path, q, blocks, wrench, kind, theta0, param_names, normalise: bool = False) -> None:
    """The NPZ of the module docstring (q in rad here, degrees in the file)."""
    extra = {}
    note = NOTE
    if normalise:
        blocks, s = normalise_blocks(blocks)
        extra["column_scale"] = s
        note += NORMALISED_NOTE
    np.savez_compressed(
        path,
        q=np.degrees(q),
        blocks=blocks,
        wrench=wrench,
        load_kind=np.array([LOAD_KINDS[k] for k in kind]),
        theta0=theta0,
        param_names=np.array(param_names),
        note=np.array(note),
        **extra,
    )


def _array(z, path, name, expected, required=True):
    if name not in z.files:
        if required:
            raise InputError(
                path,
                name,
                f"an array {name!r}: {expected}",
                "missing; arrays present: " + (", ".join(z.files) or "none"),
            )
        return None
    try:
        a = z[name]
    except ValueError as exc:  # object arrays (allow_pickle=False)
        raise InputError(path, name, expected, str(exc)) from None
    return a


def _finite(path, name, a, expected):
    if a.dtype.kind not in "iuf":
        raise InputError(path, name, expected, f"dtype {a.dtype}")
    a = a.astype(float)
    bad = ~np.isfinite(a)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise InputError(path, name, expected, f"NaN or inf (first at row {row})")
    return a


def read_candidates(path: str | Path) -> CandidateFile:
    """Read and validate a candidate NPZ (see the module docstring)."""
    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(
            path, "(file)", "a readable NPZ archive with arrays q and blocks", str(exc)
        ) from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise InputError(
            path, "(file)", "an NPZ archive (numpy.savez) with arrays q and blocks", "a single array"
        )
    with z:
        q_exp = "N x n finite joint angles in degrees (one per actuated joint)"
        b_exp = "N x m x p finite numbers, N as in q"
        q = _finite(path, "q", _array(z, path, "q", q_exp), q_exp)
        if q.ndim != 2 or min(q.shape) < 1:
            raise InputError(path, "q", q_exp, f"shape {q.shape}")
        n = q.shape[0]
        blocks = _finite(path, "blocks", _array(z, path, "blocks", b_exp), b_exp)
        if blocks.ndim != 3 or blocks.shape[0] != n or min(blocks.shape) < 1:
            raise InputError(
                path, "blocks", b_exp.replace("N as in q", f"N = {n} as in q"), f"shape {blocks.shape}"
            )
        p = blocks.shape[2]
        w_exp = f"{n} x 6 finite forces and moments (N, N*m)"
        wrench = _array(z, path, "wrench", w_exp, required=False)
        if wrench is not None:
            wrench = _finite(path, "wrench", wrench, w_exp)
            if wrench.shape != (n, 6):
                raise InputError(path, "wrench", w_exp, f"shape {wrench.shape}")
        k_exp = f"{n} strings, each one of " + ", ".join(LOAD_KINDS)
        kinds = _array(z, path, "load_kind", k_exp, required=False)
        kind = None
        if kinds is not None:
            if kinds.shape != (n,) or kinds.dtype.kind != "U" or not np.isin(kinds, LOAD_KINDS).all():
                raise InputError(path, "load_kind", k_exp, f"shape {kinds.shape}, dtype {kinds.dtype}")
            kind = (kinds == "lateral").astype(int)
        optional = {}
        for name in ("theta0", "column_scale"):
            exp = f"{p} finite positive numbers (one per column of blocks)"
            a = _array(z, path, name, exp, required=False)
            if a is not None:
                a = _finite(path, name, a, exp)
                if a.shape != (p,) or not np.all(a > 0):
                    raise InputError(
                        path, name, exp, f"shape {a.shape}" if a.shape != (p,) else "a value <= 0"
                    )
            optional[name] = a
    return CandidateFile(
        path, np.radians(q), blocks, wrench, kind, optional["theta0"], optional["column_scale"]
    )


__all__ = [
    "CandidateSet",
    "generate_candidates",
    "sample_commands",
    "CandidateJob",
    "candidate_block",
    "scalar_block",
    "CANDIDATE_BLOCK",
    "BATCH",
    "SECONDS_PER_CANDIDATE",
    "CandidateFile",
    "NOTE",
    "read_candidates",
    "write_candidates",
]
