"""Service settings: defaults, then an optional config file, then ``SCANMILL_*`` environment variables.

Every field below can be set as an environment variable named ``SCANMILL_`` + the field name in
upper case (``SCANMILL_DATA_DIR``, ``SCANMILL_WORKERS``, ...), or in a TOML or JSON file named by
``SCANMILL_CONFIG`` (or ``scanmill serve --config``) whose top-level keys are the field names. The
environment wins over the file; command-line flags of ``scanmill serve`` win over both.
``SCANMILL_API_KEYS`` is a comma-separated list.
"""

from __future__ import annotations

import ipaddress
import json
import os
import tomllib
from pathlib import Path
from typing import Any, Mapping

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

ENV_PREFIX = "SCANMILL_"


def _default_workers() -> int:
    return max(1, (os.cpu_count() or 2) // 2)


def host_memory_mb() -> int:
    """This machine's physical memory, MiB (0 when it cannot be read)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // (1 << 20))
    except (ValueError, OSError, AttributeError):
        return 0


def _comma_list(v: Any) -> Any:
    """A comma-separated string or a list as a list of non-empty stripped strings (anything else unchanged)."""
    if isinstance(v, str):
        v = v.split(",")
    if isinstance(v, (list, tuple)):
        return [str(x).strip() for x in v if str(x).strip()]
    return v


class SettingsError(ValueError):
    """A setting has a bad value; the message names the variable and the allowed range."""


class Settings(BaseModel):
    """What ``scanmill serve`` runs with. Names double as ``SCANMILL_<NAME>`` variables."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    data_dir: Path = Field(Path("scanmill-data"),
                           description="Uploads and artifacts live here (and the SQLite job database when "
                                       "SCANMILL_DATABASE_URL is unset). With the Celery backend every API and "
                                       "worker machine mounts the same shared directory here.")
    backend: str = Field("embedded", pattern="^(embedded|celery)$",
                         description="Where jobs run: 'embedded' (worker processes of the API server) or "
                                     "'celery' (a pool of `scanmill worker` machines fed through the broker).")
    database_url: str | None = Field(
        None, description="Job store: unset = SQLite in data_dir; postgresql+psycopg://USER:PASSWORD@HOST:PORT/DB "
                          "for PostgreSQL (needed when API and workers are on several machines).")
    broker_url: str | None = Field(None, description="Celery broker, redis://HOST:PORT/DB (backend 'celery' only).")
    storage: str | None = Field(
        None, pattern="^(local|shared)$",
        description="Artifact storage: 'local' (one server owns data_dir, takes a lock on it) or 'shared' "
                    "(a directory mounted by several machines: no lock, per-host upload staging). "
                    "Unset: local for the embedded backend, shared for Celery.")
    celery_queue: str = Field("scanmill", pattern="^[A-Za-z0-9_.-]{1,64}$", description="Celery queue of the jobs.")
    max_tasks_per_child: int = Field(
        10, ge=1, le=100000, description="Celery: jobs a worker child process runs before it is replaced "
                                         "(returns memory numpy/open3d kept).")
    heartbeat_s: float = Field(5.0, gt=0, le=600,
                               description="Celery: a running job writes a heartbeat to the job store this often, s.")
    lease_s: float = Field(
        30.0, gt=0, le=86400,
        description="Celery: a running job whose heartbeat is older than this (s) has lost its worker; a "
                    "redelivered task takes it over, or the API's reaper queues it again.")
    reaper_interval_s: float = Field(
        10.0, ge=0, le=3600,
        description="Celery: how often the API hands unsent jobs to the broker and re-queues jobs whose worker "
                    "is gone (s); 0 turns the reaper off (then only the broker's redelivery recovers them).")
    publish_grace_s: float = Field(
        60.0, gt=0, le=86400,
        description="Celery: a queued job taken for publication whose sending the broker has not confirmed "
                    "within this many seconds (its API died between the two) is published again by the reaper, s. "
                    "Longer than a publication may take (a few broker retries).")
    hard_time_limit_grace_s: float = Field(
        60.0, ge=1, le=86400,
        description="Celery: a job's hard time limit (the child is killed) is its soft limit plus this, s.")
    broker_visibility_timeout_s: float | None = Field(
        None, gt=0, le=30 * 86400,
        description="Redis: an unacknowledged task is delivered again after this many seconds (its worker is "
                    "presumed dead). Must exceed the longest job: default job_time_limit_s + "
                    "hard_time_limit_grace_s + 600.")
    host: str = Field("127.0.0.1", description="Address uvicorn binds to.")
    port: int = Field(8000, ge=0, le=65535, description="TCP port (0: any free port).")
    api_keys: list[str] = Field(
        default_factory=list,
        description="Accepted bearer keys. Empty: anonymous requests are accepted from loopback clients only.")
    workers: int = Field(default_factory=_default_workers, ge=1, le=64,
                         description="Jobs run at once (worker processes).")
    worker_threads: int | None = Field(
        None, ge=1, le=64,
        description="BLAS/OpenMP/numba threads per job (OMP/OPENBLAS/MKL/NUMBA_NUM_THREADS); unset: the cores "
                    "shared out over the jobs run at once (cores // workers, at least 1).")
    start_method: str = Field("forkserver", pattern="^(forkserver|spawn)$",
                              description="multiprocessing start method of the workers.")
    job_time_limit_s: float = Field(
        3600.0, gt=0, le=7 * 86400,
        description="Wall-clock limit of one attempt of a job; the worker is killed past it.")
    max_attempts: int = Field(2, ge=1, le=10,
                              description="Starts of a job that a restart of the service interrupted before it "
                                          "is failed with code 'interrupted'.")
    max_upload_bytes: int = Field(512 * 1024 * 1024, ge=1024,
                                  description="Largest multipart request (cloud and fixtures together), bytes.")
    max_json_bytes: int = Field(16 * 1024 * 1024, ge=1024, description="Largest JSON request body, bytes.")
    max_points: int = Field(20_000_000, ge=10, description="Most points accepted in a cloud (caps input.max_points).")
    max_inline_points: int = Field(100_000, ge=10, description="Most points in an inline (JSON) cloud.")
    max_fixtures: int = Field(8, ge=0, le=64, description="Most fixture files per job.")
    validation_workers: int = Field(
        2, ge=1, le=64,
        description="Submissions whose files are read and checked at once, each in a child process under the job "
                    "memory limit (SCANMILL_JOB_MEMORY_MB), never in the API process; more wait their turn.")
    validation_time_limit_s: float = Field(
        300.0, gt=0, le=86400,
        description="Longest the reading and checking of one submission may take; past it the submission is "
                    "refused with 422 validation_timeout.")
    log_level: str = Field("info", pattern="^(critical|error|warning|info|debug)$")
    # --- budgets, quotas, retention and the edge of the service ---------------------------------
    job_memory_mb: int | None = Field(
        None, ge=64, le=16 * 1024 * 1024,
        description="Memory budget of one job, MiB: a job whose estimate (from its cloud and parameters) is "
                    "larger is refused at submission (422), and each job runs under this address-space limit "
                    "(it fails with 'memory_limit_exceeded', never the host). Unset: 80 % of the host's memory "
                    "shared out over SCANMILL_WORKERS.")
    max_queued_jobs_per_key: int = Field(
        100, ge=1, le=1_000_000,
        description="Most jobs one API key (or the anonymous user) may have queued or running at once; more "
                    "are refused with 429 and Retry-After.")
    max_stored_bytes_per_key: int = Field(
        20 * 1024 ** 3, ge=1024 * 1024,
        description="Most bytes of uploads and artifacts one API key may keep stored; a submission past it is "
                    "refused with 507 naming the limit. Delete finished jobs to free space.")
    retention_days: float = Field(
        30.0, ge=0, le=36500,
        description="Finished jobs (succeeded, failed, cancelled) older than this many days are deleted with "
                    "their files; 0 keeps them forever.")
    min_free_disk_mb: int = Field(
        1024, ge=0, le=1024 * 1024 * 1024,
        description="Free space, MiB, kept on the data directory's file system: an upload or a job start that "
                    "would leave less is refused with 507 (the space needed and available named), and /healthz "
                    "reports 'degraded' below it.")
    body_read_timeout_s: float = Field(
        30.0, gt=0, le=3600,
        description="A request body that stops arriving for this many seconds is answered 408 and dropped.")
    forwarded_allow_ips: list[str] = Field(
        default_factory=lambda: ["127.0.0.1", "::1"],
        description="Proxies whose client-address headers (Forwarded, X-Forwarded-For, X-Real-IP) are believed "
                    "(comma-separated IP addresses or networks; '*' trusts every peer). From any other peer the "
                    "socket's address decides, e.g. for the loopback-only anonymous access.")
    worker_start_delay_s: float = Field(
        0.0, ge=0, le=3600,
        description="Testing aid only: a worker waits this long before reading the cloud, so that cancellation, "
                    "time limits and restarts can be exercised on small clouds. Keep 0 in production.")
    validation_start_delay_s: float = Field(
        0.0, ge=0, le=3600,
        description="Testing aid only: the check of a submission waits this long in its child process before "
                    "reading the files, so that a client leaving mid-check and checks side by side can be "
                    "exercised on small files. Keep 0 in production.")

    @field_validator("worker_threads", "database_url", "broker_url", "storage", "broker_visibility_timeout_s",
                     mode="before")
    @classmethod
    def _empty_is_unset(cls, v: Any) -> Any:
        return None if isinstance(v, str) and not v.strip() else v

    @field_validator("forwarded_allow_ips", mode="before")
    @classmethod
    def _split_ips(cls, v: Any) -> Any:
        out = _comma_list(v)
        for x in out if isinstance(out, list) else ():
            if x != "*":
                try:
                    ipaddress.ip_network(x, strict=False)
                except ValueError:
                    raise ValueError(f"{x!r} is not an IP address or network (or '*')") from None
        return out

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, v: Any) -> Any:
        keys = _comma_list(v)
        for k in keys if isinstance(keys, list) else ():
            if len(k) < 8 or any(c.isspace() for c in k):
                raise ValueError("every API key needs at least 8 characters and no spaces")
        return keys

    @model_validator(mode="after")
    def _backend_needs(self) -> "Settings":
        if self.backend == "celery" and not self.broker_url:
            raise ValueError("backend 'celery' needs SCANMILL_BROKER_URL (redis://HOST:PORT/DB)")
        if self.broker_url and not self.broker_url.startswith(("redis://", "rediss://", "memory://")):
            raise ValueError("SCANMILL_BROKER_URL must be a redis:// (or rediss://) URL")
        return self

    @property
    def threads_per_job(self) -> int:
        """``worker_threads``, or the machine's cores shared out over ``workers`` jobs."""
        return self.worker_threads or max(1, (os.cpu_count() or 1) // self.workers)

    @property
    def storage_kind(self) -> str:
        """'local' or 'shared' (the setting, or the backend's default)."""
        return self.storage or ("shared" if self.backend == "celery" else "local")

    @property
    def visibility_timeout_s(self) -> float:
        """The broker's redelivery timeout: set, or longer than the longest job can run."""
        return self.broker_visibility_timeout_s or (self.job_time_limit_s + self.hard_time_limit_grace_s + 600.0)

    @property
    def job_memory_limit_mb(self) -> int:
        """``job_memory_mb``, or 80 % of the host's memory shared out over ``workers`` (at least 256 MiB)."""
        if self.job_memory_mb:
            return self.job_memory_mb
        host = host_memory_mb() or 4096
        return max(256, int(0.8 * host) // self.workers)

    @property
    def anonymous(self) -> bool:
        """True when no API key is configured (loopback-only anonymous access)."""
        return not self.api_keys


def _read_file(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text()
    except OSError as exc:
        raise SettingsError(f"cannot read the settings file {path}: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text) if path.suffix.lower() != ".json" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise SettingsError(f"the settings file {path} is not valid {'JSON' if path.suffix == '.json' else 'TOML'}: "
                            f"{exc}") from None
    if not isinstance(data, dict):
        raise SettingsError(f"the settings file {path} must hold a table of settings")
    data = data.get("scanmill", data) if isinstance(data.get("scanmill"), dict) else data
    return {str(k).lower().replace("-", "_"): v for k, v in data.items()}


def load_settings(config_file: str | os.PathLike | None = None, *, env: Mapping[str, str] | None = None,
                  **overrides: Any) -> Settings:
    """Build :class:`Settings` from defaults, the config file, ``SCANMILL_*`` variables and ``overrides``.

    ``config_file`` defaults to ``$SCANMILL_CONFIG``. ``overrides`` with value ``None`` are ignored.
    Raises :class:`SettingsError` naming the variable at fault.
    """
    env = os.environ if env is None else env
    fields = Settings.model_fields
    data: dict[str, Any] = {}
    source: dict[str, str] = {}
    path = config_file or env.get(ENV_PREFIX + "CONFIG")
    if path:
        for k, v in _read_file(Path(path)).items():
            if k not in fields:
                raise SettingsError(f"unknown setting {k!r} in {path}; known: {', '.join(sorted(fields))}")
            data[k], source[k] = v, f"{k} in {path}"
    for name in fields:
        var = ENV_PREFIX + name.upper()
        if var in env:
            data[name], source[name] = env[var], var
    for name, v in overrides.items():
        if v is not None:
            data[name], source[name] = v, f"--{name.replace('_', '-')}"
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        msgs = []
        for e in exc.errors():
            if not e.get("loc"):            # a check across settings: its message names the variables
                msgs.append(str(e["msg"]).removeprefix("Value error, "))
                continue
            name = str(e["loc"][0])
            msgs.append(f"{source.get(name, ENV_PREFIX + name.upper())}: {e['msg']}")
        raise SettingsError("invalid settings: " + "; ".join(msgs)) from None
