"""RFC 9457 problem documents: every error the API answers is ``application/problem+json`` with a 4xx.

:class:`ApiError` is what the service code raises; :func:`install_handlers` maps it, the planning
errors (:class:`planning.errors.PlanningError`, which carry their 4xx status), FastAPI's request
validation errors and Starlette's HTTP errors (unknown route, wrong method, bad multipart) to
problem documents. A write that fails because the disk (or a quota) is full, anywhere in a request,
is answered 507 ``insufficient_storage``, and a job store that does not answer 503
``store_unavailable``; neither says more about the server (paths, hosts, ports, the driver's error)
than the setting to look at, and the details go to the log. An unexpected exception is logged with
its traceback and answered as a problem document too (500, code ``internal_error``): no request
input is meant to reach it, and the test suite (schemathesis included) checks that none does.
"""

from __future__ import annotations

import errno
import logging
import re
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy import exc as sa_exc
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from planning.errors import PlanningError

log = logging.getLogger("scanmill.service")

PROBLEM_MEDIA_TYPE = "application/problem+json"
PROBLEM_TYPE_BASE = "https://scanmill.dev/problems/"

_TITLES = {
    400: "Bad request", 401: "Unauthorized", 403: "Forbidden", 404: "Not found",
    405: "Method not allowed", 406: "Not acceptable", 409: "Conflict", 413: "Content too large",
    408: "Request timeout", 415: "Unsupported media type", 422: "Unprocessable content", 429: "Too many requests",
    500: "Internal error", 503: "Service unavailable", 507: "Insufficient storage",
}

#: errno values meaning "the file system is full" (a disk full, a quota reached)
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


def is_disk_full(exc: BaseException) -> bool:
    """Whether an exception (or one it wraps) says the disk or quota is full: ENOSPC/EDQUOT, SQLite's
    'database or disk is full', PostgreSQL's disk_full (SQLSTATE 53100)."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in DISK_FULL_ERRNOS:
            return True
        if getattr(e, "sqlstate", None) == "53100":
            return True
        if type(e).__module__.startswith("sqlite3") and "full" in str(e).lower():
            return True
        e = getattr(e, "orig", None) or e.__cause__ or e.__context__
    return False


def disk_full_error(settings: Any, what: str = "this request") -> ApiError:
    """The 507 answer for a write that failed because the data directory's disk is full."""
    from service.diskspace import MIB, free_bytes
    try:
        free = free_bytes(settings.data_dir)
    except OSError:
        free = 0
    reserve = int(settings.min_free_disk_mb)
    return ApiError(507, "insufficient_storage",
                    f"The disk of the data directory filled up while writing {what} ({free / MIB:,.0f} MiB free; "
                    f"SCANMILL_MIN_FREE_DISK_MB = {reserve:,} MiB are kept in reserve). Nothing was kept. Free "
                    "space on the data directory (delete finished jobs) or try again later.",
                    title="Insufficient storage", limit="SCANMILL_MIN_FREE_DISK_MB", limit_value=reserve,
                    free_bytes=int(free))


class ApiError(Exception):
    """An error answered as a problem document: ``status`` (4xx), stable ``code``, ``detail`` sentence.

    ``extra`` adds problem extension members (``errors``, ``limit``, ``limit_value``, ``job_status``);
    ``headers`` adds response headers (``WWW-Authenticate``, ``Allow``).
    """

    def __init__(self, status: int, code: str, detail: str, *, title: str | None = None,
                 headers: dict[str, str] | None = None, **extra: Any):
        super().__init__(detail)
        self.status, self.code, self.detail, self.title = status, code, detail, title
        self.headers = headers or {}
        self.extra = extra                      # None members are left out by problem_body


def problem_body(status: int, code: str, detail: str | None, *, instance: str | None = None,
                 title: str | None = None, **extra: Any) -> dict[str, Any]:
    """The problem document as a dict (``type`` is a URI naming the ``code``)."""
    body: dict[str, Any] = {
        "type": PROBLEM_TYPE_BASE + code.replace("_", "-"),
        "title": title or _TITLES.get(status, "Error"),
        "status": status,
        "detail": detail,
        "code": code,
    }
    if instance is not None:
        body["instance"] = instance
    body.update({k: v for k, v in extra.items() if v is not None})
    return body


def problem_response(status: int, code: str, detail: str | None, *, instance: str | None = None,
                     headers: dict[str, str] | None = None, title: str | None = None,
                     **extra: Any) -> JSONResponse:
    """A ``JSONResponse`` carrying a problem document with the problem media type."""
    return JSONResponse(problem_body(status, code, detail, instance=instance, title=title, **extra),
                        status_code=status, media_type=PROBLEM_MEDIA_TYPE, headers=headers)


# limits named in planning error details -> the setting that bounds them on this service
_LIMIT_NAMES = {"max_points": "input.max_points / SCANMILL_MAX_POINTS", "max_bytes": "SCANMILL_MAX_UPLOAD_BYTES",
                "min_points": "input.min_points", "max_faces": "input.max_faces",
                "max_pixels": "input.relief.max_pixels"}
_LIMITED_CODES = ("too_many_points", "file_too_large", "too_few_points", "too_many_faces", "too_many_pixels")


def api_error_response(exc: ApiError, instance: str | None = None) -> JSONResponse:
    """Answer an :class:`ApiError` (from a handler, or from a middleware outside them)."""
    return problem_response(exc.status, exc.code, exc.detail, instance=instance, headers=exc.headers,
                            title=exc.title, **exc.extra)


def planning_problem(exc: PlanningError, instance: str | None = None) -> JSONResponse:
    """Answer a planning error with its own 4xx status, code and message."""
    status = exc.status if 400 <= int(exc.status) < 500 else 422
    details = getattr(exc, "details", {}) or {}
    extra: dict[str, Any] = {}
    if details.get("problems"):
        extra["errors"] = [str(p) for p in details["problems"]]
    for key, name in _LIMIT_NAMES.items():
        if key in details and exc.code in _LIMITED_CODES:
            extra["limit"], extra["limit_value"] = name, details[key]
            break
    return problem_response(status, exc.code, exc.message, instance=instance, **extra)


def _loc(err: dict[str, Any]) -> str:
    loc = [str(p) for p in err.get("loc", ())]
    if loc and loc[0] in ("body", "query", "path", "header"):
        where, rest = loc[0], loc[1:]
        return f"{where} {'.'.join(rest)}" if rest else where
    return ".".join(loc) or "request"


def allowed_methods(request: Request) -> list[str]:
    """The methods the OpenAPI document declares for this request's path (for the ``Allow`` header)."""
    doc = request.app.openapi()
    methods: set[str] = set()
    for template, item in doc.get("paths", {}).items():
        pattern = "^" + re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(template)) + "$"
        if re.match(pattern, request.url.path):
            methods |= {m.upper() for m in item if m in ("get", "put", "post", "delete", "patch", "head", "options")}
    return sorted(methods)


def install_handlers(app: FastAPI) -> None:
    """Register the exception handlers that turn every error into a problem document."""

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError):
        return api_error_response(exc, request.url.path)

    @app.exception_handler(PlanningError)
    async def _planning_error(request: Request, exc: PlanningError):
        return planning_problem(exc, request.url.path)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError):
        errors = [f"{_loc(e)}: {e.get('msg', 'invalid')}" for e in exc.errors()]
        return problem_response(422, "invalid_request", "The request is not valid: " + "; ".join(errors),
                                instance=request.url.path, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException):
        status = exc.status_code
        codes = {404: "not_found", 405: "method_not_allowed", 400: "bad_request", 413: "content_too_large"}
        detail = exc.detail if isinstance(exc.detail, str) else _TITLES.get(status, "Error")
        if status == 404 and detail == "Not Found":
            detail = f"There is no resource at {request.url.path}."
        if status == 400 and any(w in detail.lower() for w in ("multipart", "part", "field", "boundary")):
            detail = f"The multipart body cannot be read: {detail}"
        headers = dict(exc.headers or {})
        if status == 405:
            allowed = allowed_methods(request)
            headers["Allow"] = ", ".join(allowed)
            detail = f"{request.method} is not allowed on {request.url.path}; allowed: {', '.join(allowed)}."
        if status >= 500:  # pragma: no cover - nothing raises these deliberately
            log.error("HTTP %s on %s: %s", status, request.url.path, detail)
        return problem_response(status, codes.get(status, "http_error"), detail, instance=request.url.path,
                                headers=headers)

    @app.exception_handler(sa_exc.OperationalError)
    @app.exception_handler(sa_exc.InterfaceError)
    async def _store_unavailable(request: Request, exc: Exception):
        if is_disk_full(exc):                  # SQLite 'database or disk is full', PostgreSQL disk_full
            log.error("job store: disk full on %s %s", request.method, request.url.path)
            return api_error_response(disk_full_error(request.app.state.settings, "the job store"),
                                      request.url.path)
        # the job database is down or unreachable: nothing was changed; the client may retry. The driver's
        # message (host, port, user) goes to the log only.
        log.error("job store unavailable on %s %s: %s", request.method, request.url.path,
                  str(getattr(exc, "orig", exc)).strip().splitlines()[0] if str(getattr(exc, "orig", exc)) else exc)
        return store_unavailable_response(request.url.path)

    @app.exception_handler(OSError)
    async def _os_error(request: Request, exc: OSError):
        if is_disk_full(exc):                  # a write under the data directory (or the upload spool) failed
            log.error("disk full on %s %s: %s", request.method, request.url.path, exc)
            return api_error_response(disk_full_error(request.app.state.settings), request.url.path)
        return _internal_error(request)

    @app.exception_handler(ClientDisconnect)
    async def _client_gone(request: Request, exc: ClientDisconnect):
        # the client closed the connection before its body was complete: nobody reads this answer
        log.info("client disconnected during %s %s", request.method, request.url.path)
        return problem_response(400, "client_disconnected", "The client closed the connection before the request "
                                "body was complete; nothing was kept.", instance=request.url.path)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):  # pragma: no cover - a bug if reached
        return _internal_error(request)


def store_unavailable_response(instance: str | None, **extra: Any) -> JSONResponse:
    """503 ``store_unavailable`` with ``Retry-After``; says nothing of the database (host, port, error)."""
    return problem_response(503, "store_unavailable",
                            "The job store does not answer right now; nothing was changed. Retry in a few seconds.",
                            instance=instance, headers={"Retry-After": "5"}, **extra)


def _internal_error(request: Request) -> JSONResponse:
    log.exception("unexpected error on %s %s", request.method, request.url.path)
    return problem_response(500, "internal_error",
                            "The service failed unexpectedly; the error was logged. Please report it.",
                            instance=request.url.path)
