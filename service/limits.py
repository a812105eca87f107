"""Request-body limits enforced while the body streams in, before anything is written to disk.

:class:`BodyLimitMiddleware` bounds the bodies of POST, PUT and PATCH requests:

- **Size.** Multipart uploads are bounded by ``SCANMILL_MAX_UPLOAD_BYTES``, JSON bodies by
  ``SCANMILL_MAX_JSON_BYTES``. A ``Content-Length`` over the limit is answered 413 at once, before a
  byte of the body is read (a client that sends ``Expect: 100-continue`` never sends it); a body
  without a length (chunked) is refused as soon as it grows past the limit (:class:`RequestTooLarge`).
- **Time.** A body that stops arriving for ``SCANMILL_BODY_READ_TIMEOUT_S`` (no new bytes while the
  service waits for them) is answered 408 ``body_timeout`` (:class:`BodyTimeout`).

Both answers carry ``Connection: close``: the rest of the body is not read, the server closes the
connection after the answer, so a client cannot hold a connection (or make the server drain
gigabytes) by promising a body it does not send. Both are problem documents naming the setting and
its value.
"""

from __future__ import annotations

import math

import anyio
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.problems import ApiError, api_error_response
from service.settings import Settings

CLOSE = {"Connection": "close"}


class RequestTooLarge(ApiError):
    """The request body is larger than the named limit: 413 ``request_too_large`` naming it."""

    def __init__(self, limit_name: str, limit: int):
        super().__init__(413, "request_too_large",
                         f"The request body is larger than {limit:,} bytes, the limit of this service "
                         f"({limit_name} = {limit}). Decimate the scan or save it as binary PLY, which is smaller.",
                         headers=dict(CLOSE), limit=limit_name, limit_value=limit)


class BodyTimeout(ApiError):
    """No byte of the request body arrived for the timeout: 408 ``body_timeout`` naming the setting."""

    def __init__(self, timeout_s: float, received: int):
        value = int(timeout_s) if float(timeout_s).is_integer() else timeout_s
        super().__init__(408, "body_timeout",
                         f"The request body stopped arriving: no data for {timeout_s:g} s "
                         f"(SCANMILL_BODY_READ_TIMEOUT_S = {timeout_s:g}) after {received:,} bytes. Nothing was "
                         "kept; send the request again over a working connection, with the whole body.",
                         title="Request timeout", headers=dict(CLOSE),
                         limit="SCANMILL_BODY_READ_TIMEOUT_S", limit_value=value)


def limit_for(settings: Settings, content_type: str) -> tuple[int, str]:
    """The byte limit and its setting name for a request with this content type."""
    ct = content_type.split(";")[0].strip().lower()
    if ct == "application/json" or ct.endswith("+json"):
        return settings.max_json_bytes, "SCANMILL_MAX_JSON_BYTES"
    return settings.max_upload_bytes, "SCANMILL_MAX_UPLOAD_BYTES"


class BodyLimitMiddleware:
    """ASGI middleware bounding the size of request bodies and the wait for them (see the module docstring)."""

    def __init__(self, app: ASGIApp, settings: Settings):
        self.app, self.settings = app, settings

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] not in ("POST", "PUT", "PATCH"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        limit, name = limit_for(self.settings, headers.get("content-type", ""))
        declared = headers.get("content-length", "").strip()
        if declared.isdigit() and int(declared) > limit:
            # answered before the body is read; Connection: close makes the server drop the rest
            response = api_error_response(RequestTooLarge(name, limit), instance=scope.get("path"))
            await response(scope, receive, send)
            return
        timeout = float(self.settings.body_read_timeout_s)
        received = 0
        body_done = False
        started = False

        async def limited() -> Message:
            nonlocal received, body_done
            if body_done:                      # after the body only a disconnect can come: no deadline
                return await receive()
            try:
                with anyio.fail_after(timeout if math.isfinite(timeout) else None):
                    message = await receive()
            except TimeoutError:
                raise BodyTimeout(timeout, received) from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise RequestTooLarge(name, limit)
                body_done = not message.get("more_body", False)
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited, tracked_send)
        except (RequestTooLarge, BodyTimeout) as exc:
            # normally the app's handlers answer these; this is the net for one raised outside them
            if started:
                raise
            await api_error_response(exc, instance=scope.get("path"))(scope, receive, send)
