"""The Docker compose files name only settings scanmill knows, and wire the scale-out services together."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from service.settings import Settings

DOCKER = Path(__file__).resolve().parents[1] / "docker"


def _compose(name: str) -> dict:
    return yaml.safe_load((DOCKER / name).read_text())


@pytest.mark.parametrize("name", ["compose.yaml", "compose.scale.yaml"])
def test_every_scanmill_variable_is_a_setting(name):
    for svc, spec in _compose(name)["services"].items():
        for var in (spec.get("environment") or {}):
            if var.startswith("SCANMILL_"):
                assert var[len("SCANMILL_"):].lower() in Settings.model_fields, f"{name}: {svc}: {var}"


def test_scale_out_compose_runs_api_workers_redis_and_postgres():
    c = _compose("compose.scale.yaml")
    s = c["services"]
    assert set(s) == {"api", "worker", "redis", "postgres"}
    api, worker = s["api"]["environment"], s["worker"]["environment"]
    for env in (api, worker):          # the same backend, broker, database and shared directory everywhere
        assert env["SCANMILL_BACKEND"] == "celery"
        assert env["SCANMILL_BROKER_URL"].startswith("redis://redis:")
        assert env["SCANMILL_DATABASE_URL"].startswith("postgresql+psycopg://") and "@postgres:" in \
            env["SCANMILL_DATABASE_URL"]
    assert s["worker"]["command"] == ["scanmill", "worker"] and "replicas" in s["worker"]["deploy"]
    assert [v.split(":")[0] for v in s["api"]["volumes"]] == [v.split(":")[0] for v in s["worker"]["volumes"]]
    assert "--appendonly" in s["redis"]["command"]
    settings = Settings.model_validate({k[len("SCANMILL_"):].lower(): v for k, v in worker.items()
                                        if "${" not in str(v)})
    assert settings.storage_kind == "shared"
