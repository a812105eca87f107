"""Service routes: ``GET /healthz`` and ``GET /version`` (tag ``service``; no API key needed).

``/healthz`` is meant for liveness and readiness probes and for monitoring. It answers 200 with
``status`` ``ok``, or ``degraded`` when the data directory's file system has less free space than
``SCANMILL_MIN_FREE_DISK_MB`` (the service still serves jobs, results and artifacts, but refuses
submissions and job starts with 507 until space is freed: an alert, not a reason to take the
instance out of rotation). It answers 503 ``store_unavailable`` (with ``Retry-After``) when the job
store does not answer, since then nothing works. Anyone may call it, so it says nothing of the
server's internals: no host, port, path or driver error (those go to the log).
"""

from __future__ import annotations

import logging

from fastapi import APIRouter, Request

import scanmill
from schemas.api import DiskHealth, Health, Version
from schemas.plan import SCHEMA_VERSION
from service.diskspace import MIB, free_bytes
from service.openapi import PROBLEM_REF
from service.problems import store_unavailable_response

router = APIRouter()
log = logging.getLogger("scanmill.service")


def disk_health(settings) -> DiskHealth:
    """The data directory's free space against SCANMILL_MIN_FREE_DISK_MB."""
    reserve = int(settings.min_free_disk_mb) * MIB
    try:
        free = free_bytes(settings.data_dir)
    except OSError as exc:
        log.error("healthz: cannot read the free space of the data directory: %s", exc)
        return DiskHealth(status="unknown", free_bytes=None, min_free_bytes=reserve)
    return DiskHealth(status="ok" if free >= reserve else "low", free_bytes=free, min_free_bytes=reserve)


@router.get("/healthz", operation_id="get_health", tags=["service"], response_model=Health,
            summary="Liveness and readiness",
            description="200 when the job store answers, with the worker pool and queue sizes, the free disk "
                        "space of the data directory and the database state. `status` is `ok`, or `degraded` "
                        "when the disk has less free space than SCANMILL_MIN_FREE_DISK_MB (jobs and results "
                        "are still served; submissions are refused with 507). No key needed, and no internal "
                        "detail (hosts, ports, errors) is shown.",
            responses={200: {"content": {"application/json": {"example": {
                                 "status": "degraded", "workers": 2, "busy_workers": 0, "queued_jobs": 0,
                                 "running_jobs": 0, "database": "ok",
                                 "disk": {"status": "low", "free_bytes": 52428800,
                                          "min_free_bytes": 1073741824}}}}},
                       503: {"description": "The job store does not answer (problem `store_unavailable`, "
                                            "`database: unavailable`, with Retry-After).",
                             "content": {"application/problem+json": {"schema": PROBLEM_REF}}}})
def get_health(request: Request):
    state = request.app.state
    disk = disk_health(state.settings)
    try:
        counts = state.store.counts()
        slots = state.backend.health()
    except Exception as exc:  # noqa: BLE001 - reported as not ready; the details go to the log only
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        log.error("healthz: the job store does not answer: %s", first)
        return store_unavailable_response(request.url.path, database="unavailable",
                                          disk=disk.model_dump(mode="json"))
    return Health(status="ok" if disk.status == "ok" else "degraded", workers=slots["workers"],
                  busy_workers=slots["busy_workers"], queued_jobs=counts.get("queued", 0),
                  running_jobs=counts.get("running", 0), disk=disk, database="ok")


@router.get("/version", operation_id="get_version", tags=["service"], response_model=Version,
            summary="What is serving")
def get_version() -> Version:
    return Version(version=scanmill.__version__, plan_schema_version=SCHEMA_VERSION)
