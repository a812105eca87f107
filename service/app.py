"""The application factory: ``create_app(settings)`` builds the FastAPI app of ``scanmill serve``.

At start (lifespan) it opens the storage (the local form takes the data directory's lock), the job
store (SQLite or PostgreSQL, migrated to the newest schema) and the execution backend
(``SCANMILL_BACKEND``: embedded worker processes, or Celery workers through Redis), which settles
what a previous run left behind and starts; at shutdown the embedded backend stops its workers and
puts their jobs back in the queue. Routers are thin; the settings, the job service and the
caller are injected as dependencies (``service.deps``).
"""

from __future__ import annotations

import logging
import time
from contextlib import asynccontextmanager

import anyio
from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

import scanmill
from scanmill.viewer import STATIC_DIR
from service.jobs import JobService
from service.limits import BodyLimitMiddleware
from service.openapi import build_openapi
from service.problems import install_handlers
from service.retention import RetentionSweeper
from service.routers import jobs as jobs_routes
from service.routers import system as system_routes
from service.routers import viewer as viewer_routes
from service.settings import Settings, load_settings
from service.backends import make_backend
from service.db import database_url
from service.storage import open_storage
from service.store import JobStore
from service.validation import SubmissionChecker

log = logging.getLogger("scanmill.service")

DESCRIPTION = """\
Plan the 3+2 five-axis machining of a part straight from its 3D scan.

Submit a point cloud with its plan configuration (`POST /jobs`), poll the job (`GET /jobs/{id}`)
until it has succeeded, then fetch `plan.json` (`GET /jobs/{id}/result`) and the artifacts
(`GET /jobs/{id}/artifacts`). Every error is an RFC 9457 problem document
(`application/problem+json`) with a 4xx status and a stable `code`.
"""

TAGS = [
    {"name": "jobs", "description": "Submit, follow, list, cancel and delete planning jobs."},
    {"name": "artifacts", "description": "Files a finished job produced (NPZ, PLY, PNG, G-code)."},
    {"name": "service", "description": "Health and version."},
]


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app; ``settings`` default to :func:`service.settings.load_settings` (environment)."""
    settings = settings or load_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        storage = open_storage(settings.data_dir, settings.storage_kind)
        storage.open()
        try:
            store = JobStore(database_url(settings.database_url, settings.data_dir))
        except BaseException:
            storage.close()
            raise
        backend = make_backend(settings, store, storage)
        recovered = backend.recover()
        if any(recovered.values()):
            log.warning("recovered jobs left running by the previous run: %s",
                        {k: len(v) for k, v in recovered.items()})
        if settings.anonymous:
            log.warning("SCANMILL_API_KEYS is empty: anonymous requests are accepted from loopback clients only")
        backend.start()
        retention = RetentionSweeper(settings, store, storage).start()
        app.state.storage, app.state.store, app.state.backend = storage, store, backend
        checker = SubmissionChecker(settings)
        # the fork server imports the planning code once, before the first request is served: /healthz
        # answers when an upload can be checked at once (the first upload used to wait for those
        # imports, 17 s on a loaded two-core machine)
        t0 = time.monotonic()
        try:
            ready = await anyio.to_thread.run_sync(checker.warm)
        except Exception as e:      # noqa: BLE001 - each upload's check then says what fails
            ready, why = False, str(e)
        else:
            why = "no forked process ran within 60 s"
        if ready:
            log.info("submission checks ready in %.1f s (fork server up, planning code imported)",
                     time.monotonic() - t0)
        else:
            log.error("the fork server for submission checks is not ready (%s); uploads will try again", why)
        app.state.jobs = JobService(settings, store, storage, backend, anyio.CapacityLimiter(1), checker)
        log.info("scanmill %s serving; backend %s; jobs in %s; files in %s (%s)", scanmill.__version__,
                 backend.name, store.display_url, storage.root, storage.kind)
        try:
            yield
        finally:
            retention.stop()
            backend.stop()
            store.close()
            storage.close()

    app = FastAPI(title="scanmill", version=scanmill.__version__, description=DESCRIPTION, openapi_tags=TAGS,
                  lifespan=lifespan, separate_input_output_schemas=False, redirect_slashes=False)
    app.state.settings = settings
    install_handlers(app)      # RequestTooLarge, raised while a body streams in, is an ApiError
    app.add_middleware(BodyLimitMiddleware, settings=settings)
    app.include_router(jobs_routes.router)
    app.include_router(system_routes.router)
    app.include_router(viewer_routes.router)
    # the viewer's own scripts and the vendored three.js (scanmill/viewer/static), public like the page
    app.mount(viewer_routes.STATIC_PREFIX.rstrip("/"), StaticFiles(directory=STATIC_DIR, check_dir=False),
              name="viewer-static")
    app.openapi = lambda: build_openapi(app)  # type: ignore[method-assign]
    return app
