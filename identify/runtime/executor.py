"""Where the independent pieces of `montecarlo`, `design` and `study` run: one interface, three places.

* **in-process**: the pieces run one after the other in this process (no start-up cost);
* **local cluster**: a Dask ``distributed.LocalCluster`` of one single-threaded worker process
  per CPU, bound to 127.0.0.1 only (nothing listens on another interface; no dashboard, the
  scheduler's HTTP routes on a free port);
* **cluster**: the user's Dask scheduler (``--scheduler tcp://HOST:PORT`` or ``tls://…``,
  else the standard ``DASK_SCHEDULER_ADDRESS`` / dask config ``scheduler-address``).

The SAME task functions run in all three (module-level functions of the installed package;
their arguments carry texts, never paths into a checkout: identify/runtime/portable.py), and every
task is a pure function of its arguments, so the results do not depend on where they ran,
on the worker count or on the order of completion (tests/test_cluster.py checks this bit for
bit). No pool or scheduler of our own: Dask's ``Client.submit`` and ``as_completed``.

Choice without an address: a local cluster pays a start-up and shut-down cost once (about
4 s + 1 s here, ``LOCAL_STARTUP_S``/``LOCAL_SHUTDOWN_S``, measured in a fresh process by
benchmarks/scaling_bench.py) and ~5 ms of scheduling per task (``TASK_OVERHEAD_S``); with W
workers it wins when the in-process work T satisfies T > (startup + shutdown) * W / (W - 1) +
tasks * overhead, the break-even of :func:`break_even_seconds` (~10 s for 2 workers). Callers pass an
estimate of T (their own measured per-piece cost times the number of pieces); the choice and
its reason are returned so the command line can say which executor it used.

Security: Dask's wire protocol carries pickled code, so whoever reaches a scheduler runs code
on its workers. The local cluster binds to 127.0.0.1; ``tls://`` addresses use Dask's own
security configuration (``distributed.comm.tls.ca-file``, ``.client.cert``, ``.client.key``;
docs/studies.md has a self-signed recipe). Never expose a plain ``tcp://`` scheduler beyond a
trusted network.

One BLAS thread per piece, everywhere (:func:`single_threaded`): each worker is a single-threaded
process with a core of its own, and the pieces' dense algebra is small; OpenBLAS's default of
one thread per CPU in EVERY worker oversubscribed the cores (2 workers x 2 BLAS threads on 2
cores: each piece ran 1.7x slower, efficiency 0.59 on 2 workers; pinned: 0.89,
benchmarks/scaling_bench.py side by side). In-process pieces run pinned too, so the numbers
stay bit-identical whichever executor ran them.

Ctrl-C (KeyboardInterrupt) while results are awaited cancels every task not yet finished
(``Client.cancel``) before it propagates; what finished has already been handed to the caller,
who keeps it (:class:`Interrupted` carries a partial result up to the command line).

Faults (tests/test_cluster_faults.py): a worker that dies mid-task (SIGKILL, out of memory) is
Dask's to handle: the scheduler gives its tasks to the other workers, and since tasks are pure
the numbers do not change. Shared inputs are therefore the results of tasks of their own, not
scattered data, so that the scheduler can make them again when the worker holding them dies. A scheduler that is lost,
or a task that killed several workers, ends the run with :class:`ClusterLost`: one line, the
results already handed over are kept (a study resumes from its journal).
"""

from __future__ import annotations

import itertools
import logging
import os
import sys
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from calbench.bench.core import CalbenchError, InputError

IN_PROCESS = "in-process"
LOCAL = "local cluster"
REMOTE = "cluster"
SCHEMES = ("tcp://", "tls://")
KEYWORDS = ("local", "in-process")

# measured on the 2-core machine (benchmarks/scaling_bench.py: "local_cluster", fresh process)
LOCAL_STARTUP_S = 4.0  # import distributed, LocalCluster + Client, first task importing calbench
LOCAL_SHUTDOWN_S = 1.0  # Client.close + LocalCluster.close (nannies stop their workers)
TASK_OVERHEAD_S = 5e-3  # scheduling per task and worker (1000 trivial tasks on 2 workers)
LOCAL_EFFICIENCY = 0.89  # parallel efficiency of 2 pinned workers (benchmarks/scaling_bench.py)
CONNECT_TIMEOUT_S = 10.0  # how long to keep trying a --scheduler address


class ClusterLost(CalbenchError):
    """The Dask cluster can no longer run the work: the scheduler is gone, or a task's workers
    kept dying (Dask's KilledWorker). The pieces already returned are the caller's to keep."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C after some pieces finished: ``partial`` is the caller's result of those pieces."""

    def __init__(self, partial: Any, done: int, total: int):
        super().__init__(f"interrupted after {done} of {total}")
        self.partial, self.done, self.total = partial, done, total


@dataclass(frozen=True)
class ExecutorChoice:
    """Which executor, where, how many workers, and why (for the user)."""

    kind: str  # IN_PROCESS, LOCAL or REMOTE
    address: str | None  # the scheduler's address (REMOTE)
    workers: int  # worker processes (LOCAL; 1 in-process; REMOTE: known once open)
    reason: str

    def expected_seconds(self, work_seconds: float, tasks: int = 1, setup_seconds: float = 0.0) -> float:
        """Wall-clock time of ``work_seconds`` of in-process work in ``tasks`` pieces here: in
        this process the work itself (its set-up already built: the caller measured it); on a
        local cluster its start and stop, each worker's set-up (``setup_seconds``, in parallel)
        and the work shared by its workers at LOCAL_EFFICIENCY, no more workers than the cores
        the machine's other work leaves (at load 5 on 2 cores one core's worth: 1000 iterated
        runs announced 3.75 min on two workers took 6.8); on another cluster the same without
        the start and stop (not ours)."""
        if self.kind == IN_PROCESS:
            return work_seconds
        w = max(self.workers, 1)
        if self.kind == LOCAL:  # the cores other work leaves us (the work was timed under it)
            w = min(w, max(1.0, machine_workers() - other_load()))
        share = work_seconds / (w * LOCAL_EFFICIENCY) + tasks * TASK_OVERHEAD_S / w + setup_seconds
        return share + (LOCAL_STARTUP_S + LOCAL_SHUTDOWN_S if self.kind == LOCAL else 0.0)

    def describe(self) -> str:
        procs = f"{self.workers} worker process" + ("es" if self.workers != 1 else "")
        where = {
            IN_PROCESS: "in this process",
            LOCAL: f"on a local Dask cluster of {procs} (127.0.0.1)",
            REMOTE: f"on the Dask cluster at {self.address}",
        }[self.kind]
        return f"running {where}: {self.reason}"


def machine_workers() -> int:
    """The CPUs this process may use: the size of a local cluster."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def other_load() -> float:
    """Runnable processes besides this one (the 1-minute load average minus 1; 0 unknown)."""
    try:
        return max(0.0, os.getloadavg()[0] - 1.0)
    except (AttributeError, OSError):  # pragma: no cover - not Unix
        return 0.0


def break_even_seconds(workers: int, tasks: int = 0) -> float:
    """In-process work (s) above which a local cluster of ``workers`` processes finishes first."""
    if workers < 2:
        return float("inf")
    return (LOCAL_STARTUP_S + LOCAL_SHUTDOWN_S) * workers / (workers - 1) + tasks * TASK_OVERHEAD_S


def configured_address() -> str | None:
    """``DASK_SCHEDULER_ADDRESS`` or the dask config's ``scheduler-address`` (None when unset)."""
    import dask

    addr = dask.config.get("scheduler-address", None)
    return str(addr) if addr else None


def choose(
    scheduler: str | None, work_seconds: float, tasks: int = 0, workers: int | None = None
) -> ExecutorChoice:
    """The executor for a job of about ``work_seconds`` of in-process work in ``tasks`` pieces.

    ``scheduler``: an address (tcp://, tls://), "local" (force a local cluster), "in-process",
    or None (the configured address, else the measured break-even decides). ``workers``: size
    of a local cluster (default: the machine's CPUs; 1 means in-process).
    """
    if scheduler is None:
        addr = configured_address()
        if addr:
            scheduler = addr
            origin = "DASK_SCHEDULER_ADDRESS / dask config scheduler-address"
        else:
            origin = None
    else:
        origin = "--scheduler"
    n = machine_workers() if workers is None else int(workers)
    if n < 1:
        raise InputError("--workers", "workers", "an integer >= 1", workers)
    if scheduler == "in-process":
        return ExecutorChoice(IN_PROCESS, None, 1, "--scheduler in-process")
    if scheduler == "local":
        return ExecutorChoice(LOCAL, None, n, "--scheduler local")
    if scheduler is not None:
        if not scheduler.startswith(SCHEMES) or len(scheduler) <= 6:
            raise InputError(
                origin, "scheduler", "tcp://HOST:PORT, tls://HOST:PORT, local or in-process", scheduler
            )
        return ExecutorChoice(REMOTE, scheduler, 0, f"scheduler from {origin}")
    tasks = max(int(tasks), 1)
    if n < 2 or tasks < 2:
        why = "one worker asked for" if n < 2 else "a single piece of work"
        return ExecutorChoice(IN_PROCESS, None, 1, why)
    be = break_even_seconds(n, tasks)
    if work_seconds <= be:
        return ExecutorChoice(
            IN_PROCESS,
            None,
            1,
            f"about {work_seconds:.1f} s of work, below the "
            f"{be:.0f} s a local cluster of {n} needs to pay off",
        )
    return ExecutorChoice(
        LOCAL,
        None,
        n,
        f"about {work_seconds:.0f} s of work in {tasks} pieces, above the {be:.0f} s break-even",
    )


# --------------------------------------------------------------------------- executors


class Executor:
    """Runs ``fn(*args)`` for many argument tuples; subclasses say where."""

    choice: ExecutorChoice

    @property
    def workers(self) -> int:
        return self.choice.workers

    def run(self, fn: Callable, arglist: Sequence[tuple], shared: tuple = ()) -> Iterator[tuple[int, Any]]:
        """(index, result) of ``fn(*shared, *args)`` for every args of ``arglist``, as each finishes
        (any order). ``shared``: large arguments common to every call, sent to a cluster once."""
        raise NotImplementedError

    def worker_counts(self) -> dict[str, int]:
        """Pieces finished per worker so far (a cluster's; empty in this process)."""
        return {}

    def progress_label(self, text: str) -> str:
        """``text``, with the per-worker counts of a cluster after `` | `` (bench.core.Progress
        shows them)."""
        counts = self.worker_counts()
        if len(counts) < 2:
            return text
        return f"{text} | pieces per worker: " + ", ".join(f"{w} {n}" for w, n in sorted(counts.items()))

    def ordered(self, fn: Callable, args: Iterable[tuple], window: int | None = None) -> Iterator[Any]:
        """Results in the order of ``args``, at most ``window`` calls in flight; ``args`` is drawn
        lazily, so a consumer that stops early (closing the iterator) costs no more pieces."""
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def single_threaded(fn: Callable, *args: Any) -> Any:
    """Run one piece with at most one BLAS thread (see the module docstring)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return fn(*args)


class InProcess(Executor):
    """The pieces in this process, in order."""

    def __init__(self, choice: ExecutorChoice | None = None):
        self.choice = choice or ExecutorChoice(IN_PROCESS, None, 1, "in-process")

    def run(self, fn, arglist, shared=()):
        for i, a in enumerate(arglist):
            yield i, single_threaded(fn, *shared, *a)

    def ordered(self, fn, args, window=None):
        for a in args:
            yield single_threaded(fn, *a)


def _calbench_version() -> str | None:
    """Runs on each worker: the calbench version installed there."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("calbench")
    except PackageNotFoundError:
        return None


def _builds() -> dict[str, str]:
    """Runs on each worker: the installed builds whose arithmetic the results depend on, bit
    for bit (the distributions' versions, as pip installed them)."""
    from importlib.metadata import PackageNotFoundError, version

    found = {}
    for lib, dists in (("MuJoCo", ("mujoco-core", "mujoco")), ("NumPy", ("numpy",))):
        for d in dists:
            try:
                found[lib] = version(d)
                break
            except PackageNotFoundError:
                continue
    return found


class DaskExecutor(Executor):
    """The pieces as Dask tasks (a local cluster we own, or the user's scheduler)."""

    def __init__(self, choice: ExecutorChoice, connect_timeout: float | None = None):
        from distributed import Client, LocalCluster, Security

        self.cluster = None
        self._names: dict[str, str] = {}  # worker address -> w1, w2, ... (first finished first)
        self._counts: dict[str, int] = {}
        if choice.kind == LOCAL:
            # dashboard_address=None turns the dashboard off, yet the scheduler still serves its
            # HTTP routes (health, metrics) on Dask's default port 8787: pinned to a free port on
            # 127.0.0.1 here, so a second cluster (another calbench run) does not warn that 8787
            # is taken
            self.cluster = LocalCluster(
                n_workers=choice.workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                scheduler_port=0,
                dashboard_address=None,
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                silence_logs=logging.ERROR,
            )
            self.client = Client(self.cluster)
        else:
            sec = Security()
            if choice.address.startswith("tls://") and not (sec.tls_ca_file and sec.tls_client_cert):
                raise InputError(
                    "--scheduler",
                    "scheduler",
                    "Dask's security configuration for a tls:// "
                    "address (distributed.comm.tls.ca-file, .client.cert, .client.key; e.g. "
                    "DASK_DISTRIBUTED__COMM__TLS__CA_FILE; see docs/studies.md)",
                    choice.address,
                )
            try:
                self.client = Client(
                    choice.address, timeout=connect_timeout or CONNECT_TIMEOUT_S, security=sec
                )
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(
                    "--scheduler", "scheduler", "a reachable Dask scheduler", f"{choice.address}: {exc}"
                ) from None
            self._check_workers()
            self._quiet()
            n = len(self.client.scheduler_info().get("workers", {}))
            choice = ExecutorChoice(REMOTE, choice.address, n, choice.reason)
        self.choice = choice

    def _quiet(self) -> None:
        """Dask's client logs its own tracebacks when the scheduler goes away (reconnect
        attempts); calbench says it in one line (ClusterLost). Kept with -v."""
        if logging.getLogger("calbench").isEnabledFor(logging.INFO):
            return
        names = ["distributed", *(n for n in logging.root.manager.loggerDict if n.startswith("distributed."))]
        self._log_levels = {n: logging.getLogger(n).level for n in names}
        for n in names:  # Dask's config gives some (distributed.client) levels of their own
            logging.getLogger(n).setLevel(logging.CRITICAL)

    def _check_workers(self) -> None:
        """Every worker must have this calbench version installed (tasks are its functions)."""
        mine = _calbench_version()
        for addr, theirs in self.client.run(_calbench_version).items():
            if theirs != mine:
                self.close()
                raise InputError(
                    "--scheduler",
                    "workers",
                    f"calbench {mine} installed on every worker (pip install calbench there)",
                    f"{addr}: {theirs or 'not installed'}",
                )
        mine_b = _builds()
        for addr, theirs_b in self.client.run(_builds).items():
            for lib, v in theirs_b.items():
                if v != mine_b.get(lib):  # named, not refused: the numbers agree to rounding, not bit for bit
                    print(
                        f"calbench: warning: Dask worker {addr} has {lib} {v}, this machine {mine_b[lib]}: "
                        "its results may differ from a local run in the last bits",
                        file=sys.stderr,
                    )

    def _submit(self, fn, args, tag: str, i: int):
        return self.client.submit(
            single_threaded, fn, *args, key=f"calbench-{fn.__name__}-{tag}-{i}", retries=0
        )

    def _count(self, fut) -> None:
        """Count a finished piece for the worker that holds its result (the one that ran it)."""
        try:
            where = self.client.who_has(fut).get(fut.key, ())
        except Exception:  # noqa: BLE001 - a count for the progress line only
            return
        for w in where[:1]:
            name = self._names.setdefault(w, f"w{len(self._names) + 1}")
            self._counts[name] = self._counts.get(name, 0) + 1

    def worker_counts(self) -> dict[str, int]:
        return dict(self._counts)

    def _cancel(self, futures) -> None:
        pending = [f for f in futures if not f.done()]
        if pending:
            try:
                self.client.cancel(pending)
            except Exception:  # noqa: BLE001  the scheduler is gone: nothing is left to cancel
                pass

    def _result(self, fut):
        """``fut.result()``, with the cluster's own failures said in one line (ClusterLost);
        an exception raised by the task itself (a bug, a bad input) passes through as it is."""
        from distributed import KilledWorker

        try:
            return fut.result()
        except KilledWorker as exc:
            raise ClusterLost(f"a task kept killing the Dask workers it ran on ({exc})") from None
        except Exception as exc:
            if self.client is not None and self.client.status == "running" and not _is_comm(exc):
                raise
            where = self.choice.address or "the local cluster"
            why = str(exc).split(" cancelled for reason: ")[-1][:120] if str(exc) else ""
            raise ClusterLost(
                f"lost the Dask scheduler at {where} ({type(exc).__name__}{': ' + why if why else ''})"
            ) from None

    def run(self, fn, arglist, shared=()):
        from distributed import as_completed

        tag = uuid.uuid4().hex[:12]
        # each as one object, made by a task of its own rather than scattered: a worker that dies
        # takes its copy with it, and the scheduler makes it again elsewhere (scattered data it
        # could not, and the tasks needing it were cancelled)
        held = [
            self.client.submit(_shared, x, key=f"calbench-shared-{tag}-{k}", pure=False)
            for k, x in enumerate(shared)
        ]
        futures = [self._submit(fn, (*held, *a), tag, i) for i, a in enumerate(arglist)]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                res = self._result(fut)
                self._count(fut)
                fut.release()
                yield index[fut.key], res
        finally:  # done, failed, interrupted or abandoned: nothing left running
            self._cancel(futures)
            self._cancel(held)

    def ordered(self, fn, args, window=None):
        window = window or 2 * max(self.workers, 1)
        tag = uuid.uuid4().hex[:12]
        it = iter(args)
        counter = itertools.count()
        inflight: deque = deque()
        try:
            for a in itertools.islice(it, window):
                inflight.append(self._submit(fn, a, tag, next(counter)))
            while inflight:
                fut = inflight.popleft()
                res = self._result(fut)
                fut.release()
                for a in itertools.islice(it, 1):
                    inflight.append(self._submit(fn, a, tag, next(counter)))
                yield res
        finally:
            self._cancel(list(inflight))

    def close(self) -> None:
        client, cluster = getattr(self, "client", None), getattr(self, "cluster", None)
        self.client = self.cluster = None
        if client is not None:
            try:
                client.close()
            except Exception:  # noqa: BLE001  a lost scheduler: there is nothing left to close
                pass
        for n, level in getattr(self, "_log_levels", {}).items():
            logging.getLogger(n).setLevel(level)
        if cluster is not None:
            cluster.close()


def _shared(x):
    """A shared input as a task's result (see :meth:`DaskExecutor.run`)."""
    return x


def _is_comm(exc: BaseException) -> bool:
    """A failure of the connection to the scheduler rather than of the task."""
    import asyncio

    from distributed.client import FutureCancelledError
    from distributed.comm.core import CommClosedError

    return isinstance(
        exc, (CommClosedError, FutureCancelledError, asyncio.CancelledError, OSError, TimeoutError)
    )


def open_executor(choice: ExecutorChoice) -> Executor:
    """The executor the choice names (a Dask client connected, or a local cluster started)."""
    return InProcess(choice) if choice.kind == IN_PROCESS else DaskExecutor(choice)


__all__ = [
    "ExecutorChoice",
    "Executor",
    "InProcess",
    "DaskExecutor",
    "Interrupted",
    "ClusterLost",
    "choose",
    "open_executor",
    "break_even_seconds",
    "machine_workers",
    "configured_address",
    "IN_PROCESS",
    "LOCAL",
    "REMOTE",
]
