"""A ``dask scheduler`` and ``dask worker`` processes on the loopback interface, started with the ``dask`` command
line as an operator would start them: the external cluster of ``rsrivc_fleet --scheduler ADDR`` for the fleet
benchmark (``scripts/bench_fleet_scale.py``) and tests.

Every process is started by this object and stopped by it, by process id (the scheduler and each worker's nanny
in their own process group, so that a worker process a nanny started goes with it).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

#: cli/fleet.py ``WORKER_CONFIG`` as a dask config file (what an operator puts into ``~/.config/dask/``)
WORKER_CONFIG_YAML = """\
distributed:
  nanny:
    pre-spawn-environ:
      MALLOC_TRIM_THRESHOLD_: null
  worker:
    profile:
      enabled: false
"""


def _dask_command() -> list[str]:
    """The ``dask`` command of this interpreter's environment."""
    exe = Path(sys.executable).with_name("dask")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("dask")
    if found:
        return [found]
    return [sys.executable, "-m", "distributed.cli.dask_spec"]   # pragma: no cover - dask installed without scripts


class LoopbackCluster:
    """``with LoopbackCluster(workers=2) as c: rsrivc_fleet ... --scheduler c.address`` (single-threaded workers,
    each under its own nanny, no dashboards, 127.0.0.1 only)."""

    def __init__(self, workers: int = 2, *, env: dict[str, str] | None = None, timeout_s: float = 60.0) -> None:
        self.n_workers = workers
        self.timeout_s = timeout_s
        self._tmp = Path(tempfile.mkdtemp(prefix="rsrivc_dask_"))
        # the workers' settings as rsrivc_fleet's own LocalCluster has them (cli/fleet.py WORKER_CONFIG), in a dask
        # config file (an environment variable cannot unset dask's MALLOC_TRIM_THRESHOLD_: it lower-cases the key)
        (self._tmp / "rsrivc_fleet.yaml").write_text(WORKER_CONFIG_YAML, encoding="utf-8")
        inherited = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}   # a nanny's leftover
        self.env = {**inherited, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                    "DASK_CONFIG": str(self._tmp), **(env or {})}
        self.scheduler_file = self._tmp / "scheduler.json"
        self.procs: list[subprocess.Popen[bytes]] = []
        self.address = ""

    def _spawn(self, args: list[str], log: str) -> subprocess.Popen[bytes]:
        with (self._tmp / log).open("wb") as fh:
            proc = subprocess.Popen([*_dask_command(), *args], stdout=fh, stderr=subprocess.STDOUT, env=self.env,
                                    cwd=self._tmp, start_new_session=True)
        self.procs.append(proc)
        return proc

    def start(self) -> LoopbackCluster:
        """Start the scheduler, then the workers; return when every worker has registered (on failure: every
        process stopped, RuntimeError)."""
        try:
            return self._start()
        except BaseException:
            self.stop()
            raise

    def _start(self) -> LoopbackCluster:
        self._spawn(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file",
                     str(self.scheduler_file)], "scheduler.log")
        self._wait(lambda: self.scheduler_file.is_file() and self.scheduler_file.stat().st_size > 0, "the scheduler")
        self.address = json.loads(self.scheduler_file.read_text())["address"]
        for i in range(self.n_workers):
            self.add_worker(f"worker{i}.log")
        self._wait(lambda: len(self.worker_pids()) >= self.n_workers, f"{self.n_workers} worker(s)")
        return self

    def add_worker(self, log: str = "worker.log") -> None:
        """One more single-threaded worker (under a nanny) on the loopback interface."""
        self._spawn(["worker", "--scheduler-file", str(self.scheduler_file), "--nthreads", "1", "--nworkers", "1",
                     "--host", "127.0.0.1", "--no-dashboard", "--local-directory", str(self._tmp)], log)

    def _wait(self, ready: Any, what: str) -> None:
        t_end = time.monotonic() + self.timeout_s
        while not ready():
            if time.monotonic() > t_end or any(p.poll() is not None for p in self.procs):
                raise RuntimeError(f"dask loopback cluster: {what} did not start ({self._last_log_line()})")
            time.sleep(0.1)

    def _last_log_line(self) -> str:
        lines = [ln for p in sorted(self._tmp.glob("*.log")) for ln in p.read_text(errors="replace").splitlines()
                 if ln.strip()]
        return lines[-1].strip() if lines else "no output"

    def worker_pids(self) -> dict[str, int]:
        """``{worker address: worker process id}`` of the registered workers (through a short-lived client)."""
        from dask.distributed import Client

        try:
            with Client(self.address, timeout="10s") as client:
                return {a: int(p) for a, p in client.run(os.getpid).items()}
        except (OSError, TimeoutError):
            return {}

    def stop(self) -> None:
        """Stop every process this object started (SIGTERM to its process group, then SIGKILL)."""
        for proc in reversed(self.procs):
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        t_end = time.monotonic() + 10.0
        for proc in self.procs:
            try:
                proc.wait(max(0.1, t_end - time.monotonic()))
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait()
        self.procs.clear()
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> LoopbackCluster:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
