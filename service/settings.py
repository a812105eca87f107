"""Service settings: defaults, then an optional config file, then ``SCANMILL_*`` environment variables.

Every field below can be set as an environment variable named ``SCANMILL_`` + the field name in
upper case (``SCANMILL_DATA_DIR``, ``SCANMILL_WORKERS``, ...), or in a TOML or JSON file named by
``SCANMILL_CONFIG`` (or ``scanmill serve --config``) whose top-level keys are the field names. The
environment wins over the file; command-line flags of ``scanmill serve`` win over both.
``SCANMILL_API_KEYS`` is a comma-separated list.
"""

from __future__ import annotations

import json
import os
import tomllib
from pathlib import Path
from typing import Any, Mapping

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

ENV_PREFIX = "SCANMILL_"


def _default_workers() -> int:
    return max(1, (os.cpu_count() or 2) // 2)


class SettingsError(ValueError):
    """A setting has a bad value; the message names the variable and the allowed range."""


class Settings(BaseModel):
    """What ``scanmill serve`` runs with. Names double as ``SCANMILL_<NAME>`` variables."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    data_dir: Path = Field(Path("scanmill-data"),
                           description="Job database (SQLite), uploads and artifacts live here.")
    host: str = Field("127.0.0.1", description="Address uvicorn binds to.")
    port: int = Field(8000, ge=0, le=65535, description="TCP port (0: any free port).")
    api_keys: list[str] = Field(
        default_factory=list,
        description="Accepted bearer keys. Empty: anonymous requests are accepted from loopback clients only.")
    workers: int = Field(default_factory=_default_workers, ge=1, le=64,
                         description="Jobs run at once (worker processes).")
    worker_threads: int = Field(1, ge=1, le=64,
                                description="BLAS/OpenMP threads per worker (OMP/OPENBLAS/MKL_NUM_THREADS).")
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
    log_level: str = Field("info", pattern="^(critical|error|warning|info|debug)$")
    worker_start_delay_s: float = Field(
        0.0, ge=0, le=3600,
        description="Testing aid only: a worker waits this long before reading the cloud, so that cancellation, "
                    "time limits and restarts can be exercised on small clouds. Keep 0 in production.")

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, v: Any) -> Any:
        if isinstance(v, str):
            v = v.split(",")
        if isinstance(v, (list, tuple)):
            keys = [str(k).strip() for k in v if str(k).strip()]
            for k in keys:
                if len(k) < 8 or any(c.isspace() for c in k):
                    raise ValueError("every API key needs at least 8 characters and no spaces")
            return keys
        return v

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
            name = str(e["loc"][0]) if e.get("loc") else "?"
            msgs.append(f"{source.get(name, ENV_PREFIX + name.upper())}: {e['msg']}")
        raise SettingsError("invalid settings: " + "; ".join(msgs)) from None
