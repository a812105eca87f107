"""Shared helpers for the service tests: a real ``scanmill serve`` process on 127.0.0.1, sample scans.

:class:`ServerProcess` starts the service as a user would (``python -m scanmill.cli serve``) on a
free loopback port with its own data directory and ``SCANMILL_*`` settings, waits until
``/healthz`` answers, and can stop it gently (SIGTERM) or brutally (SIGKILL, for restart tests).
Every wait here is a loop bounded in count; nothing asserts on elapsed time.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np

from planning.inputs.samples import half_sphere
from planning.report.files import write_ply

ROOT = Path(__file__).resolve().parents[1]
KEY_A = "key-alpha-0123456789"
KEY_B = "key-bravo-9876543210"

#: The paper's half sphere (Makki 2010 §3.2) with the normals from the file: a whole plan in ~1 s.
HALF_SPHERE_PARAMS = {
    "normals": {"method": "input"},
    "tool": {"diameter_mm": 10},
    "visibility": {"cone_deg": [10, 80]},
    "setups": {"coverage": 0.95, "max_setups": 2},
    # coarse paths keep the service tests quick while exercising roughing, finishing and the posts
    "paths": {"finishing": {"scallop_mm": 0.2}, "roughing": {"step_down_mm": 5}},
}

#: The half sphere planned without paths and verification: for the tests of the jobs API itself (listing,
#: idempotency), where what the plan holds does not matter and a job should not take a full plan's time.
NO_PATHS_PARAMS = dict(HALF_SPHERE_PARAMS, paths={"roughing": {"enabled": False}, "finishing": {"enabled": False}},
                       simulate={"enabled": False})


def write_half_sphere(path: Path) -> Path:
    """Write the 2537-point half sphere with exact normals as binary PLY; return the path."""
    s = half_sphere()
    path.parent.mkdir(parents=True, exist_ok=True)
    write_ply(path, s.points, normals=s.normals, binary=True)
    return path


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _ScanmillProcess:
    """A ``scanmill`` command in a subprocess of its own session, configured by ``SCANMILL_*`` variables."""

    settings: dict
    proc: subprocess.Popen | None = None

    def env(self) -> dict[str, str]:
        """This environment without its SCANMILL_* variables, plus ``settings`` as SCANMILL_* variables."""
        env = {k: v for k, v in os.environ.items() if not k.startswith("SCANMILL_")}
        env["PYTHONUNBUFFERED"] = "1"
        for k, v in self.settings.items():
            env["SCANMILL_" + k.upper()] = ",".join(v) if isinstance(v, (list, tuple)) else str(v)
        return env

    def kill9(self) -> None:
        """SIGKILL the main process only, as ``kill -9 PID`` (a crash) would; its children die with it."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(60)

    def stop(self) -> None:
        """SIGTERM (a clean stop), then SIGKILL of the whole session if it does not end."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(30)

    def __exit__(self, *exc) -> None:
        self.stop()                                # a no-op after kill9()


class ServerProcess(_ScanmillProcess):
    """``scanmill serve`` in a subprocess on 127.0.0.1 (a new free port for each start)."""

    def __init__(self, data_dir: Path, log_dir: Path | None = None, **settings):
        self.data_dir = Path(data_dir)
        self.log_dir = Path(log_dir or data_dir.parent)
        self.settings = settings
        self.proc: subprocess.Popen | None = None
        self.port: int | None = None
        self.starts = 0

    def __enter__(self) -> "ServerProcess":
        return self.start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"


    def start(self, max_polls: int = 600) -> "ServerProcess":
        """Start the server and wait (at most ``max_polls`` x 0.1 s) until /healthz answers 200."""
        for _ in range(3):                         # a port taken between choosing and binding: try another
            self.port = free_port()
            self.starts += 1
            log = open(self.log_dir / f"server-{self.starts}.log", "wb")
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "scanmill.cli", "serve", "--host", "127.0.0.1", "--port", str(self.port),
                 "--data-dir", str(self.data_dir), "--log-level", str(self.settings.get("log_level", "info"))],
                cwd=ROOT, env=self.env(), stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            log.close()
            for _ in range(max_polls):
                if self.proc.poll() is not None:
                    break
                try:
                    if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                        return self
                except httpx.TransportError:
                    pass
                time.sleep(0.1)
            self.stop()
        raise RuntimeError(f"the server did not start; see {self.log_dir}/server-{self.starts}.log:\n"
                           + self.log_text()[-3000:])

    def log_text(self) -> str:
        p = self.log_dir / f"server-{self.starts}.log"
        return p.read_text(errors="replace") if p.exists() else ""


    def client(self, key: str | None = None, **kw) -> httpx.Client:
        headers = {"Authorization": f"Bearer {key}"} if key else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=60, **kw)

    def worker_pids(self) -> list[int]:
        """Pids of the job worker processes (children of the fork server, itself a child of the server)."""
        import psutil
        if self.proc is None:
            return []
        pids = []
        try:
            for child in psutil.Process(self.proc.pid).children():
                try:
                    if "forkserver" in " ".join(child.cmdline()):
                        pids += [c.pid for c in child.children() if c.status() != psutil.STATUS_ZOMBIE]
                except psutil.Error:
                    continue
        except psutil.Error:
            return []
        return pids


def submit(client: httpx.Client, cloud_path: Path, params: dict | None = None, *, headers=None,
           **fields) -> httpx.Response:
    """POST /jobs as multipart with the cloud file and the parameters as JSON text."""
    data = {"parameters": json.dumps(params if params is not None else HALF_SPHERE_PARAMS)}
    data.update({k: str(v) for k, v in fields.items()})
    with open(cloud_path, "rb") as fh:
        return client.post("/jobs", files={"cloud": (cloud_path.name, fh, "application/octet-stream")},
                           data=data, headers=headers or {})


def wait_status(client: httpx.Client, job_id: str, statuses=("succeeded", "failed", "cancelled"),
                max_polls: int = 1200, interval: float = 0.1) -> dict:
    """Poll GET /jobs/{id} until its status is one of ``statuses`` (bounded count); return the job."""
    job = None
    for _ in range(max_polls):
        r = client.get(f"/jobs/{job_id}")
        assert r.status_code == 200, r.text
        job = r.json()
        if job["status"] in statuses:
            return job
        time.sleep(interval)
    raise AssertionError(f"job {job_id} never reached {statuses}; last state: {job}")


def wait_until(predicate, max_polls: int = 600, interval: float = 0.1):
    """Call ``predicate`` until it returns a truthy value (bounded count); return that value."""
    for _ in range(max_polls):
        v = predicate()
        if v:
            return v
        time.sleep(interval)
    raise AssertionError("condition never became true")


def stray_files(data_dir: Path, job_ids) -> list[str]:
    """Files in the data directory that no job owns: anything in tmp/, or a job folder without a job."""
    known = set(job_ids)
    out = [str(p) for p in (data_dir / "tmp").iterdir()] if (data_dir / "tmp").exists() else []
    if (data_dir / "jobs").exists():
        out += [str(p) for p in (data_dir / "jobs").iterdir() if p.name not in known]
    return out


def ascii_ply(points: np.ndarray, *, claim: int | None = None) -> bytes:
    """An ascii PLY of ``points`` whose header claims ``claim`` vertices (default: the true count)."""
    n = len(points) if claim is None else claim
    head = (f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n")
    body = "".join(f"{x} {y} {z}\n" for x, y, z in points)
    return (head + body).encode()


class WorkerProcess(_ScanmillProcess):
    """``scanmill worker`` (a Celery worker) in a subprocess and its own session, logging to a file.

    ``settings`` become ``SCANMILL_*`` variables (broker, database, data directory, ...).
    """

    def __init__(self, name: str, log_dir: Path, **settings):
        self.name, self.log_dir, self.settings = name, Path(log_dir), settings
        self.proc: subprocess.Popen | None = None
        self.log_path = self.log_dir / f"worker-{name}.log"

    def start(self, max_polls: int = 600) -> "WorkerProcess":
        """Start it and wait (at most ``max_polls`` x 0.1 s) until Celery logs that the worker is ready."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "scanmill.cli", "worker", "--name", f"{self.name}@test",
                 "--log-level", "info"], cwd=ROOT, env=self.env(), stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True)
        for _ in range(max_polls):
            if self.proc.poll() is not None:
                break
            if f"{self.name}@test ready" in self.log_text():
                return self
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"worker {self.name} did not start:\n{self.log_text()[-3000:]}")

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def children(self) -> list[int]:
        """Pids of the pool's child processes."""
        import psutil
        try:
            return [c.pid for c in psutil.Process(self.proc.pid).children() if c.status() != psutil.STATUS_ZOMBIE]
        except psutil.Error:
            return []

    def __enter__(self) -> "WorkerProcess":
        return self.start()
