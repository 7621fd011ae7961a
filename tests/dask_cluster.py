"""A real Dask cluster on localhost for the tests: a scheduler and worker PROCESSES started with
the `dask` command line (as docs/studies.md tells users to), and the self-signed certificates of
the docs' TLS recipe. Each worker runs in its own process (--no-nanny), one thread, bound to
127.0.0.1, with its working folder outside the checkout."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

DASK = str(Path(sys.executable).with_name("dask"))


def self_signed(folder: Path) -> dict[str, Path]:
    """docs/studies.md's recipe: a private CA and one certificate it signs (openssl)."""
    folder.mkdir(parents=True, exist_ok=True)
    ext = folder / "san.cnf"
    ext.write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    steps = [
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-days",
            "2",
            "-subj",
            "/CN=calbench-ca",
            "-keyout",
            "ca.key",
            "-out",
            "ca.pem",
        ],
        [
            "openssl",
            "req",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-subj",
            "/CN=calbench-node",
            "-keyout",
            "node.key",
            "-out",
            "node.csr",
        ],
        [
            "openssl",
            "x509",
            "-req",
            "-in",
            "node.csr",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-days",
            "2",
            "-out",
            "node.pem",
            "-extfile",
            "san.cnf",
        ],
    ]
    for cmd in steps:
        subprocess.run(cmd, cwd=folder, check=True, capture_output=True)
    return {"ca": folder / "ca.pem", "cert": folder / "node.pem", "key": folder / "node.key"}


def tls_env(certs: dict[str, Path]) -> dict[str, str]:
    """Dask's own security configuration of a client, as environment variables."""
    return {
        "DASK_DISTRIBUTED__COMM__TLS__CA_FILE": str(certs["ca"]),
        "DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT": str(certs["cert"]),
        "DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY": str(certs["key"]),
    }


class LocalDaskCluster:
    """`dask scheduler` + n `dask worker` processes; ``address``; ``stop()`` ends them all."""

    def __init__(
        self, folder: Path, workers: int = 2, certs: dict[str, Path] | None = None, timeout: float = 60.0
    ):
        folder.mkdir(parents=True, exist_ok=True)
        self.folder = folder
        self.procs: list[subprocess.Popen] = []
        sched_file = folder / "scheduler.json"
        tls = (
            []
            if certs is None
            else [
                "--tls-ca-file",
                str(certs["ca"]),
                "--tls-cert",
                str(certs["cert"]),
                "--tls-key",
                str(certs["key"]),
            ]
        )
        proto = ["--protocol", "tls"] if certs else []
        env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
        self._start(
            [
                DASK,
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(sched_file),
                *proto,
                *tls,
            ],
            env,
            "scheduler",
        )
        t0 = time.monotonic()
        while not sched_file.exists() or not sched_file.read_text().strip():
            if time.monotonic() - t0 > timeout or self.procs[0].poll() is not None:
                self.stop()
                raise RuntimeError(
                    f"the Dask scheduler did not start: {(folder / 'scheduler.log').read_text()}"
                )
            time.sleep(0.1)
        time.sleep(0.2)
        self.address = json.loads(sched_file.read_text())["address"]
        for i in range(workers):
            self._start(
                [
                    DASK,
                    "worker",
                    self.address,
                    "--nthreads",
                    "1",
                    "--no-nanny",
                    "--no-dashboard",
                    "--host",
                    "127.0.0.1",
                    "--name",
                    f"w{i}",
                    *tls,
                ],
                env,
                f"worker{i}",
            )
        self.worker_pids = [p.pid for p in self.procs[1:]]

    def _start(self, cmd, env, name) -> None:
        log = open(self.folder / f"{name}.log", "w")
        self.procs.append(
            subprocess.Popen(cmd, cwd=self.folder, env=env, stdout=log, stderr=subprocess.STDOUT)
        )

    def wait_for_workers(self, client, n: int, timeout: float = 60.0) -> None:
        client.wait_for_workers(n, timeout=timeout)

    def stop(self) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def strip_timing(x, keys):
    """A JSON report without the keys (``keys``) that depend on the clock or on where it ran."""
    if isinstance(x, dict):
        return {k: strip_timing(v, keys) for k, v in x.items() if k not in keys}
    if isinstance(x, list):
        return [strip_timing(v, keys) for v in x]
    return x


def same_table(a: Path, b: Path, timing_columns) -> None:
    """Two study Parquet files hold the same rows, bit for bit, but for their timing columns."""
    import pyarrow.parquet as pq

    ta, tb = pq.read_table(a), pq.read_table(b)
    assert ta.schema == tb.schema and ta.num_rows == tb.num_rows
    for name in ta.column_names:
        if name in timing_columns:
            continue
        x, y = ta.column(name).to_pylist(), tb.column(name).to_pylist()
        assert [v if v == v else "nan" for v in x] == [v if v == v else "nan" for v in y], name


def reference_study(folder: Path, text: str, paper: Path) -> tuple[Path, Path]:
    """A study (``text``, its ``{paper}`` the paper scenario's path) written in ``folder`` and run
    in one go in this process: (the study TOML, its Parquet results), what a run on a cluster,
    interrupted or with a worker lost, must reproduce (:func:`same_table`)."""
    from calbench.identify.cli import main

    study = folder / "study.toml"
    study.write_text(text.format(paper=paper.as_posix()))
    ref = folder / "reference.parquet"
    assert main(["study", str(study), "--out", str(ref), "--scheduler", "in-process"]) == 0
    return study, ref
