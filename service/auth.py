"""Who is asking: bearer API keys from ``SCANMILL_API_KEYS``, or anonymous on loopback only.

With keys configured, every jobs request needs ``Authorization: Bearer KEY`` (401 otherwise).
Without keys the service warns at start and accepts anonymous requests from loopback clients
only (403 for others). A job belongs to the key that created it: the owner stored with the job is
a hash of the key (the key itself is never stored), and other keys get 404 for it.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.problems import ApiError
from service.settings import Settings

ANONYMOUS = "anonymous"

bearer_scheme = HTTPBearer(auto_error=False, scheme_name="ApiKey",
                           description="An API key from SCANMILL_API_KEYS, as `Authorization: Bearer KEY`.")


@dataclass(frozen=True)
class Principal:
    """The caller: ``owner`` is the stable id jobs are stored under."""

    owner: str
    anonymous: bool


def owner_of_key(key: str) -> str:
    """The owner id of an API key (a SHA-256 prefix; the key is never stored)."""
    return "key-" + hashlib.sha256(key.encode()).hexdigest()[:32]


def is_loopback(host: str | None) -> bool:
    """Whether a client address is a loopback address (127.0.0.0/8, ::1)."""
    if not host:
        return False
    try:
        return ipaddress.ip_address(host.split("%")[0]).is_loopback
    except ValueError:
        return host == "localhost"


async def get_settings(request: Request) -> Settings:
    """The running service's settings (dependency)."""
    return request.app.state.settings


async def get_principal(request: Request,
                        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
                        settings: Annotated[Settings, Depends(get_settings)]) -> Principal:
    """Authenticate the request (dependency); raises 401/403 problems."""
    if settings.api_keys:
        if credentials is None or credentials.scheme.lower() != "bearer" or not credentials.credentials:
            raise ApiError(401, "unauthenticated",
                           "This service needs an API key: send `Authorization: Bearer KEY`.",
                           headers={"WWW-Authenticate": 'Bearer realm="scanmill"'})
        given = credentials.credentials.encode()
        for key in settings.api_keys:
            if hmac.compare_digest(given, key.encode()):
                return Principal(owner=owner_of_key(key), anonymous=False)
        raise ApiError(401, "invalid_api_key", "The API key is not valid for this service.",
                       headers={"WWW-Authenticate": 'Bearer realm="scanmill", error="invalid_token"'})
    client = request.client.host if request.client else None
    if not is_loopback(client):
        raise ApiError(403, "anonymous_not_allowed",
                       "This service has no API keys configured (SCANMILL_API_KEYS) and accepts anonymous "
                       "requests from the local machine only.")
    return Principal(owner=ANONYMOUS, anonymous=True)
