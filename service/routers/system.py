"""Service routes: ``GET /healthz`` and ``GET /version`` (tag ``service``; no API key needed)."""

from __future__ import annotations

from fastapi import APIRouter, Request

import scanmill
from schemas.api import Health, Version
from schemas.plan import SCHEMA_VERSION
from service.openapi import PROBLEM_REF
from service.problems import ApiError

router = APIRouter()


@router.get("/healthz", operation_id="get_health", tags=["service"], response_model=Health,
            summary="Liveness and readiness",
            description="200 when the job store answers; includes the worker pool and queue sizes.",
            responses={503: {"description": "The job store does not answer.",
                             "content": {"application/problem+json": {"schema": PROBLEM_REF}}}})
def get_health(request: Request) -> Health:
    state = request.app.state
    try:
        counts = state.store.counts()
    except Exception as exc:  # noqa: BLE001 - reported as not ready
        raise ApiError(503, "store_unavailable", f"The job store does not answer: {exc}") from None
    slots = state.backend.health()
    return Health(status="ok", workers=slots["workers"], busy_workers=slots["busy_workers"],
                  queued_jobs=counts.get("queued", 0), running_jobs=counts.get("running", 0))


@router.get("/version", operation_id="get_version", tags=["service"], response_model=Version,
            summary="What is serving")
def get_version() -> Version:
    return Version(version=scanmill.__version__, plan_schema_version=SCHEMA_VERSION)
