"""FastAPI dependencies: the objects the routes get injected (settings, job service, caller)."""

from __future__ import annotations

from fastapi import Request

from service.auth import Principal, get_principal, get_settings  # noqa: F401 - re-exported for the routers
from service.jobs import JobService


async def get_jobs(request: Request) -> JobService:
    """The running service's :class:`JobService`."""
    return request.app.state.jobs
