"""Fixtures shared across test modules."""

from __future__ import annotations

import pytest
from service_fixtures import (
    KEY_A,
    KEY_B,
    ServerProcess,
    submit,
    wait_status,
    write_half_sphere,
)


@pytest.fixture(scope="session")
def half_sphere_service(tmp_path_factory):
    """A service with the keys KEY_A and KEY_B and one finished half-sphere job of KEY_A (the
    tests' coarse parameters): ``(server, job)`` with ``job`` the GET /jobs/{id} document. Shared by the
    modules that read a finished job's artifacts (moves files, the viewer) so that the job is planned
    once per run."""
    root = tmp_path_factory.mktemp("half_sphere_service")
    srv = ServerProcess(root / "data", api_keys=[KEY_A, KEY_B], workers=1).start()
    try:
        cloud = write_half_sphere(root / "half_sphere.ply")
        with srv.client(KEY_A) as c:
            r = submit(c, cloud)
            assert r.status_code == 202, r.text
            job = wait_status(c, r.json()["id"])
        assert job["status"] == "succeeded", job
        yield srv, job
    finally:
        srv.stop()
