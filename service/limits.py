"""Request-size limits enforced while the body streams in, before anything is written to disk.

:class:`BodyLimitMiddleware` answers 413 (problem JSON naming the limit) when ``Content-Length``
exceeds the limit, and raises :class:`RequestTooLarge` (an :class:`~service.problems.ApiError`) as
soon as a streamed body (chunked, or lying about its length) grows past it. Multipart uploads are
bounded by ``SCANMILL_MAX_UPLOAD_BYTES``, JSON bodies by ``SCANMILL_MAX_JSON_BYTES``. Before
answering, up to :data:`DRAIN_CAP` bytes of the rest of the body are read and dropped, so an ordinary
client that sends its whole body before reading the answer still gets the 413 rather than a reset
connection.
"""

from __future__ import annotations

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.problems import ApiError, api_error_response
from service.settings import Settings

DRAIN_CAP = 64 * 1024 * 1024


class RequestTooLarge(ApiError):
    """The request body is larger than the named limit: 413 ``request_too_large`` naming it."""

    def __init__(self, limit_name: str, limit: int):
        super().__init__(413, "request_too_large",
                         f"The request body is larger than {limit:,} bytes, the limit of this service "
                         f"({limit_name}). Decimate the scan or save it as binary PLY, which is smaller.",
                         limit=limit_name, limit_value=limit)


def limit_for(settings: Settings, content_type: str) -> tuple[int, str]:
    """The byte limit and its setting name for a request with this content type."""
    ct = content_type.split(";")[0].strip().lower()
    if ct == "application/json" or ct.endswith("+json"):
        return settings.max_json_bytes, "SCANMILL_MAX_JSON_BYTES"
    return settings.max_upload_bytes, "SCANMILL_MAX_UPLOAD_BYTES"


async def _drain(receive: Receive, cap: int) -> None:
    dropped = 0
    while dropped <= cap:
        message = await receive()
        if message["type"] != "http.request":
            return
        dropped += len(message.get("body", b""))
        if not message.get("more_body", False):
            return


class BodyLimitMiddleware:
    """ASGI middleware bounding the size of request bodies (see the module docstring)."""

    def __init__(self, app: ASGIApp, settings: Settings):
        self.app, self.settings = app, settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] not in ("POST", "PUT", "PATCH"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        limit, name = limit_for(self.settings, headers.get("content-type", ""))
        declared = headers.get("content-length", "")
        if declared.isdigit() and int(declared) > limit:
            await _drain(receive, DRAIN_CAP)
            response = api_error_response(RequestTooLarge(name, limit), instance=scope.get("path"))
            await response(scope, receive, send)
            return
        received = 0

        async def limited() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    if message.get("more_body", False):
                        await _drain(receive, DRAIN_CAP)
                    raise RequestTooLarge(name, limit)
            return message

        await self.app(scope, limited, send)
